"""Run one case: build the solver from a validated case, step it, write the outputs.

The loop advances the Fortran solver in chunks between series samples (no I/O inside
the solver), evaluates probes, appends ``series.csv`` and writes snapshots at
``output_every``. On a solver error the outputs written so far are kept,
``summary.json`` gets status ``failed`` with the reason, and :class:`RunFailed` is raised.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from harness.cases import Case
from harness.output import SeriesWriter, SnapshotWriter, corners, write_json
from harness.probes import ProbeSet
from harness.seeding import ParticleSet, seed
from harness.solver import CpdiError, Simulation, pressure

SERIES_BASE = ["t", "kinetic_energy", "strain_energy", "momentum_x", "momentum_y", "gravity_work",
               "body_force_work", "friction_work", "viscous_dissipation", "mass", "steps", "dt"]


class RunFailed(RuntimeError):
    """The solver stopped with an error; ``summary`` holds what was written."""

    def __init__(self, message: str, summary: dict[str, Any]):
        super().__init__(message)
        self.summary = summary


def build(case: Case, parts: ParticleSet | None = None) -> tuple[Simulation, ParticleSet]:
    """A ready-to-step Simulation for a case (particles seeded unless given)."""
    parts = parts if parts is not None else seed(case)
    g, s = case["grid"], case["solver"]
    h = g["cell"]
    ncell = [round(g["size"][0] / h), round(g["size"][1] / h)]
    sim = Simulation()
    sim.set_grid(g["origin"], ncell, h, g["walls"])
    sim.set_materials(case["materials"])
    sim.set_particles(parts.x, parts.v, parts.mass, parts.vol, parts.r, parts.mat)
    contact = case["contact"]
    sim.set_bodies(parts.group, contact=contact["enabled"], friction=contact["friction"],
                   fullness=contact["fullness"])
    sim.set_options(shape=s["shape"], update=s["update"], projection=s["projection"],
                    kinematics=s["kinematics"], domain_scaling=s["domain_scaling"], dt=s.get("dt"),
                    cfl=s["cfl"], gravity=s["gravity"], damping=s["damping"], flip=s["flip"],
                    projection_stabilization=s["projection_stabilization"])
    return sim, parts


@dataclass
class RunResult:
    summary: dict[str, Any]
    series: dict[str, np.ndarray]
    final: dict[str, np.ndarray]
    parts: ParticleSet
    snapshots: list[float] = field(default_factory=list)


def _progress(total: float, enabled: bool, desc: str):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="s(sim)", bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                "t={n:.4g}/{total:.4g} s [{elapsed}<{remaining}{postfix}]", leave=False, dynamic_ncols=True,
                disable=None)  # None: off when stderr is not a terminal (CI logs)


def run(case: Case, out_dir: Path | None = None, progress: bool = True,
        snapshots: bool = True) -> RunResult:
    """Run a case to t_end. With ``out_dir`` the contract outputs are written there."""
    s = case["solver"]
    t_end, dt_out, dt_ser = s["t_end"], s["output_every"], s["series_every"]
    sim, parts = build(case)
    probes = ProbeSet(case, parts)
    columns = SERIES_BASE + probes.names
    rows: dict[str, list[float]] = {c: [] for c in columns}
    writer = series = None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        series = SeriesWriter(out_dir / "series.csv", columns)
        writer = SnapshotWriter(out_dir) if snapshots else None
    summary: dict[str, Any] = {
        "case": case.name, "case_file": str(case.path) if case.path else None, "overrides": case.overrides,
        "parameters": case.data, "status": "running", "particles": parts.n, "steps": 0, "simulated_time": 0.0,
        "wall_s": 0.0, "particle_updates_per_s": 0.0,
    }
    snap_times: list[float] = []
    bar = _progress(t_end, progress, case.name)
    t0 = time.perf_counter()
    t = 0.0
    total_steps = 0

    def sample(state):
        d = sim.diagnostics()
        row = {c: d.get(c, 0.0) for c in SERIES_BASE}
        row["t"] = t
        row.update(probes.evaluate(state["x"], state["v"]))
        for c in columns:
            rows[c].append(row[c])
        if series is not None:
            series.write(row)

    def snapshot(state):
        snap_times.append(t)
        if writer is not None:
            writer.write(t, {
                "position": state["x"], "velocity": state["v"], "pressure": pressure(state["sigma"]),
                "stress": state["sigma"], "material": parts.mat.astype(np.int32), "volume": state["vol"],
                "jacobian": state["F"][:, 0] * state["F"][:, 3] - state["F"][:, 1] * state["F"][:, 2],
                "corners": corners(state["x"], state["r"])})

    try:
        state = sim.state()
        sample(state)
        snapshot(state)
        n_out = 1
        n_ser = 1
        while t < t_end * (1 - 1e-12):
            t_next_out = min(n_out * dt_out, t_end)
            t_next = min(n_ser * dt_ser, t_next_out)
            steps, t = sim.advance(t_next, max_steps=max(1, s["max_steps"] - total_steps))
            total_steps += steps
            if total_steps >= s["max_steps"] and t < t_next * (1 - 1e-12):
                raise CpdiError(2, f"reached solver.max_steps = {s['max_steps']} at t = {t:.6g} s; "
                                   "raise max_steps or shorten t_end")
            state = sim.state()
            if t >= t_next * (1 - 1e-12):
                n_ser += 1
                sample(state)
            if t >= t_next_out * (1 - 1e-12):
                n_out += 1
                snapshot(state)
            if bar is not None:
                wall = time.perf_counter() - t0
                bar.set_postfix_str(f"steps={total_steps} {parts.n * total_steps / max(wall, 1e-9) / 1e6:.2f} Mpu/s",
                                    refresh=False)
                bar.update(t - bar.n)
        status = "completed"
        reason = None
    except CpdiError as exc:
        status = "failed"
        reason = f"{exc.kind}: {exc}"
        state = None
    finally:
        wall = time.perf_counter() - t0
        if bar is not None:
            bar.close()
        if writer is not None:
            writer.close()
        if series is not None:
            series.close()
        diag = sim.diagnostics()
        summary.update(status=status, steps=int(diag["steps"]), simulated_time=diag["t"], wall_s=wall,
                       particle_updates_per_s=parts.n * diag["steps"] / wall if wall > 0 else 0.0,
                       timers=sim.timers(), snapshots=len(snap_times))
        if status != "completed":
            summary["error"] = reason
        if out_dir is not None:
            write_json(out_dir / "summary.json", summary)
    final = sim.state() if state is not None else {}
    sim.close()
    result = RunResult(summary=summary, series={k: np.asarray(v) for k, v in rows.items()}, final=final,
                       parts=parts, snapshots=snap_times)
    if status != "completed":
        raise RunFailed(f"case '{case.name}' failed at t = {summary['simulated_time']:.6g} s: {reason}", summary)
    if not math.isfinite(summary["simulated_time"]):
        raise RunFailed(f"case '{case.name}' produced a non-finite time", summary)
    return result
