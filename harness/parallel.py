"""Run independent simulations side by side, one process per core (each has its own solver)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any


def pmap(fn: Callable[..., Any], items: Iterable[Any], workers: int | None = None) -> list[Any]:
    """[fn(*item) for item in items], in up to `workers` processes (default: the machine's cores).
    Exceptions inside fn are returned as values, not raised, so one failed run does not lose the others."""
    items = list(items)
    workers = min(workers or os.cpu_count() or 1, len(items)) or 1
    if workers == 1:
        return [_safe(fn, it) for it in items]
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("fork")) as ex:
        return list(ex.map(_safe, [fn] * len(items), items))


def _safe(fn, item):
    try:
        return fn(*item)
    except Exception as exc:  # reported by the caller
        return exc
