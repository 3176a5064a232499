"""The tests' own extension tests/_cpdi_test*.so (the Fortran module cpdi_test_hooks,
fortran/tests/cpdi_test_hooks.f90): stand-alone pressure-operator grids that no run uses, built
from the solver's core by make build and never installed (docs/design.md)."""

from __future__ import annotations

from harness.solver import Extension

HOOKS = Extension("tests._cpdi_test", "cpdi_test_hooks", "tests/_cpdi_test*.so")


def call(name: str, *args):
    """Call the hook `name` as harness.solver calls the solver's routines (ierr becomes CpdiError)."""
    return HOOKS.call(name, *args)
