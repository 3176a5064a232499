"""cpdi-verify harness: run, verify, validate and benchmark the Fortran CPDI solver.

Importing the package sets two OpenMP defaults for the solver, before its extension (and
with it libgomp, which reads the environment once, when it is loaded) can be imported.
Neither overrides a setting the user made:

* GOMP_SPINCOUNT=10000 (unless OMP_WAIT_POLICY or GOMP_SPINCOUNT is set): a thread that
  waits at a barrier spins for about 0.1 ms, then sleeps. libgomp's default spins 300000
  times (3-4 ms on the 2-core VM); when another process shares the cores, the spinning
  thread holds a core the thread it waits for needs, and a 2-thread run was measured 17x
  slower than 1 thread. Sleeping at once (passive) is safe under load but pays a wake-up
  per barrier on an idle machine (32k CPDI, 2 threads: 0.45 s per 100 steps against 0.31
  with the short spin). With the short spin a 2-thread step beside a busy process still
  takes ~1.7x a 1-thread one, so the solver measures both and runs each step on the
  faster team (cpdi_step.team_for_step). docs/notes/threads.md has the measurements.
* OMP_NUM_THREADS = the cores this process may use (available_cores: the affinity mask
  and a cgroup CPU quota), not the machine's total. solver.threads(n) overrides it.
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


def _openmp_defaults() -> None:
    env = os.environ
    if "OMP_WAIT_POLICY" not in env and "GOMP_SPINCOUNT" not in env:
        env["GOMP_SPINCOUNT"] = "10000"
    if not env.get("OMP_NUM_THREADS"):
        env["OMP_NUM_THREADS"] = str(available_cores())


_openmp_defaults()
