"""The checks register themselves: ``@check(...)`` on a check module's ``run``.

``verify`` runs what is registered, in ``order``; nothing else lists the checks. A check's
requirement is its case file's ``[case] requirement`` (:func:`requirement`), read where the
module is imported, so the report, ``verify --only`` and the README's table (``python -m
tools.readme_checks``) all show the one text. A check with no case file (the manufactured and
analytic solutions of ``convergence`` and ``vibrating_bar``) holds its own ``REQUIREMENT``.

``experimental``: why the check is not in the gated set yet (runnable with ``--only``, never
run by ``make verify``); its notes page says more.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from harness import cases, paths


@dataclass(frozen=True)
class Registered:
    name: str
    module: str
    order: int
    experimental: str = ""   # why not gated; "" for a gated check
    notes: str = ""          # docs/notes page of an experimental check

    @property
    def gated(self) -> bool:
        return not self.experimental


_REGISTRY: dict[str, Registered] = {}


def requirement(case: Path | str) -> str:
    """The requirement of a case file (its ``[case] requirement``): a check's requirement."""
    return cases.load(paths.CASES / case if isinstance(case, str) else case)["case"]["requirement"]


def check(*, order: int, experimental: str = "", notes: str = "") -> Callable:
    """Register the decorated ``run(ctx)`` of a check module; the check's name is the module's."""
    if experimental and not notes:
        raise ValueError("an experimental check names its notes page (notes=...)")

    def deco(run: Callable) -> Callable:
        module = run.__module__
        name = module.rsplit(".", 1)[-1]
        other = _REGISTRY.get(name)
        if other is not None and other.module != module:
            raise ValueError(f"check {name!r} registered twice ({other.module}, {module})")
        _REGISTRY[name] = Registered(name, module, order, experimental, notes)
        return run

    return deco


def _discover() -> None:
    """Import every module of harness.checks: each registers its check."""
    import harness.checks as pkg

    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name not in ("base", "registry"):
            importlib.import_module(f"harness.checks.{info.name}")


def all_checks() -> list[Registered]:
    """Every registered check, gated first, each group in ``order``."""
    _discover()
    return sorted(_REGISTRY.values(), key=lambda r: (not r.gated, r.order, r.name))


def gated() -> list[str]:
    return [r.name for r in all_checks() if r.gated]


def experimental() -> list[str]:
    return [r.name for r in all_checks() if not r.gated]
