"""Check `dam_break_pressure`: downstream-wall pressure of a dam break, Lobovsky et al. (2014).

cases/dam_break_pressure.toml: H = 0.3 m, L = 0.6 m, tank 1.61 m; sensors 3 (z = 30 mm) and
4 (z = 80 mm) on the downstream wall, 4.2 mm faces. The run is stepped in windows of 0.01 t*
(t* = t sqrt(g/H)) and each sensor is read two ways: the wall column's cell pressure, linear in
height, averaged over a 4.2 mm disc (harness.water.wall_sensor, "ours"), and as the 2D SPH
references define it (harness.water.kernel_wall_sensor: a Shepard Wendland C2 average of the
water particles' pressures, negatives clipped, support 8 particle spacings, at 10 points of a
4.2 mm segment on the wall).

Code-to-code gates (issue 38), against the converged 2D single-phase reference
(reference/data/lobovsky_2d_numerical/, TrixiParticles EDAC H/400: means 0.822 and 0.363):
a resolution study at h = H/30, H/60 (quick tier H/20, H/30; H/120, the issue's third level,
passes every gate and runs to t* = 6 in 230 s on two threads, but in the full tier it takes
make verify past its 15 minutes on the 2-core machine, docs/notes/performance_measurements.md;
the runs from H/60 on use the multigrid preconditioner; the runs other than H/30, the experiment's, end at t* = 5.5, the
end of the gated window; the full tier's finest run starts with verify, beside the checks before
this one); at the two finest h the mean over 3 <= t* <= 5.5 (references'
definition) within 10 %; at the finest h the sustained impact time (the first sample from which
p* stays >= 0.1 for 0.05 t*) within 0.1 t* of the reference's; and the mean's error at the finest h no
larger than at the coarsest (plus 0.02 for the window mean's sampling noise).

Against the one recorded repetition of the experiment
(reference/data/lobovsky_2014_pressure_H300_sensors34_event5.csv), on the H/30 run: first time
p/(rho g H) >= 0.1 within 0.1 t* of the record's (gated), mean over 3 <= t* <= 5.5 within 15 % and
RMS of 0.1 t* window means over 3 <= t* <= 6 at most 0.15 (known limitations, XFAIL / XPASS: the
2D single-phase references read 0.82 and 0.36 against the record's 0.63 and 0.52); the water's
volume change at the end at most 1 % (every run).

Beside it, the weakly compressible model (particle pressure of the particles within one cell
of the wall and of the sensor's height) at the reduced bulk modulus that gives
c = 10 sqrt(2 g H), on a coarser grid (h = 0.023 m): labelled as such, not gated.
"""

from __future__ import annotations

import math
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from harness import cases, parallel, paths, refdata, water
from harness.checks import registry
from harness.checks.base import CheckContext, CheckResult, Gate, body_bounds, gravity, material
from harness.runner import build

NAME = "dam_break_pressure"
CASE = paths.CASES / "dam_break_pressure.toml"
REQUIREMENT = registry.requirement(CASE)   # one source: the case file
REF = "lobovsky_2014_pressure_H300_sensors34_event5.csv"
REF_2D = "lobovsky_2d_numerical/trixiparticles_edac_400.csv"   # the gated code-to-code reference
REF_2D_SHOWN = {"TrixiParticles WCSPH H/400": "lobovsky_2d_numerical/trixiparticles_wcsph_400.csv"}
REF_DECOURCY = "lobovsky_2d_numerical/decourcy2024_sensors.csv"
_CASE = cases.load(CASE)
H = body_bounds(_CASE, "column")[1][1]   # the column's height
RHO, G = material(_CASE, "water")["density"], gravity(_CASE)
TSTAR = math.sqrt(G / H)
SENSORS = {"3": 0.03, "4": 0.08}
DIAMETER = 0.0042
KERNEL_SPACINGS = 8.0   # the references' sensor support: 8 initial particle spacings
# h = H/N. H/120 passes every gate but does not fit make verify's 15 minutes on two cores
# (docs/notes/performance_measurements.md, "The full tier with H/120")
LEVELS_FULL = (30, 60)
LEVELS_QUICK = (20, 30)
MULTIGRID_FROM = 60   # N >= this: the multigrid preconditioner (CG iterations about constant in h)
EXPERIMENT_LEVEL = 30   # the run the experiment's gates read (the check's grid before issue 38)
MEAN_TOL_2D, IMPACT_TOL_2D, TREND_NOISE = 0.10, 0.1, 0.02
H_COARSE = 0.023
K_REDUCED = RHO * (10.0 * math.sqrt(2.0 * G * H)) ** 2  # c = 10 sqrt(2 g H)
WC_SETTINGS = ['solver.fluid="weakly_compressible"', 'solver.transfer="flip"', "solver.flip=0.999",
               'solver.projection="cell"', "solver.projection_stabilization=0.1", "solver.cfl=0.4",
               f"materials.0.bulk_modulus={K_REDUCED}"]
SNAP_TSTAR = (2.6, 5.0)
# Code-to-code comparisons reported but not gated, with the reason (none now). Sensor 4 was listed
# here while the volume correction was one-sided (it read 19-22 % above the 2D references at every h);
# the two-sided correction (branch s45-vc2, docs/notes/dam_break_pressure_sensor4.md) brings it
# within 6 %, and its gates are back.
NOT_GATED_2D: dict[str, str] = {}
QUASI_STATIC_LIMITATION = (
    "a 2D single-phase model does not reach the experiment's quasi-static level: the converged 2D references "
    "(TrixiParticles EDAC and WCSPH at H/400, De Courcy et al. 2024) read 0.82 and 0.36 rho g H at sensors 3 and 4 "
    "against the record's 0.63 and 0.52 (+30 %, -30 %), and this model is gated against them instead; "
    "see reference/data/lobovsky_2d_numerical/README.md and docs/notes/dam_break_pressure_sensor4.md")


def _run(case, incompressible: bool) -> dict:
    """Step the case in 0.01 t* windows; sensor pressures [rho g H] (ours, then the references'
    definition for the incompressible water) and two snapshots."""
    sim, parts = build(case)
    g = case["grid"]
    h, t_end = g["cell"], case["solver"]["t_end"]
    ncell = (round(g["size"][0] / h), round(g["size"][1] / h))
    xw = g["origin"][0] + g["size"][0]
    support = KERNEL_SPACINGS * h / case["bodies"][0]["ppc"]
    dt_s = 0.01 / TSTAR   # not the case's: a sample every 0.01 t*
    t, rows, snaps = 0.0, [], {}
    t0 = time.perf_counter()
    try:
        while t < t_end * (1 - 1e-12):
            _, t = sim.advance(min(t + dt_s, t_end), land=False)
            st = sim.state()
            row = [t * TSTAR]
            x = st["x"]
            p = -(st["sigma"][:, 0] + st["sigma"][:, 1] + st["sigma"][:, 3]) / 3.0
            if incompressible:
                cp = sim.grid_pressure()["pressure"]
                row += [water.wall_sensor(cp, g["origin"], h, "right", z, DIAMETER) / (RHO * G * H)
                        for z in SENSORS.values()]
                near = x[:, 0] > xw - support
                row += [water.kernel_wall_sensor(x[near], p[near], st["vol"][near], xw, z, DIAMETER, support)
                        / (RHO * G * H) for z in SENSORS.values()]
            else:
                for z in SENSORS.values():
                    sel = (x[:, 0] > xw - h) & (np.abs(x[:, 1] - z) < h)
                    row.append(float(p[sel].mean()) / (RHO * G * H) if sel.any() else 0.0)
            rows.append(row)
            for ts in SNAP_TSTAR:
                if ts not in snaps and t * TSTAR >= ts - 1e-9:
                    snaps[ts] = (x.copy(), p / (RHO * G * H))
        fin = sim.state()
        d = sim.diagnostics()
        return {"series": np.array(rows), "snaps": snaps, "steps": int(d["steps"]),
                "cg_total": float(d["cg_iterations_total"]), "particles": parts.n, "h": h,
                "wall_s": time.perf_counter() - t0,
                "volume_change": abs(water.volume_change(fin["x"], fin["vol"], g["origin"], h, ncell)),
                "overfill_change": abs(water.overfill_change(fin["x"], fin["vol"], g["origin"], h, ncell))}
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


def window_mean(t, p, lo: float = 3.0, hi: float = 5.5) -> float:
    """Trapezoidal time average of the samples with lo <= t <= hi over the span of those samples
    (the definition of the 2D references' README)."""
    t, p = np.asarray(t, dtype=float), np.asarray(p, dtype=float)
    sel = (t >= lo) & (t <= hi)
    ts, ps = t[sel], p[sel]
    if ts.size < 2:
        return math.nan
    return float(np.sum(0.5 * (ps[1:] + ps[:-1]) * np.diff(ts)) / (ts[-1] - ts[0]))


def sustained_impact(t, p, level: float = 0.1, hold: float = 0.05) -> float:
    """First sample time from which p stays >= level for at least `hold` (every sample up to and
    including the first one at or after t + hold); inf if none. The references' "sustained"
    impact time (their first sample above 0.1 is often a one-sample spike of the run-up jet)."""
    t, p = np.asarray(t, dtype=float), np.asarray(p, dtype=float)
    ok = p >= level
    for i in np.flatnonzero(ok):
        j = int(np.searchsorted(t, t[i] + hold - 1e-9))
        if j < t.size and ok[i:j + 1].all():
            return float(t[i])
    return math.inf


def level_settings(n: int) -> list[str]:
    """Case overrides of the run at h = H/n: the cell, the tank length and grid height as whole
    cells (H/20: 1.605 m = 5.35 H, as the references' H/40 tank, and 0.93 m), the multigrid
    preconditioner from MULTIGRID_FROM on."""
    h = round(H / n, 12)
    case = cases.load(CASE)
    lx, ly = case["grid"]["size"]
    sets = [f"grid.cell={h}"]
    if abs(lx / h - round(lx / h)) > 1e-9 or abs(ly / h - round(ly / h)) > 1e-9:
        sets.append(f"grid.size=[{round(round(lx / h) * h, 12)}, {round(math.ceil(ly / h - 1e-9) * h, 12)}]")
    if n >= MULTIGRID_FROM:
        sets.append('solver.pressure_precond="multigrid"')
    return sets


def reference_2d(name: str = REF_2D) -> dict:
    """A 2D reference's series: t*, and p* per sensor ("3", "4")."""
    d = refdata.read(name)
    return {"t": d["tstar"], **{k: d[f"P{k}"] for k in SENSORS}}


def decourcy() -> dict:
    """De Courcy et al. (2024) digitised curves per sensor: (t*, p*)."""
    d = refdata.read(REF_DECOURCY)
    return {k: (d["tstar"][d["sensor"] == int(k)], d["pstar"][d["sensor"] == int(k)]) for k in SENSORS}


EARLY_SECONDS = 130   # the finest run's time on one core, about (parallel.submit's priority: the longest first)
GATED_END = 5.5   # t*: the code-to-code gates read 3 <= t* <= 5.5; the runs beside the experiment's end there


def level_case(n: int):
    """The incompressible run at h = H/n: the experiment's level to t* = 6 (its window RMS reads up
    to 6), the others to the end of the code-to-code window."""
    sets = level_settings(n)
    if n != EXPERIMENT_LEVEL:
        sets.append(f"solver.t_end={GATED_END / TSTAR!r}")
    return cases.load(CASE, sets)


def start_early(ctx: CheckContext) -> None:
    """The full tier's finest run (most of the check's time, on one worker) starts with verify,
    beside the checks before this one."""
    if not ctx.quick:
        n = LEVELS_FULL[-1]
        ctx.early[f"H/{n}"] = parallel.submit(_run, (level_case(n), True), priority=EARLY_SECONDS)


@registry.check(order=9)
def run(ctx: CheckContext) -> CheckResult:
    res = CheckResult(NAME, REQUIREMENT)
    ref = refdata.read(REF)
    ref2d = reference_2d()
    levels = LEVELS_QUICK if ctx.quick else LEVELS_FULL
    early = {n: ctx.early.get(f"H/{n}") for n in levels}
    jobs = [(level_case(n), True) for n in levels if early[n] is None]
    jobs.append((cases.load(CASE, [*WC_SETTINGS, f"grid.cell={H_COARSE}"]), False))
    rest = iter(parallel.pmap(_run, jobs[::-1])[::-1])   # the longest first
    out = [next(rest) if early[n] is None else early[n].result() for n in levels] + [next(rest)]
    for label, r in zip([f"incompressible H/{n}" for n in levels] + ["weakly compressible"], out, strict=True):
        if isinstance(r, Exception):
            raise RuntimeError(f"the {label} run failed: {r}")
    runs, wc = dict(zip(levels, out[:-1], strict=True)), out[-1]
    inc = runs[EXPERIMENT_LEVEL]

    # against the experiment (the H/30 run, the check's grid before issue 38)
    for k, name in enumerate(SENSORS, start=1):
        for label, r in (("", inc), ("wc_", wc)):
            m = sensor_metrics(r["series"][:, 0], r["series"][:, k], ref["t_star"], ref[f"p{name}"])
            for key, v in m.items():
                res.metrics[f"{label}sensor{name}_{key}"] = v
        m = {k: res.metrics[f"sensor{name}_{k}"] for k in ("rise_dt", "mean_rel", "window_rms")}
        res.gates += [
            Gate.at_most(f"sensor{name}_rise_dt", m["rise_dt"], 0.1,
                         f"first p >= 0.1 rho g H [t*], H/{EXPERIMENT_LEVEL}"),
            Gate.at_most(f"sensor{name}_mean_rel", m["mean_rel"], 0.15, "experiment: mean over 3 <= t* <= 5.5",
                         known_limitation=QUASI_STATIC_LIMITATION),
            Gate.at_most(f"sensor{name}_window_rms", m["window_rms"], 0.15,
                         "experiment: 0.1 t* window means, 3 <= t* <= 6", known_limitation=QUASI_STATIC_LIMITATION)]
    res.metrics.update({"volume_change": inc["volume_change"], "wc_volume_change": wc["volume_change"],
                        "steps": float(inc["steps"]), "wc_steps": float(wc["steps"]),
                        "cg_iterations_per_step": inc["cg_total"] / max(inc["steps"], 1)})
    res.gates.append(Gate.at_most("volume_change", inc["volume_change"], 0.01,
                                  f"|occupied - particle volume| / particle volume, H/{EXPERIMENT_LEVEL}"))

    # code to code: the converged 2D reference, resolution study
    rows = []
    fine = levels[-2:]
    for name in SENSORS:
        m_ref = window_mean(ref2d["t"], ref2d[name])
        t_ref = sustained_impact(ref2d["t"], ref2d[name])
        res.metrics[f"sensor{name}_mean_2d_ref"] = m_ref
        res.metrics[f"sensor{name}_impact_2d_ref"] = t_ref
        errs = {}
        for n, r in runs.items():
            t, s = r["series"][:, 0], r["series"]
            k_ours, k_kern = 1 + list(SENSORS).index(name), 3 + list(SENSORS).index(name)
            m_kern, m_ours = window_mean(t, s[:, k_kern]), window_mean(t, s[:, k_ours])
            errs[n] = (m_kern - m_ref) / m_ref
            dt_imp = abs(sustained_impact(t, s[:, k_kern]) - t_ref)
            res.metrics.update({f"sensor{name}_mean_2d_h{n}": m_kern, f"sensor{name}_mean_cell_h{n}": m_ours,
                                f"sensor{name}_mean_rel_2d_h{n}": abs(errs[n]),
                                f"sensor{name}_impact_dt_2d_h{n}": dt_imp})
            if n in fine and name not in NOT_GATED_2D:
                res.gates.append(Gate.at_most(
                    f"sensor{name}_mean_rel_2d_h{n}", abs(errs[n]), MEAN_TOL_2D,
                    f"2D reference (EDAC H/400, {m_ref:.3f}): mean over 3 <= t* <= 5.5, H/{n}"))
            if n == levels[-1]:
                res.gates.append(Gate.at_most(
                    f"sensor{name}_impact_dt_2d_h{n}", dt_imp, IMPACT_TOL_2D,
                    f"2D reference: sustained p* >= 0.1 from t* = {t_ref:.2f}, H/{n} (the finest)"))
        trend = abs(errs[levels[-1]]) - abs(errs[levels[0]])
        res.metrics[f"sensor{name}_mean_err_trend"] = trend
        if name in NOT_GATED_2D:
            res.notes.append(f"Not gated: sensor {name}'s code-to-code mean and its trend. {NOT_GATED_2D[name]}.")
            continue
        res.gates.append(Gate.at_most(
            f"sensor{name}_mean_err_trend", trend, TREND_NOISE,
            f"|mean error| at H/{levels[-1]} minus at H/{levels[0]} (the means approach the 2D reference)"))
    for n, r in runs.items():
        res.metrics[f"volume_change_h{n}"] = r["volume_change"]
        res.metrics[f"overfill_change_h{n}"] = r["overfill_change"]
        res.metrics[f"steps_h{n}"] = float(r["steps"])
        if n != EXPERIMENT_LEVEL:
            res.gates.append(Gate.at_most(f"volume_change_h{n}", r["volume_change"], 0.01,
                                          f"|occupied - particle volume| / particle volume, H/{n}"))
        rows.append(f"| H/{n} | {r['h']:.4g} | {r['particles']} | {r['steps']} | "
                    f"{'multigrid' if n >= MULTIGRID_FROM else 'mic0'} | {r['cg_total'] / max(r['steps'], 1):.1f} | "
                    + " | ".join(f"{res.metrics[f'sensor{s}_mean_2d_h{n}']:.3f} / "
                                 f"{res.metrics[f'sensor{s}_mean_cell_h{n}']:.3f}" for s in SENSORS)
                    + " | " + " | ".join(f"{res.metrics[f'sensor{s}_impact_dt_2d_h{n}']:.2f}" for s in SENSORS)
                    + f" | {r['volume_change']:.2%} | {r['wall_s']:.0f} |")
    res.tables.append(
        "Resolution study against the 2D reference (TrixiParticles EDAC H/400: means "
        + ", ".join(f"{res.metrics[f'sensor{s}_mean_2d_ref']:.3f}" for s in SENSORS)
        + "; sustained impact " + ", ".join(f"{res.metrics[f'sensor{s}_impact_2d_ref']:.2f}" for s in SENSORS)
        + "). Means over 3 <= t* <= 5.5, references' definition / ours (cell pressure):\n\n"
        "| h | m | particles | steps | preconditioner | CG it./step | sensor 3 mean | sensor 4 mean | "
        "sensor 3 impact dt | sensor 4 impact dt | volume change | wall [s] |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows))

    _figures(ctx, res, ref, ref2d, runs, wc)
    per_run = ", ".join(f"H/{n} {r['particles']} particles, {r['steps']} steps, {r['wall_s']:.0f} s"
                        for n, r in runs.items())
    res.notes.append(f"incompressible: {per_run}; weakly compressible (reduced K, h = {H_COARSE} m): "
                     f"{wc['steps']} steps, {wc['wall_s']:.0f} s.")
    return res


def _figures(ctx, res, ref, ref2d, runs, wc) -> None:
    levels = sorted(runs)
    blues = plt.cm.Blues(np.linspace(0.45, 1.0, len(levels)))
    dc = decourcy()
    others = {lab: reference_2d(f) for lab, f in REF_2D_SHOWN.items()}
    fig, axes = plt.subplots(2, 1, figsize=(8, 8), sharex=True)
    for ax, (k, name) in zip(axes, enumerate(SENSORS, start=1), strict=True):
        ax.plot(ref["t_star"][::20], ref[f"p{name}"][::20], ".", ms=2, color="0.45",
                label="Lobovsky et al. (2014), experiment")
        ax.plot(ref2d["t"], ref2d[name], "--", lw=1.0, color="k", zorder=4,
                label="TrixiParticles EDAC H/400 (gated)")
        for lab, r2 in others.items():
            ax.plot(r2["t"], r2[name], ":", lw=1.0, color="tab:red", zorder=4, label=lab)
        ax.plot(*dc[name], "-.", lw=0.8, color="tab:green", zorder=4, label="De Courcy et al. (2024), H/400")
        ax.plot(wc["series"][:, 0], wc["series"][:, k], "-", lw=0.5, alpha=0.2, color="tab:orange", zorder=1,
                label=f"weakly compressible, c = 10 sqrt(2gH), h = {H_COARSE} m")
        for c, n in zip(blues, levels, strict=True):
            r = runs[n]
            ax.plot(r["series"][:, 0], r["series"][:, 2 + k], "-", lw=1.0, color=c, zorder=3,
                    label=f"incompressible, H/{n} (references' sensor)")
        ax.set_ylabel(f"sensor {name}: p / (rho g H)")
        ax.set_ylim(-0.2, 2.5)
        m_ref = res.metrics[f"sensor{name}_mean_2d_ref"]
        txt = "; ".join(f"H/{n}: mean {res.metrics[f'sensor{name}_mean_2d_h{n}']:.3f} "
                        f"({res.metrics[f'sensor{name}_mean_2d_h{n}'] / m_ref - 1:+.0%})" for n in levels)
        ax.text(0.02, 0.88, f"mean 3-5.5 vs 2D ref {m_ref:.3f}: {txt}\n"
                            f"experiment {res.metrics[f'sensor{name}_mean_ref']:.3f}",
                transform=ax.transAxes, fontsize=7, bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"},
                zorder=5)
        ax.axvspan(3.0, 5.5, color="0.9", zorder=0)
    axes[1].set_xlabel("t* = t sqrt(g/H)")
    axes[0].set_xlim(2.0, 6.0)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0.0, 0.13, 1.0, 1.0))
    fig.savefig(ctx.fig_dir / "dam_break_pressure_sensors.png", dpi=120)
    plt.close(fig)

    inc = runs[EXPERIMENT_LEVEL]
    fig, axes = plt.subplots(2, 2, figsize=(9, 4.5), sharex=True, sharey=True)
    sc = None
    for i, (label, r) in enumerate(((f"incompressible H/{EXPERIMENT_LEVEL}", inc), ("weakly compressible", wc))):
        for j, ts in enumerate(SNAP_TSTAR):
            ax = axes[i, j]
            if ts in r["snaps"]:
                x, p = r["snaps"][ts]
                sc = ax.scatter(x[:, 0], x[:, 1], c=p, s=1, cmap="viridis", vmin=0.0, vmax=1.5)
            ax.set_title(f"{label}, t* = {ts}", fontsize=8)
            ax.set_aspect("equal")
    # fixed scale from the hydrostatic range (p / rho g H from 0 at the surface to 1 at the initial column's
    # foot, with headroom for the surge), not from the extremes: impact spikes saturate instead of flattening it
    if sc is not None:
        fig.colorbar(sc, ax=axes, label="p / (rho g H) (0-1.5: hydrostatic range)", extend="both")
    fig.savefig(ctx.fig_dir / "dam_break_pressure_fields.png", dpi=120)
    plt.close(fig)
    res.figures += ["dam_break_pressure_sensors.png", "dam_break_pressure_fields.png"]
