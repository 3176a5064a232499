"""Checkpoints of a run: the solver's full state plus the runner's, in one HDF5 file.

A checkpoint lets ``python -m harness run CASE --restart DIR`` continue a run bit for bit:
the solver's full internal state (:meth:`Simulation.get_full_state`), the runner's
counters (next series and output sample, steps, snapshots written, wall time so far) and
every series row written so far. The case it belongs to is stored as JSON and a restart
with a different case is refused, naming the keys that differ. A SHA-256 over the
contents detects a damaged file.

Layout of ``checkpoint.h5``: attributes ``format``, ``version``, ``case_name``, ``t``,
``created``, ``content_sha256``; datasets ``case_json`` and ``meta_json`` (runner state,
seeding digest, series columns), ``particles`` (rows x n), ``scalars`` and ``series``
(rows x columns). The file is written to a temporary name in the same directory, synced
and renamed over the old one, so a crash never leaves a half-written checkpoint.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from harness.cases import Case
from harness.output import _jsonable
from harness.seeding import ParticleSet

FORMAT = "cpdi-verify checkpoint"
VERSION = 1
FILENAME = "checkpoint.h5"


class CheckpointError(RuntimeError):
    """A checkpoint is missing, damaged or belongs to another case; the message names the fix."""


@dataclass
class Checkpoint:
    path: Path
    particles: np.ndarray  # (rows, n), Fortran layout of cpdi_get_full_state
    scalars: np.ndarray
    runner: dict[str, Any]  # n_out, n_ser, total_steps, snap_times, wall_s
    rows: dict[str, list[float]]  # series rows written so far, by column


def case_json(case: Case) -> str:
    return json.dumps(case.data, sort_keys=True, default=_jsonable)


def seed_digest(parts: ParticleSet) -> str:
    """SHA-256 of the seeded particles (the case-fixed state the checkpoint omits)."""
    h = hashlib.sha256()
    for a in (parts.x, parts.v, parts.mass, parts.vol, parts.r, parts.mat, parts.body, parts.group):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _digest(case_text: str, meta_text: str, arrays: list[np.ndarray]) -> str:
    h = hashlib.sha256(case_text.encode())
    h.update(meta_text.encode())
    for a in arrays:
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def locate(where: str | Path) -> Path:
    """The checkpoint file of a run directory (or the file itself)."""
    p = Path(where)
    return p / FILENAME if p.is_dir() else p


def save(path: Path, case: Case, parts: ParticleSet, full: dict[str, np.ndarray], runner: dict[str, Any],
         rows: dict[str, list[float]]) -> None:
    """Write a checkpoint atomically (temporary file in the same directory, fsync, rename)."""
    columns = list(rows)
    series = np.array([rows[c] for c in columns], dtype=np.float64).T.reshape(-1, len(columns))
    meta = json.dumps({**runner, "columns": columns, "seed_sha256": seed_digest(parts)}, sort_keys=True,
                      default=_jsonable)
    text = case_json(case)
    particles = np.ascontiguousarray(full["particles"])
    scalars = np.asarray(full["scalars"], dtype=np.float64)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs.update(format=FORMAT, version=VERSION, case_name=case.name, t=float(scalars[0]),
                           created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                           content_sha256=_digest(text, meta, [particles, scalars, series]))
            f["case_json"] = text
            f["meta_json"] = meta
            f["particles"] = particles
            f["scalars"] = scalars
            f["series"] = series
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise CheckpointError(f"could not write the checkpoint {path}: {exc}; check free space and permissions") \
            from None


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        out: dict[str, Any] = {}
        for k, v in data.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(data, list) and any(isinstance(v, dict) for v in data):
        out = {}
        for i, v in enumerate(data):
            out.update(_flatten(v, f"{prefix}.{i}"))
        return out
    return {prefix: data}


def _case_difference(stored: dict[str, Any], now: dict[str, Any]) -> list[str]:
    a, b = _flatten(stored), _flatten(now)
    return [f"{k} is {a.get(k, '(absent)')!r} in the checkpoint but {b.get(k, '(absent)')!r} now"
            for k in sorted(set(a) | set(b)) if a.get(k, "(absent)") != b.get(k, "(absent)")]


def load(where: str | Path, case: Case, parts: ParticleSet) -> Checkpoint:
    """Read and check a checkpoint for this case; CheckpointError names any problem and its fix."""
    path = locate(where)
    fresh = "rerun from t = 0 without --restart"
    if not path.is_file():
        hint = f" (expected {FILENAME} there)" if Path(where).is_dir() else ""
        raise CheckpointError(f"no checkpoint at {where}{hint}; write one with --checkpoint-every T, or stop a "
                              f"run with Ctrl-C (SIGINT) or SIGTERM, or {fresh}")
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise CheckpointError(f"{path} is not a cpdi-verify checkpoint; give the directory of a run "
                                      f"written with --checkpoint-every, or {fresh}")
            if int(f.attrs.get("version", -1)) != VERSION:
                raise CheckpointError(f"{path} has checkpoint format version {f.attrs.get('version')}, this "
                                      f"harness reads version {VERSION}; {fresh}")
            text = f["case_json"][()].decode()
            meta_text = f["meta_json"][()].decode()
            arrays = [f["particles"][()], f["scalars"][()], f["series"][()]]
            stored_sha = f.attrs["content_sha256"]
    except CheckpointError:
        raise
    except (OSError, KeyError, ValueError, TypeError, AttributeError) as exc:
        raise CheckpointError(f"{path} is damaged or truncated ({type(exc).__name__}: {exc}); restart from "
                              f"another checkpoint or {fresh}") from None
    if _digest(text, meta_text, arrays) != stored_sha:
        raise CheckpointError(f"{path} is damaged: its contents do not match their SHA-256; restart from "
                              f"another checkpoint or {fresh}")
    stored = json.loads(text)
    now = json.loads(case_json(case))
    if stored != now:
        diff = _case_difference(stored, now)
        more = f" (and {len(diff) - 3} more)" if len(diff) > 3 else ""
        raise CheckpointError(f"{path} belongs to a different case: {'; '.join(diff[:3])}{more}; restart with "
                              f"the case file and --set overrides of the original run, or {fresh}")
    meta = json.loads(meta_text)
    if meta["seed_sha256"] != seed_digest(parts):
        raise CheckpointError(f"{path}: the case now seeds other particles than when the checkpoint was written "
                              f"(the harness changed); {fresh}")
    particles, scalars, series = arrays
    columns = meta.pop("columns")
    rows = {c: series[:, i].tolist() for i, c in enumerate(columns)}
    return Checkpoint(path=path, particles=np.asfortranarray(particles), scalars=scalars, runner=meta, rows=rows)
