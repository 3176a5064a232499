"""Where the harness finds its data (case files, reference data, gold baselines) and writes its outputs.

Two layouts:

- **Source checkout** (``make``): the package sits in the repository, beside ``cases/`` and
  ``reference/``; data are read from there and ``runs/`` and ``reports/`` are written there,
  whatever the current directory.
- **Installed copy** (``pip install .``): meson installs ``cases/``, ``reference/`` and the build's
  ``fflags.txt`` into the package as ``harness/_data/``; ``runs/`` and ``reports/`` are written
  under the current directory.

``CPDI_DATA_DIR`` overrides the data directory in both layouts (a directory holding ``cases/``
and ``reference/``, e.g. a checkout's root).
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
SOURCE_ROOT = PACKAGE.parent
INSTALLED_DATA = PACKAGE / "_data"


def in_source_tree() -> bool:
    """True when the package is imported from a checkout (``cases/`` and ``reference/gold/`` beside it)."""
    return (SOURCE_ROOT / "cases").is_dir() and (SOURCE_ROOT / "reference" / "gold").is_dir()


def data_root() -> Path:
    """The directory holding ``cases/`` and ``reference/``."""
    env = os.environ.get("CPDI_DATA_DIR")
    if env:
        return Path(env).resolve()
    return SOURCE_ROOT if in_source_tree() else INSTALLED_DATA


def work_root() -> Path:
    """Where ``runs/`` and ``reports/`` go: the checkout's root, or the current directory for an installed copy."""
    return SOURCE_ROOT if in_source_tree() else Path.cwd()


def build_dir() -> Path:
    """The directory holding the build's ``fflags.txt`` (provenance)."""
    return SOURCE_ROOT / "build" / "fortran" if in_source_tree() else INSTALLED_DATA


DATA_ROOT = data_root()
CASES = DATA_ROOT / "cases"
REFERENCE = DATA_ROOT / "reference"
