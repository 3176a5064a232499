"""The bench's probe of the host, through tools' own extension tools/_cpdi_bench*.so (the Fortran
module cpdi_bench_probe, fortran/bench/): built from the solver's core by make build and never
installed, since only the bench (make bench, from the checkout) measures the host."""

from __future__ import annotations

from harness.solver import CpdiError, Extension

BENCH = Extension("tools._cpdi_bench", "cpdi_bench_probe", "tools/_cpdi_bench*.so")


def core_round_trip(iters: int = 20000) -> float:
    """Mean wall time [ns] of one round trip of a cache line between two OpenMP threads of this
    process (over iters trips): what moving data between the team's cores costs now. A control
    of make bench. It always runs on 2 threads, whatever harness.solver.threads() says, and raises
    CpdiError where OpenMP cannot start them (a build without OpenMP, OMP_THREAD_LIMIT=1)."""
    if not isinstance(iters, int) or iters < 1:
        raise CpdiError(1, f"iters must be a whole number >= 1, got {iters!r}")
    return float(BENCH.call("cpdi_core_round_trip", iters))
