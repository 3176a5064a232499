"""Run one case: build the solver from a validated case, step it, write the outputs.

The loop advances the Fortran solver in chunks between series samples (no I/O inside
the solver), evaluates probes, appends ``series.csv`` and writes snapshots at
``output_every``. On a solver error the outputs written so far are kept,
``summary.json`` gets status ``failed`` with the reason, and :class:`RunFailed` is raised.

Checkpoint and restart: with ``checkpoint_every`` the full state goes to
``checkpoint.h5`` (see :mod:`harness.checkpoint`) at the first step boundary at or after
each multiple of that simulated time; ``restart`` continues from one, bit for bit. With
``stop`` (e.g. :class:`StopOnSignal`) the solver advances in pieces of about
``STOP_LATENCY_S`` of wall time and the run ends at the next piece boundary once ``stop()``
returns a reason: a final checkpoint is written, ``summary.json`` gets status
``interrupted``, and :class:`RunInterrupted` is raised. Neither changes a bit of the
results: pieces end on step boundaries, and the solver's steps depend only on the target
time of the chunk, never on where a call stopped.
"""

from __future__ import annotations

import math
import shutil
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from harness import checkpoint
from harness.cases import Case, CaseError
from harness.output import SeriesWriter, SnapshotWriter, corners, write_json
from harness.probes import ProbeSet, SurfacePressure
from harness.seeding import ParticleSet, seed
from harness.solver import MODELS, CpdiError, Simulation, pressure

SERIES_BASE = ["t", "kinetic_energy", "strain_energy", "momentum_x", "momentum_y", "gravity_work",
               "body_force_work", "friction_work", "viscous_dissipation", "mass", "steps", "dt", "cg_iterations",
               "cg_residual", "correction_work"]


STOP_LATENCY_S = 0.2  # wall time per solver call while a stop request is watched


class RunFailed(RuntimeError):
    """The solver stopped with an error; ``summary`` holds what was written."""

    def __init__(self, message: str, summary: dict[str, Any]):
        super().__init__(message)
        self.summary = summary

    def __reduce__(self):  # pmap returns it from a worker
        return type(self), (str(self), self.summary)


class RunInterrupted(RuntimeError):
    """The run was stopped on request; ``summary`` holds what was written, ``exit_code`` the
    conventional status (128 + signal number) when a signal asked for it."""

    def __init__(self, message: str, summary: dict[str, Any], exit_code: int):
        super().__init__(message)
        self.summary = summary
        self.exit_code = exit_code


class StopOnSignal:
    """Context manager: SIGINT and SIGTERM ask the run to stop at the next piece boundary
    instead of killing it. Calling the object returns the reason once a signal came."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def _handler(self, signum, frame) -> None:
        self.signum = signum

    def __enter__(self) -> StopOnSignal:
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def __call__(self) -> str | None:
        return None if self.signum is None else signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        return 128 + (self.signum or 0)


def build(case: Case, parts: ParticleSet | None = None) -> tuple[Simulation, ParticleSet]:
    """A ready-to-step Simulation for a case (particles seeded unless given)."""
    parts = parts if parts is not None else seed(case)
    g, s = case["grid"], case["solver"]
    h = g["cell"]
    ncell = [round(g["size"][0] / h), round(g["size"][1] / h)]
    sim = Simulation()
    sim.set_grid(g["origin"], ncell, h, g["walls"])
    mats = case["materials"]
    if s["fluid"] == "incompressible":  # incompressible water has no bulk modulus; the solver's check wants one
        mats = [{**m, "bulk_modulus": m.get("bulk_modulus", 1.0)} for m in mats]
    sim.set_materials(mats)
    for i, m in enumerate(mats):
        if "velocity_table" in m:
            sim.set_velocity_table(i, m["velocity_table"])
    sim.set_particles(parts.x, parts.v, parts.mass, parts.vol, parts.r, parts.mat)
    contact = case["contact"]
    sim.set_bodies(parts.group, contact=contact["enabled"], friction=contact["friction"],
                   fullness=contact["fullness"])
    sim.set_options(shape=s["shape"], update=s["update"], projection=s["projection"],
                    kinematics=s["kinematics"], domain_scaling=s["domain_scaling"], dt=s.get("dt"),
                    cfl=s["cfl"], gravity=s["gravity"], damping=s["damping"], flip=s["flip"],
                    projection_stabilization=s["projection_stabilization"], fluid=s["fluid"],
                    transfer=s["transfer"], cg_tolerance=s["cg_tolerance"],
                    cg_max_iterations=s["cg_max_iterations"], volume_correction=s["volume_correction"],
                    correction_tolerance=s["correction_tolerance"],
                    pressure_precond=s["pressure_precond"],
                    solid_substeps=s["solid_substeps"])
    if any(s["body_acceleration"]):
        sim.set_body_force(np.tile(np.asarray(s["body_acceleration"], dtype=np.float64), (parts.x.shape[0], 1)))
    return sim, parts


def check_feasible(case: Case, sim: Simulation) -> None:
    """Refuse a run whose first time step forecasts more than solver.max_estimated_steps
    steps to t_end, naming what sets the step and how to override."""
    s = case["solver"]
    dt = s.get("dt") or s["cfl"] * sim.stable_dt()
    n = s["t_end"] / dt if dt > 0 else math.inf
    if n <= s["max_estimated_steps"]:
        return
    h = case["grid"]["cell"]
    why = f"the time step {dt:.3g} s"
    if s["fluid"] != "incompressible":
        fluids = [(m["bulk_modulus"] / m["density"]) ** 0.5 for m in case["materials"] if "bulk_modulus" in m]
        solids = [((m["youngs_modulus"] * (1 - m["poisson_ratio"]) / ((1 + m["poisson_ratio"])
                                                                        * (1 - 2 * m["poisson_ratio"])))
                   / m["density"]) ** 0.5 for m in case["materials"] if "youngs_modulus" in m]
        c, who = max([(c, m["name"]) for c, m in zip(fluids, [m for m in case["materials"] if "bulk_modulus" in m],
                                                             strict=True)]
                     + [(c, m["name"]) for c, m in zip(solids, [m for m in case["materials"]
                                                                 if "youngs_modulus" in m], strict=True)],
                     default=(0.0, "?"))
        why += (f", set by the sound speed {c:.4g} m/s of material '{who}' (bulk_modulus or youngs_modulus) on "
                f"cells of {h:g} m")
    raise CaseError(f"{case.name}: {why} forecasts {n:.3g} steps to t_end = {s['t_end']:g} s, more than "
                    f"solver.max_estimated_steps = {s['max_estimated_steps']:.3g}; use fluid = \"incompressible\" "
                    "or a reduced bulk modulus (c = 10 sqrt(2 g H) is the usual choice), a coarser grid or a "
                    "shorter t_end, or raise solver.max_estimated_steps to run it anyway")


SOLID_MODELS = tuple(m for m in MODELS if m != "newtonian_fluid")   # every model but the water


class WaterLoads:
    """The incompressible water's force and moment on each solid body of a case, per series row:
    columns water_fx_<body>, water_fy_<body> [N/m] and water_moment_<body> [N m/m] (about the
    body's mass centre, counter-clockwise), from Simulation.water_loads() (the last step's load on
    each particle). <body> is the body's name, or body<i> for an unnamed one. None without solids
    in incompressible water (the weakly compressible water's loads are not computed)."""

    def __init__(self, case: Case, parts: ParticleSet):
        models = {m["name"]: m["model"] for m in case["materials"]}
        self.bodies: list[tuple[str, np.ndarray]] = []
        if case["solver"]["fluid"] != "incompressible":
            return
        seen: set[str] = set()
        for i, b in enumerate(case["bodies"]):
            if models[b["material"]] not in SOLID_MODELS:
                continue
            label = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in b["name"]) or f"body{i}"
            if label in seen:
                label = f"{label}{i}"
            seen.add(label)
            self.bodies.append((label, np.flatnonzero(parts.body == i)))
        self.mass = parts.mass

    @property
    def names(self) -> list[str]:
        return [f"water_{q}_{label}" for label, _ in self.bodies for q in ("fx", "fy", "moment")]

    def evaluate(self, sim: Simulation, x: np.ndarray) -> dict[str, float]:
        if not self.bodies:
            return {}
        wl = sim.water_loads()
        out = {}
        for label, idx in self.bodies:
            f, m = wl[idx, :2], self.mass[idx]
            r = x[idx] - np.average(x[idx], axis=0, weights=m)
            out[f"water_fx_{label}"] = float(f[:, 0].sum())
            out[f"water_fy_{label}"] = float(f[:, 1].sum())
            out[f"water_moment_{label}"] = float((r[:, 0] * f[:, 1] - r[:, 1] * f[:, 0]).sum() + wl[idx, 2].sum())
        return out


@dataclass
class RunResult:
    summary: dict[str, Any]
    series: dict[str, np.ndarray]
    final: dict[str, np.ndarray]
    parts: ParticleSet
    snapshots: list[float] = field(default_factory=list)


def _progress(total: float, enabled: bool, desc: str, initial: float = 0.0):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="s(sim)", bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                "t={n:.4g}/{total:.4g} s [{elapsed}<{remaining}{postfix}]", leave=False, dynamic_ncols=True,
                disable=None)  # None: off when stderr is not a terminal (CI logs)


def _resume_snapshots(out_dir: Path, ck: checkpoint.Checkpoint) -> SnapshotWriter:
    """The snapshot file of the checkpoint's run (copied into out_dir if that is elsewhere),
    cut back to the snapshots written before the checkpoint."""
    src, dst = ck.path.parent / "snapshots.h5", out_dir / "snapshots.h5"
    keep = len(ck.runner["snap_times"])
    try:
        if not (dst.exists() and src.samefile(dst)):
            shutil.copyfile(src, dst)
        return SnapshotWriter(out_dir, keep=keep)
    except (OSError, KeyError, ValueError) as exc:
        raise checkpoint.CheckpointError(
            f"cannot continue the snapshots: {src} should hold the {keep} snapshots written before the checkpoint "
            f"({exc}); restore that file, or rerun from t = 0 without --restart") from None


def run(case: Case, out_dir: Path | None = None, progress: bool = True, snapshots: bool = True,
        checkpoint_every: float | None = None, restart: str | Path | None = None,
        stop: Callable[[], str | None] | None = None) -> RunResult:
    """Run a case to t_end. With ``out_dir`` the contract outputs are written there;
    ``checkpoint_every``, ``restart`` and ``stop`` as described in the module doc."""
    s = case["solver"]
    t_end, dt_out, dt_ser = s["t_end"], s["output_every"], s["series_every"]
    if out_dir is None and (checkpoint_every is not None or restart is not None):
        raise ValueError("checkpoint_every and restart need an output directory")
    sim, parts = build(case)
    try:
        check_feasible(case, sim)
    except CaseError:
        sim.close()
        raise
    probes = ProbeSet(case, parts)
    loads = WaterLoads(case, parts)
    surface = SurfacePressure(case, parts)
    columns = SERIES_BASE + probes.names + surface.names + loads.names
    rows: dict[str, list[float]] = {c: [] for c in columns}
    ck = None
    if restart is not None:  # read and check everything before any output is touched
        ck = checkpoint.load(restart, case, parts)
        if list(ck.rows) != columns:
            raise checkpoint.CheckpointError(f"{ck.path} has series columns {list(ck.rows)}, this harness writes "
                                             f"{columns}; rerun from t = 0 without --restart")
        try:
            sim.set_full_state(ck.particles, ck.scalars)
        except CpdiError as exc:
            raise checkpoint.CheckpointError(f"{ck.path}: {exc}") from None
        rows = ck.rows
    writer = series = None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        if snapshots:
            writer = SnapshotWriter(out_dir) if ck is None else _resume_snapshots(out_dir, ck)
        series = SeriesWriter(out_dir / "series.csv", columns)
        for i in range(len(rows["t"])):  # a restart rewrites the rows up to its checkpoint
            series.write({c: rows[c][i] for c in columns})
    summary: dict[str, Any] = {
        "case": case.name, "case_file": str(case.path) if case.path else None, "overrides": case.overrides,
        "parameters": case.data, "status": "running", "particles": parts.n, "steps": 0, "simulated_time": 0.0,
        "wall_s": 0.0, "particle_updates_per_s": 0.0,
    }
    snap_times: list[float] = []
    t = 0.0
    total_steps = 0
    wall_before = 0.0
    if ck is not None:
        snap_times, total_steps, wall_before = ck.runner["snap_times"], ck.runner["total_steps"], ck.runner["wall_s"]
        t = float(ck.scalars[0])
        summary["restarted_from"] = {"checkpoint": str(ck.path), "t": t}
    ckpt_path = out_dir / checkpoint.FILENAME if out_dir is not None else None

    def ckpt_after(t_now: float) -> float:  # the next multiple of checkpoint_every
        if checkpoint_every is None:
            return math.inf
        return (math.floor(t_now / checkpoint_every * (1 + 1e-12)) + 1) * checkpoint_every

    next_ckpt = ckpt_after(t)
    bar = _progress(t_end, progress, case.name, initial=t)
    t0 = time.perf_counter()

    def sample(state):
        d = sim.diagnostics()
        row = {c: d.get(c, 0.0) for c in SERIES_BASE}
        row["t"] = t
        row.update(probes.evaluate(state["x"], state["v"]))
        row.update(surface.evaluate(sim, state["x"]))
        row.update(loads.evaluate(sim, state["x"]))
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
                "corners": corners(state["x"], state["r"])}, grid=cell_fields())

    def cell_fields():  # the pressure grid of incompressible water
        if s["fluid"] != "incompressible":
            return None
        return {"origin": case["grid"]["origin"], "h": case["grid"]["cell"], **sim.grid_pressure()}

    def save_checkpoint():
        checkpoint.save(ckpt_path, case, parts, sim.get_full_state(),
                        {"n_out": n_out, "n_ser": n_ser, "total_steps": total_steps, "snap_times": snap_times,
                         "wall_s": wall_before + time.perf_counter() - t0}, rows)
        summary["checkpoint"] = {"path": str(ckpt_path), "t": t}

    status, reason, state, interrupted = "failed", "aborted by a Python exception", None, None
    try:
        if ck is None:
            state = sim.state()
            sample(state)
            snapshot(state)
            n_out = n_ser = 1
        else:
            n_out, n_ser = ck.runner["n_out"], ck.runner["n_ser"]
        piece = 1  # steps per solver call while a stop request is watched
        while t < t_end * (1 - 1e-12):
            if stop is not None and (interrupted := stop()) is not None:
                break
            t_next_out = min(n_out * dt_out, t_end)
            t_next = min(n_ser * dt_ser, t_next_out)
            budget = max(1, s["max_steps"] - total_steps)
            w0 = time.perf_counter()
            steps, t = sim.advance(t_next, max_steps=budget if stop is None else min(budget, piece),
                                   land=t_next >= t_end * (1 - 1e-12))  # incompressible water lands at t_end only
            total_steps += steps
            if stop is not None and steps:
                piece = max(1, min(8 * piece, int(STOP_LATENCY_S * steps / max(time.perf_counter() - w0, 1e-9))))
            reached = t >= t_next * (1 - 1e-12)
            if not reached and total_steps >= s["max_steps"]:
                raise CpdiError(2, f"reached solver.max_steps = {s['max_steps']} at t = {t:.6g} s; "
                                   "raise max_steps or shorten t_end")
            if reached:  # (incompressible water, which does not land, may have passed more sample times)
                state = sim.state()
                n_ser += 1
                while n_ser * dt_ser < t * (1 - 1e-12):
                    n_ser += 1
                sample(state)
                if t >= t_next_out * (1 - 1e-12):
                    n_out += 1
                    while n_out * dt_out < t * (1 - 1e-12):
                        n_out += 1
                    snapshot(state)
            if t >= next_ckpt * (1 - 1e-12) and t < t_end * (1 - 1e-12):
                save_checkpoint()
                next_ckpt = ckpt_after(t)
            if bar is not None:
                wall = time.perf_counter() - t0
                bar.set_postfix_str(f"steps={total_steps} {parts.n * total_steps / max(wall, 1e-9) / 1e6:.2f} Mpu/s",
                                    refresh=False)
                bar.update(t - bar.n)
        if interrupted is None:
            status, reason = "completed", None
        else:
            if ckpt_path is not None:
                save_checkpoint()
            status, reason = "interrupted", f"interrupted by {interrupted} at t = {t:.6g} s (step {total_steps})"
    except (CpdiError, checkpoint.CheckpointError) as exc:
        status = "failed"
        reason = f"{getattr(exc, 'kind', 'checkpoint')}: {exc}"
        state = None
    finally:
        wall = wall_before + time.perf_counter() - t0
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
        if status == "interrupted":
            summary["reason"] = reason
        elif status != "completed":
            summary["error"] = reason
        if out_dir is not None:
            write_json(out_dir / "summary.json", summary)
    final = sim.state() if state is not None else {}
    sim.close()
    result = RunResult(summary=summary, series={k: np.asarray(v) for k, v in rows.items()}, final=final,
                       parts=parts, snapshots=snap_times)
    if status == "interrupted":
        raise RunInterrupted(f"case '{case.name}' {reason}", summary, getattr(stop, "exit_code", 130))
    if status != "completed":
        raise RunFailed(f"case '{case.name}' failed at t = {summary['simulated_time']:.6g} s: {reason}", summary)
    if not math.isfinite(summary["simulated_time"]):
        raise RunFailed(f"case '{case.name}' produced a non-finite time", summary)
    return result
