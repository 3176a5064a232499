"""Published reference data in reference/data/: CSV files with a `#` citation header."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from harness import paths

DATA = paths.REFERENCE / "data"


def header(path: Path) -> list[str]:
    """The citation and definition lines (without the leading '#')."""
    return [ln[1:].strip() for ln in Path(path).read_text().splitlines() if ln.startswith("#")]


def read(name: str | Path) -> dict[str, np.ndarray]:
    """Columns of a reference CSV; numeric columns as float arrays (nan for 'nan'), others as str arrays."""
    path = Path(name) if Path(name).is_absolute() else DATA / name
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    rows = list(csv.reader(lines))
    cols = {}
    for j, key in enumerate(rows[0]):
        vals = [r[j] for r in rows[1:]]
        try:
            cols[key] = np.array([float(v) for v in vals])
        except ValueError:
            cols[key] = np.array(vals)
    return cols
