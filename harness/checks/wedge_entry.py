"""Check `wedge_entry`: a wedge enters water at rest at constant speed (issue 40 item 4).

cases/wedge_entry.toml: a prescribed rigid wedge of deadrise beta = 30 degrees moves down at
V = 5 m/s into incompressible water, gravity off, keel at the surface at t = 0. Half the wedge is
modelled, its plane of symmetry the left (slip) wall: the wedge's force is twice the half's
``water_fy_wedge``. Without gravity, viscosity or surface tension the flow has no length scale:
it is self-similar, the pressure coefficient Cp = p / (0.5 rho V^2) a function of z / (Vt) alone
(z the height above the keel) and the vertical force F = C rho V^3 t.

The pressure on the face comes from the case's ``surface_pressure`` probe (harness/probes.py
SurfacePressure: the cell pressure of the first water cell out along the face's normal from each
of 60 points between keel and chine). Three times, V t = 0.03, 0.05, 0.07 m (the first series row at
or after each), give three profiles Cp(z / Vt).

Gates (the issue's):
- self-similarity: the three profiles, interpolated onto one z / (Vt) grid over the range wetted at
  all three times, differ from their mean by at most 10 % of the mean peak (the largest deviation);
- the peak Cp (mean of the three times' peaks) within 10 % of the similarity solution's,
  reference/data/wedge_entry_wagner_similarity.csv (6.927 at 30 degrees: UNVERIFIED, the issue's
  value from memory; see the file's header) and below Wagner's (pi / (2 tan beta))^2 = 7.40;
- the force grows linearly: F / (rho V^3 t) at the three times within 10 % of their mean;
- F / (rho V^3 t) against the similarity solution's: that value was not found (nan in the file),
  so the gate compares with Wagner's pi (pi / (2 tan beta))^2 = 23.25 as an upper bound (below it)
  and reports the ratio; the issue's "within 10 % of the similarity value" is not evaluated.

A prescribed body is a staircase of cells to the water: as the wedge moves, cells join it and the
pressure jumps from step to step (the force by a factor 10 at h = 0.01), with the period h / V of the
body's moving one cell. So each profile and force is a time average (each step weighted by its dt)
over whole such cycles spanning about +/- 20 % (WINDOW) of its time (window_weights), each step's
profile taken against z / (V t) at its own t. The quick tier runs h = 0.01 m; the full tier the resolution study
h = 0.02, 0.01, 0.005 m, gated at the finest, with a table of every h. Not in the gated set yet
(verify.EXPERIMENTAL): the collapse gate fails (docs/notes/wedge_entry.md).
"""

from __future__ import annotations

import math
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from harness import cases, paths, refdata, runner
from harness.checks.base import CheckContext, CheckResult, Gate, put_level_metrics, runs_by_h
from harness.probes import SurfacePressure

NAME = "wedge_entry"
REQUIREMENT = ("A wedge of deadrise 30 degrees enters water at rest at constant speed V (incompressible water, no "
               "gravity): the pressure profiles p/(0.5 rho V^2) against z/(Vt) at three times collapse within 10 % "
               "of their peak; the peak lies within 10 % of the similarity solution's and below Wagner's "
               "(pi/(2 tan beta))^2; F/(rho V^3 t) is constant in time within 10 % and below Wagner's.")
CASE = paths.CASES / "wedge_entry.toml"
REF = "wedge_entry_wagner_similarity.csv"
RHO, V, BETA = 1000.0, 5.0, 30.0
DEPTHS = (0.03, 0.05, 0.07)      # V t of the three profiles [m]
WINDOW = 0.2                     # each profile and force: a time mean over whole cycles h/V, ~ +/- 20 % of its time
T_END = 0.0171                   # past the last window's end (V t = 0.085 m at h = 0.01 and 0.005), V t = 0.0855 m
PROBE = "face"
H_QUICK = (0.01,)
H_FULL = (0.02, 0.01, 0.005)
TOL = 0.10


def reference() -> dict:
    ref = refdata.read(REF)
    row = int(np.flatnonzero(ref["beta_deg"] == BETA)[0])
    return {k: float(v[row]) for k, v in ref.items()}


def simulate(h: float) -> dict:
    """One run at cell size h, stepped one step at a time: after every step the face's pressure
    (the case's surface_pressure probe) and the water's force on the wedge (twice the half's)."""
    case = cases.load(CASE, [f"grid.cell={h}", f"solver.t_end={T_END}"])
    w0 = time.perf_counter()
    sim, parts = runner.build(case)
    surface, loads = SurfacePressure(case, parts), runner.WaterLoads(case, parts)
    keel = case["bodies"][0]["geometry"]["vertices"][0]
    z0 = np.asarray(case["probes"][PROBE]["points"])[:, 1] - keel[1]   # height above the keel
    ts, ps, fs = [], [], []
    try:
        t = 0.0
        while t < T_END * (1 - 1e-12):
            _, t = sim.advance(T_END, max_steps=1, land=True)
            x = sim.state()["x"]
            row = surface.evaluate(sim, x)
            ts.append(t)
            ps.append([row[n] for n in surface.names])
            fs.append(2.0 * loads.evaluate(sim, x)["water_fy_wedge"])   # half the wedge: its symmetry plane is the wall
        steps = int(sim.diagnostics()["steps"])
    finally:
        sim.close()
    return {"h": h, "t": np.array(ts), "cp": np.array(ps) / (0.5 * RHO * V**2), "z0": z0, "force": np.array(fs),
            "steps": steps, "particles": int(parts.n), "wall_s": time.perf_counter() - w0}


def window_weights(t: np.ndarray, tk: float, h: float) -> tuple[np.ndarray, float, float]:
    """Time weights of the steps for the average at time tk: the interval [lo, hi] centred on tk
    spans m whole staircase cycles h / V (the time the body takes to move one cell, over which each
    point of the face meets one cell joining the body), m = round(2 WINDOW tk V / h), at least 1; step
    i, whose pressure acts over (t[i-1], t[i]], weighs the length of that interval inside [lo, hi].
    (A plain mean over the steps within +/- WINDOW tk, the first version, weighed the short steps
    that follow a cell's joining as much as the long ones and covered a fraction of a cycle more or
    less at each time.)"""
    m = max(1, round(2.0 * WINDOW * tk * V / h))
    lo, hi = tk - 0.5 * m * h / V, tk + 0.5 * m * h / V
    prev = np.concatenate([[0.0], t[:-1]])
    w = np.clip(t, lo, hi) - np.clip(prev, lo, hi)
    return w, lo, hi


def window(o: dict, depth: float) -> dict:
    """The profile and force at V t = depth: time averages over whole staircase cycles around it
    (window_weights), each step's profile taken against z / (V t) at its own t (self-similar
    variables)."""
    tk = depth / V
    w, lo, hi = window_weights(o["t"], tk, o["h"])
    sel = np.flatnonzero(w > 0)
    if len(sel) == 0 or hi > o["t"][-1] * (1 + 1e-9):
        raise ValueError(f"the run (to V t = {V * o['t'][-1]:g} m) does not cover the window up to V t = {V * hi:g} m")
    zeta = o["z0"] / (V * tk)
    cp = np.average([np.interp(zeta, o["z0"] / (V * o["t"][i]), o["cp"][i]) for i in sel], axis=0, weights=w[sel])
    coef = float(np.average(o["force"][sel] / (RHO * V**3 * o["t"][sel]), weights=w[sel]))
    return {"t": tk, "zeta": zeta, "cp": cp, "force_coef": coef, "steps": len(sel),
            "cycles": round((hi - lo) * V / o["h"])}


def half_peak_root(zeta: np.ndarray, cp: np.ndarray) -> float:
    """The spray root's position: the z/(Vt) at which the profile, past its peak, first falls to half the
    peak (linear interpolation between the points); nan if it does not."""
    k = int(np.argmax(cp))
    half = 0.5 * cp[k]
    for i in range(k, len(cp) - 1):
        if cp[i] >= half > cp[i + 1]:
            return float(zeta[i] + (zeta[i + 1] - zeta[i]) * (cp[i] - half) / (cp[i] - cp[i + 1]))
    return math.nan


def measures(o: dict, ref: dict) -> dict:
    """Collapse error, peak Cp and force coefficients of one run."""
    prof = [window(o, d) for d in DEPTHS]
    o["profiles"] = prof
    peaks = np.array([p["cp"].max() for p in prof])
    zpk = np.array([p["zeta"][int(np.argmax(p["cp"]))] for p in prof])
    zmax = min(p["zeta"][-1] for p in prof)        # the range every profile covers
    grid = np.linspace(0.0, zmax, 400)
    curves = np.array([np.interp(grid, p["zeta"], p["cp"]) for p in prof])
    dev = np.abs(curves - curves.mean(axis=0)).max(axis=0) / peaks.mean()
    collapse = float(dev.max())
    # diagnostic (not gated): the same below the spray roots, less one cell height in z/(Vt) at the
    # first time (where the three profiles are all wetted), to show where the deviation lies
    roots = [p["zeta"][np.flatnonzero(p["cp"] >= 0.5 * p["cp"].max())[-1]] for p in prof]
    below = grid <= min(roots) - o["h"] / (V * prof[0]["t"])
    collapse_wetted = float(dev[below].max()) if below.any() else math.nan
    coefs = np.array([p["force_coef"] for p in prof])
    cp_max = float(peaks.mean())
    return {"cp_max": cp_max, "cp_max_spread": float(np.ptp(peaks) / cp_max), "zeta_peak": float(zpk.mean()),
            "collapse_err": collapse, "collapse_err_wetted": collapse_wetted,
            "zeta_root": float(np.mean(roots)), "cp_max_rel_similarity": abs(cp_max - ref["similarity_cp_max"])
            / ref["similarity_cp_max"], "cp_max_over_wagner": cp_max / ref["wagner_cp_max"],
            "force_coef": float(coefs.mean()), "force_coef_spread": float(np.ptp(coefs) / coefs.mean()),
            "force_coef_over_wagner": float(coefs.mean() / ref["wagner_force_coef"]),
            **{f"force_coef_t{k}": float(c) for k, c in enumerate(coefs)},
            **{f"zeta_half_t{k}": half_peak_root(p["zeta"], p["cp"]) for k, p in enumerate(prof)}}


def run(ctx: CheckContext) -> CheckResult:
    res = CheckResult(NAME, REQUIREMENT)
    ref = reference()
    hs = H_QUICK if ctx.quick else H_FULL
    outs = runs_by_h(simulate, hs)
    rows = []
    for o in outs:
        m = measures(o, ref)
        put_level_metrics(res, o["h"], m, o["steps"])
        rows.append(f"| {o['h']:g} | {o['particles']} | {o['steps']} | {m['cp_max']:.3f} | {m['zeta_peak']:.3f} | "
                    f"{m['collapse_err']:.3f} | {m['collapse_err_wetted']:.3f} | {m['force_coef']:.2f} | "
                    f"{m['force_coef_spread']:.3f} | {o['wall_s']:.0f} |")
    fin, mf = outs[-1], measures(outs[-1], ref)
    note = f"h = {fin['h']:g} m"
    res.metrics.update({k: v for k, v in mf.items()})
    res.gates += [
        Gate.at_most("collapse_err", mf["collapse_err"], TOL,
                     f"{note}: largest deviation of the three Cp(z/Vt) profiles from their mean / mean peak"),
        Gate.at_most("cp_max_rel_similarity", mf["cp_max_rel_similarity"], TOL,
                     f"{note}: |Cp_max - {ref['similarity_cp_max']:g}| / {ref['similarity_cp_max']:g} (similarity "
                     "solution's peak, UNVERIFIED: the issue's value from memory)"),
        Gate.at_most("cp_max_over_wagner", mf["cp_max_over_wagner"], 1.0,
                     f"{note}: Cp_max / Wagner's (pi/(2 tan beta))^2 = {ref['wagner_cp_max']:.3f}"),
        Gate.at_most("force_coef_spread", mf["force_coef_spread"], TOL,
                     f"{note}: range of F/(rho V^3 t) over the three times / their mean (F linear in t)"),
        Gate.at_most("force_coef_over_wagner", mf["force_coef_over_wagner"], 1.0,
                     f"{note}: F/(rho V^3 t) / Wagner's pi (pi/(2 tan beta))^2 = {ref['wagner_force_coef']:.2f} "
                     "(the similarity solution's value was not found)"),
    ]
    res.tables.append("| h [m] | particles | steps | Cp_max | z_peak/(Vt) | collapse error / peak | same, below the "
                      "spray roots less a cell | F/(rho V^3 t) | its spread over t | wall [s] |\n"
                      "|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows))
    res.notes.append(
        f"References (reference/data/{REF}): Wagner's Cp_max = {ref['wagner_cp_max']:.3f} and F/(rho V^3 t) = "
        f"{ref['wagner_force_coef']:.2f}, von Karman's F/(rho V^3 t) = {ref['von_karman_force_coef']:.2f} (derived); "
        f"the similarity solution's Cp_max = {ref['similarity_cp_max']:g} is the issue's value, not checked against "
        "Zhao & Faltinsen (1993); its force coefficient was not found, so the issue's force gate against it is not "
        "evaluated (the force is gated below Wagner's instead).")

    fig, ax = plt.subplots(figsize=(7, 4.5))
    colors = ("tab:blue", "tab:orange", "tab:green")
    for p, c in zip(fin["profiles"], colors, strict=True):
        ax.plot(p["zeta"], p["cp"], "-", color=c, lw=1.3,
                label=f"Vt = {V * p['t']:.3f} m (time mean over {p['cycles']} cycles, {p['steps']} steps)")
    ax.axhline(ref["similarity_cp_max"], ls="--", color="k", lw=1,
               label=f"similarity solution's peak {ref['similarity_cp_max']:g} (unverified)")
    ax.axhline(ref["wagner_cp_max"], ls=":", color="0.4", lw=1, label=f"Wagner's peak {ref['wagner_cp_max']:.2f}")
    # Wagner's outer (flat-plate) pressure, Cp = 2 k / sqrt(1 - (z / z_c)^2), z_c = (pi/2) V t, up to its peak k^2
    k = math.sqrt(ref["wagner_cp_max"])
    zw = np.linspace(0.0, 0.5 * math.pi * (1 - 1e-9), 300)
    ax.plot(zw, np.minimum(2 * k / np.sqrt(1 - (zw / (0.5 * math.pi)) ** 2), k * k), "-.", color="0.5", lw=0.8,
            label="Wagner's outer solution (capped at its peak)")
    ax.set_xlabel("z / (V t)   (height above the keel)")
    ax.set_ylabel("Cp = p / (0.5 rho V^2)")
    ax.set_title(f"Wedge entry, deadrise {BETA:g} deg, h = {fin['h']:g} m (incompressible water)")
    ax.text(0.02, 0.98, f"collapse error {mf['collapse_err']:.1%} of the peak; Cp_max {mf['cp_max']:.2f} "
                        f"({mf['cp_max_rel_similarity']:.1%} from {ref['similarity_cp_max']:g}); "
                        f"F/(rho V^3 t) = {mf['force_coef']:.2f} (Wagner {ref['wagner_force_coef']:.2f})",
            transform=ax.transAxes, va="top", fontsize=7,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    ax.set_xlim(0.0, 2.5)
    ax.set_ylim(min(0.0, *(p["cp"].min() for p in fin["profiles"])), 1.3 * ref["wagner_cp_max"])
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(ctx.fig_dir / "wedge_entry_cp.png", dpi=120)
    plt.close(fig)
    res.figures.append("wedge_entry_cp.png")
    if len(outs) > 1:
        errs = [res.metrics[f"h{o['h']:g}".replace(".", "") + "_collapse_err"] for o in outs]
        hs_run = [o["h"] for o in outs]
        rates = [math.log(errs[i] / errs[i + 1]) / math.log(hs_run[i] / hs_run[i + 1]) for i in range(len(errs) - 1)]
        res.notes.append("Observed order of the collapse error between successive h: "
                         + ", ".join(f"{r:.2f}" for r in rates) + ".")
        # the spray root's drift (docs/notes/wedge_entry.md): its half-peak position against h/(Vt) over
        # every h and time, zeta_half = zeta_0 + c h/(Vt); c != 0 is an offset of the root by c h in z
        xs, ys = [], []
        for o in outs:
            tag = f"h{o['h']:g}".replace(".", "")
            for k, d in enumerate(DEPTHS):
                zh = res.metrics[f"{tag}_zeta_half_t{k}"]
                if math.isfinite(zh):
                    xs.append(o["h"] / d)
                    ys.append(zh)
        if len(xs) > 2:
            c, z0 = np.polyfit(xs, ys, 1)
            rms = float(np.sqrt(np.mean((np.polyval([c, z0], xs) - np.asarray(ys)) ** 2)))
            res.metrics.update({"root_drift_c": float(c), "root_drift_zeta0": float(z0), "root_drift_rms": rms})
            res.notes.append(f"Spray root (half-peak position) over every h and time: z/(Vt) = {z0:.3f} + {c:.3f} "
                             "h/(Vt) "
                             f"(rms residual {rms:.3f}): the root lies {c:.2f} h higher than self-similar, the same "
                             "length at every time, so the three profiles part at the root by c h (1/Vt_1 - 1/Vt_3).")
    if math.isnan(ref["similarity_force_coef"]):
        res.notes.append("Not evaluated: F/(rho V^3 t) within 10 % of the similarity solution's (value not found).")
    return res
