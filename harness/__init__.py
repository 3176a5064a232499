"""cpdi-verify harness: run, verify, validate and benchmark the Fortran CPDI solver.

Importing the package changes nothing in the caller's environment. The solver's OpenMP
defaults are applied where its extension is loaded (harness.solver, on first use):
see openmp_defaults.
"""

import math
import os

__version__ = "0.1.0"


def available_cores() -> int:
    """CPUs this process may run on: its affinity mask, capped by a cgroup CPU quota
    (cgroup v2 cpu.max, or v1 cpu.cfs_quota_us / cpu.cfs_period_us), at least 1."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    quota = None
    try:
        q, period = open("/sys/fs/cgroup/cpu.max").read().split()[:2]
        if q != "max":
            quota = int(q) / int(period)
    except (OSError, ValueError):
        try:
            q = int(open("/sys/fs/cgroup/cpu/cpu.cfs_quota_us").read())
            period = int(open("/sys/fs/cgroup/cpu/cpu.cfs_period_us").read())
            if q > 0 and period > 0:
                quota = q / period
        except (OSError, ValueError):
            pass
    if quota is not None:
        n = min(n, max(1, math.ceil(quota)))
    return max(1, n)


def openmp_defaults(env: dict[str, str]) -> dict[str, str]:
    """The OpenMP settings the solver's extension is loaded with, for the environment env;
    neither overrides a setting the user made. libgomp reads them once, when it is loaded, so
    harness.solver sets them for the import of the extension only and then restores the
    caller's environment.

    * GOMP_SPINCOUNT=10000 (unless OMP_WAIT_POLICY or GOMP_SPINCOUNT is set): a thread that
      waits at a barrier spins briefly, then sleeps. libgomp's default spins 30 times longer;
      when another process shares the cores, the spinning thread holds a core the thread it
      waits for needs, and a 2-thread run can be many times slower than 1 thread (measured:
      docs/notes/threads.md). The solver also measures both team sizes and runs each step on
      the faster one (cpdi_step.team_for_step).
    * OMP_NUM_THREADS = the cores this process may use (available_cores: the affinity mask and
      a cgroup CPU quota), not the machine's total. solver.threads(n) overrides it.
    """
    out = {}
    if "OMP_WAIT_POLICY" not in env and "GOMP_SPINCOUNT" not in env:
        out["GOMP_SPINCOUNT"] = "10000"
    if not env.get("OMP_NUM_THREADS"):
        out["OMP_NUM_THREADS"] = str(available_cores())
    return out
