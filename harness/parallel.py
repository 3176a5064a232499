"""Run independent simulations side by side, one process per core (each has its own solver).

The workers come from a fork server, not from a fork of this process: GNU OpenMP (libgomp)
cannot be used in a child forked from a process that has already run a parallel region
(the child waits forever on the parent's thread pool), and the solver is OpenMP. Each worker
runs its solver on one thread (solver.threads(1) in the worker's initializer), so
`workers` processes use `workers` cores and never oversubscribe them.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any


def pmap(fn: Callable[..., Any], items: Iterable[Any], workers: int | None = None) -> list[Any]:
    """[fn(*item) for item in items], in up to `workers` processes (default: the cores this process may use).
    fn must be a module-level function (it is pickled to the workers). Exceptions inside fn are
    returned as values, not raised, so one failed run does not lose the others."""
    items = list(items)
    from harness import available_cores

    workers = min(workers or available_cores(), len(items)) or 1
    if workers == 1:
        return [_safe(fn, it) for it in items]
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("forkserver"),
                             initializer=_one_thread) as ex:
        return list(ex.map(_safe, [fn] * len(items), items))


def _one_thread() -> None:
    os.environ["OMP_NUM_THREADS"] = "1"  # for anything the worker starts
    from harness import solver

    solver.threads(1)  # the fork server may have loaded the solver already


def _safe(fn, item):
    try:
        return fn(*item)
    except Exception as exc:  # reported by the caller
        return exc
