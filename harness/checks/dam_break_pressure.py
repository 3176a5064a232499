"""Check `dam_break_pressure`: downstream-wall pressure of a dam break, Lobovsky et al. (2014).

cases/dam_break_pressure.toml: H = 0.3 m, L = 0.6 m, tank 1.61 m; sensors 3 (z = 30 mm) and
4 (z = 80 mm) on the downstream wall, 4.2 mm faces, against one recorded repetition
(reference/data/lobovsky_2014_pressure_H300_sensors34_event5.csv). The run is stepped here
in windows of 0.01 t* (t* = t sqrt(g/H)) and the sensor reads the wall column's cell
pressure, linear in height, averaged over its face (harness.water.wall_sensor).

Gates per sensor: first time p/(rho g H) >= 0.1 within 0.1 t* of the record's; mean over
3 <= t* <= 5.5 within 15 %; RMS of the difference of 0.1 t* window means over 3 <= t* <= 6
at most 0.15; and the water's volume change at the end at most 1 %. The two quasi-static
gates (mean, window RMS) are known limitations of the 2D single-phase model
(QUASI_STATIC_LIMITATION): evaluated and reported as XFAIL / XPASS, they do not fail the check;
the rise times and the volume change do.

Beside it, the weakly compressible model (particle pressure of the particles within one cell
of the wall and of the sensor's height) at the reduced bulk modulus that gives
c = 10 sqrt(2 g H), on a coarser grid (h = 0.023 m): labelled as such, not gated.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from harness import cases, parallel, paths, refdata, water
from harness.checks.base import CheckContext, CheckResult, Gate
from harness.runner import build

NAME = "dam_break_pressure"
REQUIREMENT = ("A 0.6 m x 0.3 m water column collapses in a 1.61 m tank; the downstream-wall pressure at 30 and "
               "80 mm follows Lobovsky et al. (2014): first rise within 0.1 t*, mean over 3 <= t* <= 5.5 within "
               "15 %, RMS of 0.1 t* window means <= 0.15 rho g H; water volume change <= 1 %.")
CASE = paths.CASES / "dam_break_pressure.toml"
REF = "lobovsky_2014_pressure_H300_sensors34_event5.csv"
H, RHO, G = 0.3, 1000.0, 9.81
TSTAR = math.sqrt(G / H)
SENSORS = {"3": 0.03, "4": 0.08}
DIAMETER = 0.0042
H_COARSE = 0.023
K_REDUCED = RHO * (10.0 * math.sqrt(2.0 * G * H)) ** 2  # c = 10 sqrt(2 g H)
WC_SETTINGS = ['solver.fluid="weakly_compressible"', 'solver.transfer="flip"', "solver.flip=0.999",
               'solver.projection="cell"', "solver.projection_stabilization=0.1", "solver.cfl=0.4",
               f"materials.0.bulk_modulus={K_REDUCED}"]
SNAP_TSTAR = (2.6, 5.0)
QUASI_STATIC_LIMITATION = (
    "single-phase inviscid 2D water on slip walls: the floor jet turns up the wall faster and thinner than in "
    "the 3D, aerated experiment, so the wall pressure falls off with height more steeply than measured (sensor 3 "
    "about 35 % high, sensor 4 8-20 % low) at every h (0.023-0.005 m), ppc (2-4), cfl (0.2-0.5) and transfer "
    "(FLIP, APIC) tried; see docs/notes/incompressible_water_measurements.md")


def _run(case, incompressible: bool) -> dict:
    """Step the case in 0.01 t* windows; sensor pressures [rho g H] and two snapshots."""
    sim, parts = build(case)
    g = case["grid"]
    h, t_end = g["cell"], case["solver"]["t_end"]
    ncell = (round(g["size"][0] / h), round(g["size"][1] / h))
    dt_s = 0.01 / TSTAR
    t, rows, snaps = 0.0, [], {}
    try:
        while t < t_end * (1 - 1e-12):
            _, t = sim.advance(min(t + dt_s, t_end), land=False)
            st = sim.state()
            row = [t * TSTAR]
            if incompressible:
                cp = sim.grid_pressure()["pressure"]
                row += [water.wall_sensor(cp, g["origin"], h, "right", z, DIAMETER) / (RHO * G * H)
                        for z in SENSORS.values()]
            else:
                x = st["x"]
                p = -(st["sigma"][:, 0] + st["sigma"][:, 1] + st["sigma"][:, 3]) / 3.0
                xw = g["origin"][0] + g["size"][0]
                for z in SENSORS.values():
                    sel = (x[:, 0] > xw - h) & (np.abs(x[:, 1] - z) < h)
                    row.append(float(p[sel].mean()) / (RHO * G * H) if sel.any() else 0.0)
            rows.append(row)
            for ts in SNAP_TSTAR:
                if ts not in snaps and t * TSTAR >= ts - 1e-9:
                    p = -(st["sigma"][:, 0] + st["sigma"][:, 1] + st["sigma"][:, 3]) / 3.0
                    snaps[ts] = (st["x"].copy(), p / (RHO * G * H))
        fin = sim.state()
        d = sim.diagnostics()
        return {"series": np.array(rows), "snaps": snaps, "steps": int(d["steps"]),
                "cg_total": float(d["cg_iterations_total"]), "particles": parts.n,
                "volume_change": abs(water.volume_change(fin["x"], fin["vol"], g["origin"], h, ncell))}
    finally:
        sim.close()


def _window_means(t, p, lo, hi, width=0.1):
    edges = np.arange(lo, hi + 1e-9, width)
    return np.array([p[(t >= a) & (t < a + width)].mean() if np.any((t >= a) & (t < a + width)) else np.nan
                     for a in edges[:-1]])


def sensor_metrics(t, p, tr, pr) -> dict:
    """Rise time, quasi-static mean and window-mean RMS of one sensor against the record."""
    def first(tt, pp):
        i = np.flatnonzero(pp >= 0.1)
        return float(tt[i[0]]) if i.size else math.inf

    m_sim = float(p[(t >= 3) & (t <= 5.5)].mean())
    m_ref = float(pr[(tr >= 3) & (tr <= 5.5)].mean())
    ws, wr = _window_means(t, p, 3.0, 6.0), _window_means(tr, pr, 3.0, 6.0)
    return {"rise_dt": abs(first(t, p) - first(tr, pr)), "mean_rel": abs(m_sim - m_ref) / m_ref,
            "window_rms": float(np.sqrt(np.nanmean((ws - wr) ** 2))), "mean": m_sim, "mean_ref": m_ref}


def run(ctx: CheckContext) -> CheckResult:
    res = CheckResult(NAME, REQUIREMENT)
    ref = refdata.read(REF)
    h_inc = H_COARSE if ctx.quick else 0.01
    inc, wc = parallel.pmap(_run, [(cases.load(CASE, [f"grid.cell={h_inc}"]), True),
                                   (cases.load(CASE, [*WC_SETTINGS, f"grid.cell={H_COARSE}"]), False)])
    for label, r in (("incompressible", inc), ("weakly compressible", wc)):
        if isinstance(r, Exception):
            raise RuntimeError(f"the {label} run failed: {r}")
    for k, name in enumerate(SENSORS, start=1):
        for label, r in (("", inc), ("wc_", wc)):
            m = sensor_metrics(r["series"][:, 0], r["series"][:, k], ref["t_star"], ref[f"p{name}"])
            for key, v in m.items():
                res.metrics[f"{label}sensor{name}_{key}"] = v
        m = {k: res.metrics[f"sensor{name}_{k}"] for k in ("rise_dt", "mean_rel", "window_rms")}
        res.gates += [
            Gate.at_most(f"sensor{name}_rise_dt", m["rise_dt"], 0.1, "first p >= 0.1 rho g H [t*]"),
            Gate.at_most(f"sensor{name}_mean_rel", m["mean_rel"], 0.15, "mean over 3 <= t* <= 5.5",
                         known_limitation=QUASI_STATIC_LIMITATION),
            Gate.at_most(f"sensor{name}_window_rms", m["window_rms"], 0.15, "0.1 t* window means, 3 <= t* <= 6",
                         known_limitation=QUASI_STATIC_LIMITATION)]
    res.metrics.update({"volume_change": inc["volume_change"], "wc_volume_change": wc["volume_change"],
                        "steps": float(inc["steps"]), "wc_steps": float(wc["steps"]),
                        "cg_iterations_per_step": inc["cg_total"] / max(inc["steps"], 1)})
    res.gates.append(Gate.at_most("volume_change", inc["volume_change"], 0.01, "overfilled-cell volume / water volume"))

    fig, axes = plt.subplots(2, 1, figsize=(7.5, 6), sharex=True)
    for ax, (k, name) in zip(axes, enumerate(SENSORS, start=1), strict=True):
        ax.plot(ref["t_star"][::20], ref[f"p{name}"][::20], ".", ms=2, color="0.5", label="Lobovsky et al. (2014)")
        ax.plot(wc["series"][:, 0], wc["series"][:, k], "-", lw=0.6, alpha=0.45, color="tab:orange", zorder=1,
                label=f"weakly compressible, K = {K_REDUCED:.2g} Pa (c = 10 sqrt(2gH)), h = {H_COARSE} m")
        ax.plot(inc["series"][:, 0], inc["series"][:, k], "-", lw=1.2, color="tab:blue", zorder=3,
                label=f"incompressible, h = {h_inc} m")
        ax.set_ylabel(f"sensor {name}: p / (rho g H)")
        ax.set_ylim(-0.5, 3.0)
        ax.text(0.02, 0.06, f"incompressible: mean err {res.metrics[f'sensor{name}_mean_rel']:.0%}, window RMS "
                           f"{res.metrics[f'sensor{name}_window_rms']:.2f}; weakly compr.: "
                           f"{res.metrics[f'wc_sensor{name}_mean_rel']:.0%}, "
                           f"{res.metrics[f'wc_sensor{name}_window_rms']:.2f}", transform=ax.transAxes, fontsize=7,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"}, zorder=5)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[1].set_xlabel("t* = t sqrt(g/H)")
    fig.tight_layout()
    fig.savefig(ctx.fig_dir / "dam_break_pressure_sensors.png", dpi=120)
    plt.close(fig)

    fig, axes = plt.subplots(2, 2, figsize=(9, 4.5), sharex=True, sharey=True)
    for i, (label, r) in enumerate((("incompressible", inc), ("weakly compressible", wc))):
        for j, ts in enumerate(SNAP_TSTAR):
            ax = axes[i, j]
            if ts in r["snaps"]:
                x, p = r["snaps"][ts]
                sc = ax.scatter(x[:, 0], x[:, 1], c=p, s=1, cmap="viridis", vmin=0.0, vmax=1.5)
            ax.set_title(f"{label}, t* = {ts}", fontsize=8)
            ax.set_aspect("equal")
    # fixed scale from the hydrostatic range (p / rho g H from 0 at the surface to 1 at the initial column's
    # foot, with headroom for the surge), not from the extremes: impact spikes saturate instead of flattening it
    fig.colorbar(sc, ax=axes, label="p / (rho g H) (0-1.5: hydrostatic range)", extend="both")
    fig.savefig(ctx.fig_dir / "dam_break_pressure_fields.png", dpi=120)
    plt.close(fig)
    res.figures += ["dam_break_pressure_sensors.png", "dam_break_pressure_fields.png"]
    res.notes.append(f"incompressible: {inc['particles']} particles, {inc['steps']} steps, "
                     f"{res.metrics['cg_iterations_per_step']:.0f} CG iterations per step; weakly compressible "
                     f"(reduced K, h = {H_COARSE} m): {wc['steps']} steps.")
    return res
