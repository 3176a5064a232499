"""cpdi-verify harness: run, verify, validate and benchmark the Fortran CPDI solver."""

__version__ = "0.1.0"
