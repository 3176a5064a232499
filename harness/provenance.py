"""Provenance of a verification run: code version, toolchain, libraries, machine, date.

:func:`collect` never raises: every probe is isolated and a failing probe yields
``"unknown"`` (``"missing"`` for Python packages that are not installed). The keys
``git_sha``, ``dirty``, ``compiler``, ``fflags``, ``numpy`` and ``date`` are part of the
``metrics.json`` contract (docs/design.md, "Interface contract").
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import socket
import subprocess
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from harness import openmp_defaults

UNKNOWN = "unknown"
MISSING = "missing"

# Untracked files under these top-level directories are generated output, not code changes.
_GENERATED_DIRS = ("runs/", "reports/")
_PACKAGES = ("numpy", "h5py", "matplotlib", "meson")


def _run(args: list[str], cwd: Path | None = None, timeout: float = 10.0) -> str:
    """Run a command and return its stripped stdout; raise on failure."""
    proc = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout, check=True)
    return proc.stdout.strip()


def _safe(probe: Callable[[], Any], default: Any = UNKNOWN) -> Any:
    """Call ``probe``; any exception (or an empty answer) gives ``default``."""
    try:
        value = probe()
    except Exception:  # noqa: BLE001 - provenance must never raise
        return default
    return default if value is None or value == "" else value


def git_sha(repo_root: Path) -> str:
    return _safe(lambda: _run(["git", "rev-parse", "HEAD"], cwd=repo_root))


def git_branch(repo_root: Path) -> str:
    return _safe(lambda: _run(["git", "rev-parse", "--abbrev-ref", "HEAD"], cwd=repo_root))


def _is_generated(porcelain_line: str) -> bool:
    """True for an untracked entry (``?? path``) under runs/ or reports/."""
    if not porcelain_line.startswith("?? "):
        return False
    path = porcelain_line[3:].strip().strip('"')
    return path.startswith(_GENERATED_DIRS)


def git_dirty(repo_root: Path) -> bool | str:
    """True if the work tree has changes other than untracked files under runs/ or reports/."""

    def probe() -> bool:
        out = subprocess.run(
            ["git", "status", "--porcelain"], cwd=repo_root, capture_output=True, text=True, timeout=30, check=True
        ).stdout
        return any(line and not _is_generated(line) for line in out.splitlines())

    return _safe(probe)


def compiler() -> str:
    return _safe(lambda: _run(["gfortran", "--version"]).splitlines()[0])


def fflags(build_dir: Path | None) -> str:
    """Fortran flags recorded by the build in ``build_dir/fflags.txt``."""
    if build_dir is None:
        return UNKNOWN
    return _safe(lambda: (Path(build_dir) / "fflags.txt").read_text().strip())


def package_version(name: str) -> str:
    return _safe(lambda: importlib.metadata.version(name), default=MISSING)


def lapack() -> str:
    """Resolved path of the LAPACK library pkg-config points at, or the raw link flags."""

    def probe() -> str:
        libs = _run(["pkg-config", "--libs", "lapack"]).split()
        dirs = [a[2:] for a in libs if a.startswith("-L")]
        try:
            dirs.append(_run(["pkg-config", "--variable=libdir", "lapack"]))
        except Exception:  # noqa: BLE001
            pass
        names = [a[2:] for a in libs if a.startswith("-l")]
        for name in names:
            for d in dirs:
                candidate = Path(d) / f"lib{name}.so"
                if candidate.exists():
                    return str(candidate.resolve())
        return " ".join(libs)

    return _safe(probe)


def cpu_model() -> str:
    def probe() -> str:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith(("model name", "cpu model")):
                return line.split(":", 1)[1].strip()
        return platform.processor()

    return _safe(probe)


def nproc() -> int | str:
    def probe() -> int | None:
        if hasattr(os, "sched_getaffinity"):
            return len(os.sched_getaffinity(0))
        return os.cpu_count()

    return _safe(probe)


def utc_now() -> str:
    return _safe(lambda: datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"))


def collect(repo_root: Path, build_dir: Path | None = None) -> dict[str, Any]:
    """Gather provenance for a run of the code in ``repo_root`` built in ``build_dir``."""
    repo_root = Path(repo_root)
    info: dict[str, Any] = {
        "git_sha": git_sha(repo_root),
        "dirty": git_dirty(repo_root),
        "branch": git_branch(repo_root),
        "compiler": compiler(),
        "fflags": fflags(build_dir),
        "python": _safe(platform.python_version),
    }
    for name in _PACKAGES:
        info[name] = package_version(name)
    info.update(
        {
            "lapack": lapack(),
            "hostname": _safe(socket.gethostname),
            "cpu": cpu_model(),
            "nproc": nproc(),
            # the user's setting, else the solver's default (harness.openmp_defaults)
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS")
            or openmp_defaults(os.environ).get("OMP_NUM_THREADS", "unset"),
            "date": utc_now(),
        }
    )
    return info
