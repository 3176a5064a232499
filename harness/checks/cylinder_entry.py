"""Check `cylinder_entry`: a circular cylinder enters water at rest at constant speed (issue 40).

cases/cylinder_entry.toml: a prescribed rigid cylinder of diameter D = 0.2 m moves down at V = 5 m/s into
incompressible water, gravity off, its lowest point on the surface at t = 0. Half the cylinder is modelled
(a polygon of 64 chords on the semicircle), its plane of symmetry the left (slip) wall: the cylinder's force
is twice the half's ``water_fy_cylinder``. Without gravity, viscosity or surface tension the slamming
coefficient Cs = F / (0.5 rho V^2 D) is a function of s/D alone, s = V t the penetration.

Measuring through the staircase (as wedge_entry does, docs/notes/wedge_entry.md): the water sees the body
as the cells holding its particles, so the force jumps from step to step as cells join it. The impulse
I(s) = integral of F dt is smooth (each step's force acts over that step), so Cs is measured as the mean
over windows of s/D (edges 0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5): (I(b) - I(a)) / ((b - a) D / V) /
(0.5 rho V^2 D), the fit's mean over the same window its exact integral: window means on both sides, not
point values.

Reference (reference/data/cylinder_entry_campbell_weynberg.csv): Campbell & Weynberg's (1980) fit as DNV
quotes it, Cs = 5.15 (1 / (1 + 19 s/D) + 0.107 s/D), read from a secondary source (the file's header says
how); its range and the scatter of the measurements about it were not found. Gates, at the finest h:

- `cs_fit_err`: the largest |Cs / Cs_fit - 1| over the windows in 0.05 <= s/D <= 0.5, at most TOL = 0.10.
  The range: up to s/D = 0.5, the cylinder half under (where the water-entry force of the slamming
  models ends: the wetted width stops growing in von Karman's); from 0.05, the first window being the limit
  gate's (2 cells of penetration at h = D/40). TOL: no stated scatter was found to derive it from; 0.10 is
  the tolerance the issue sets for the sister check's force (wedge_entry), used until the standard's
  figure or the report is read. Not chosen from our results (which it fails: docs/notes/cylinder_entry.md).
- `cs_limit_low` / `cs_limit_high`: the small-s limit between von Karman's pi and Wagner's 2 pi, measured as
  the mean Cs over the first window 0 < s/D <= 0.05. For Cs falling with s (as every model and the fit do)
  that mean lies below the limit, so mean >= pi shows the limit is >= pi and mean > 2 pi would show it
  above 2 pi; the fit's own mean over the window is 3.63, von Karman's pi (1 - 2 s/D) gives 2.98.
- `convergence` (full tier, three h): the mean relative change of the windowed Cs over the gated windows
  between the two finest h is smaller than between the two coarsest (the differences fall with h); the
  observed order is reported. The mean, not the largest: one window of a coarse run can hold a staircase
  jump that the window does not average out (h = 0.01: 2.14 over 0.15-0.2 against 1.47 at h = 0.005).

The tank, 6 D x 5 D, is large enough (the case file's header). The quick tier runs h = 0.01 m (D/20) alone
(7-15 s), the full tier h = 0.02, 0.01, 0.005 m (D/10, D/20, D/40; the last 80-140 s on a loaded core).
Not in the gated set (verify.EXPERIMENTAL): the lead decides; `cs_fit_err` fails (the note says why).
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

NAME = "cylinder_entry"
REQUIREMENT = ("A circular cylinder enters water at rest at constant speed V (incompressible water, no gravity): "
               "the slamming coefficient Cs = F/(0.5 rho V^2 D) against s/D follows Campbell & Weynberg's fit "
               "(as DNV quotes it) within 10 % over 0.05 <= s/D <= 0.5, its small-s limit lies between von "
               "Karman's pi and Wagner's 2 pi, and it converges with the cell size.")
CASE = paths.CASES / "cylinder_entry.toml"
REF = "cylinder_entry_campbell_weynberg.csv"
RHO, V, D = 1000.0, 5.0, 0.2
S_END = 0.5                       # the window's end, s/D (the cylinder half under)
T_END = S_END * D / V
EDGES = np.array([0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5])   # windows of s/D, wider where Cs varies slowly
GATED = (0.05, 0.5)               # windows inside this range are gated against the fit
H_QUICK = (0.01,)
H_FULL = (0.02, 0.01, 0.005)
TOL = 0.10


def reference() -> dict[str, dict[str, float]]:
    """The rows of the reference file by name: fit, von_karman, wagner."""
    ref = refdata.read(REF)
    return {str(n): {k: float(v[i]) for k, v in ref.items() if k != "name"} for i, n in enumerate(ref["name"])}


def cs_fit(x, cs0: float = 5.15, b: float = 19.0, c: float = 0.107):
    """Campbell & Weynberg's fit as DNV quotes it: Cs = cs0 (1 / (1 + b s/D) + c s/D), x = s/D."""
    x = np.asarray(x, dtype=float)
    return cs0 * (1.0 / (1.0 + b * x) + c * x)


def cs_fit_mean(a: float, b_: float, cs0: float = 5.15, b: float = 19.0, c: float = 0.107) -> float:
    """The fit's mean over a < s/D < b_ (its exact integral over the window / the window's width)."""
    return cs0 * (math.log((1.0 + b * b_) / (1.0 + b * a)) / (b * (b_ - a)) + 0.5 * c * (a + b_))


def window_means(t: np.ndarray, force: np.ndarray, edges=EDGES, rho: float = RHO, v: float = V,
                 d: float = D) -> np.ndarray:
    """Mean Cs over each window [edges[k], edges[k+1]] of s/D from a force series sampled at the ends of the
    steps (force[i] acting over (t[i-1], t[i]], t[-1] = 0): the impulse, piecewise linear in t, is
    interpolated at the window's ends."""
    t = np.concatenate([[0.0], np.asarray(t, dtype=float)])
    imp = np.concatenate([[0.0], np.cumsum(np.asarray(force, dtype=float) * np.diff(t))])
    s = v * t / d
    e = np.asarray(edges, dtype=float)
    ie = np.interp(e, s, imp)
    return np.diff(ie) / (np.diff(e) * d / v) / (0.5 * rho * v**2 * d)


def simulate(h: float) -> dict:
    """One run at cell size h, one step at a time: after every step the water's force on the cylinder
    (twice the half's)."""
    case = cases.load(CASE, [f"grid.cell={h}", f"solver.t_end={T_END}"])
    w0 = time.perf_counter()
    sim, parts = runner.build(case)
    loads = runner.WaterLoads(case, parts)
    ts, fs = [], []
    try:
        t = 0.0
        while t < T_END * (1 - 1e-12):
            _, t = sim.advance(T_END, max_steps=1, land=True)
            ts.append(t)
            fs.append(2.0 * loads.evaluate(sim, sim.state()["x"])["water_fy_cylinder"])
        steps = int(sim.diagnostics()["steps"])
    finally:
        sim.close()
    return {"h": h, "t": np.array(ts), "force": np.array(fs), "steps": steps, "particles": int(parts.n),
            "wall_s": time.perf_counter() - w0}


def measures(o: dict, fit: dict[str, float]) -> dict:
    """Windowed Cs of one run, its error against the fit over the gated range and the first window's mean."""
    cs = window_means(o["t"], o["force"])
    ref = np.array([cs_fit_mean(a, b, fit["cs0"], fit["b"], fit["c"])
                    for a, b in zip(EDGES[:-1], EDGES[1:], strict=True)])
    gated = (EDGES[:-1] >= GATED[0] - 1e-9) & (EDGES[1:] <= GATED[1] + 1e-9)
    rel = cs / ref - 1.0
    k = int(np.argmax(np.abs(np.where(gated, rel, 0.0))))
    o["cs"], o["cs_ref"], o["gated"] = cs, ref, gated
    return {"cs_fit_err": float(np.abs(rel[gated]).max()), "cs_fit_bias": float(rel[gated].mean()),
            "cs_fit_err_at": float(0.5 * (EDGES[k] + EDGES[k + 1])), "cs_first_window": float(cs[0]),
            **{f"cs_w{i}": float(c) for i, c in enumerate(cs)}}


def run(ctx: CheckContext) -> CheckResult:
    res = CheckResult(NAME, REQUIREMENT)
    ref = reference()
    fit = ref["fit"]
    lo, hi = ref["von_karman"]["cs0"], ref["wagner"]["cs0"]
    hs = H_QUICK if ctx.quick else H_FULL
    outs = runs_by_h(simulate, hs)
    rows = []
    for o in outs:
        m = measures(o, fit)
        put_level_metrics(res, o["h"], m, o["steps"])
        rows.append(f"| {o['h']:g} | {D / o['h']:.0f} | {o['particles']} | {o['steps']} | "
                    + " | ".join(f"{c:.2f}" for c in o["cs"]) + f" | {m['cs_fit_err']:.3f} | {o['wall_s']:.0f} |")
    fin = outs[-1]
    mf = measures(fin, fit)
    note = f"h = {fin['h']:g} m (D/{D / fin['h']:.0f})"
    res.metrics.update(mf)
    res.gates += [
        Gate.at_most("cs_fit_err", mf["cs_fit_err"], TOL,
                     f"{note}: largest |Cs/Cs_fit - 1| of the window means over {GATED[0]:g} <= s/D <= {GATED[1]:g} "
                     f"(at s/D = {mf['cs_fit_err_at']:.3f}); Cs_fit = 5.15 (1/(1 + 19 s/D) + 0.107 s/D), "
                     "Campbell & Weynberg as DNV quotes it (read from a secondary source)"),
        Gate.at_least("cs_limit_low", mf["cs_first_window"], lo,
                      f"{note}: mean Cs over 0 < s/D <= 0.05 (below the s -> 0 limit) >= von Karman's pi"),
        Gate.at_most("cs_limit_high", mf["cs_first_window"], hi,
                     f"{note}: mean Cs over 0 < s/D <= 0.05 <= Wagner's 2 pi"),
    ]
    if len(outs) >= 3:
        w = [o["cs"][fin["gated"]] for o in outs]
        d_coarse = float(np.mean(np.abs(w[-3] / w[-2] - 1.0)))
        d_fine = float(np.mean(np.abs(w[-2] / w[-1] - 1.0)))
        res.metrics.update({"change_coarse": d_coarse, "change_fine": d_fine})
        res.gates.append(Gate.at_most(
            "convergence", d_fine / d_coarse, 1.0,
            f"mean relative change of the windowed Cs over the gated range between h = {outs[-2]['h']:g} and "
            f"{outs[-1]['h']:g} ({d_fine:.3f}) / between h = {outs[-3]['h']:g} and {outs[-2]['h']:g} ({d_coarse:.3f})"))
        ratio = outs[-3]["h"] / outs[-2]["h"]
        res.notes.append(f"Observed order of the windowed Cs's mean change: "
                         f"{math.log(d_coarse / d_fine) / math.log(ratio):.2f}.")
    heads = " | ".join(f"{a:g}-{b:g}" for a, b in zip(EDGES[:-1], EDGES[1:], strict=True))
    fit_row = " | ".join(f"{c:.2f}" for c in fin["cs_ref"])
    res.tables.append(f"| h [m] | D/h | particles | steps | {heads} | err vs fit | wall [s] |\n"
                      "|---|---|---|---|" + "---|" * (len(EDGES) - 1) + "---|---|\n"
                      + "\n".join(rows) + f"\n| fit | | | | {fit_row} | | |")
    res.notes.append(
        f"Cs = window means over s/D (columns), from the impulse. References (reference/data/{REF}): the fit "
        "5.15 (1/(1 + 19 s/D) + 0.107 s/D), Campbell & Weynberg (1980) as DNV-RP-C205 / DNV-OS-J101 quote it, "
        "read from a secondary source, UNVERIFIED; its range and scatter not found. Von Karman's pi and Wagner's "
        "2 pi derived (flat-plate added mass without and with the rise-up).")

    fig, ax = plt.subplots(figsize=(7, 4.5))
    mids = 0.5 * (EDGES[:-1] + EDGES[1:])
    colors = ("tab:blue", "tab:orange", "tab:green")
    for o, c in zip(outs, colors[-len(outs):], strict=True):
        ax.step(EDGES, np.append(o["cs"], o["cs"][-1]), where="post", color=c, lw=1.3,
                label=f"h = {o['h']:g} m (D/{D / o['h']:.0f}), window means")
    xs = np.linspace(0.0, S_END, 400)
    ax.plot(xs, cs_fit(xs, fit["cs0"], fit["b"], fit["c"]), "--", color="k", lw=1,
            label="Campbell & Weynberg's fit (DNV), 5.15 (1/(1+19 s/D) + 0.107 s/D)")
    ax.plot(mids, fin["cs_ref"], "k.", ms=4, label="the fit's window means")
    ax.axhline(hi, ls=":", color="0.4", lw=1, label="Wagner's 2 pi (s -> 0)")
    ax.axhline(lo, ls="-.", color="0.5", lw=0.8, label="von Karman's pi (s -> 0)")
    ax.axvspan(0.0, GATED[0], color="0.9", zorder=0)
    ax.set_xlabel("s / D   (penetration / diameter)")
    ax.set_ylabel("Cs = F / (0.5 rho V^2 D)")
    ax.set_title(f"Cylinder entry at constant speed, D = {D:g} m (incompressible water, no gravity)")
    ax.text(0.35, 0.62, f"{note}: largest |Cs/Cs_fit - 1| over {GATED[0]:g}-{GATED[1]:g} = {mf['cs_fit_err']:.1%} "
                        f"(mean {mf['cs_fit_bias']:+.1%})\nmean Cs over 0-0.05: {mf['cs_first_window']:.2f} "
                        f"(pi = {lo:.2f}, 2 pi = {hi:.2f})",
            transform=ax.transAxes, va="top", fontsize=7,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    ax.set_xlim(0.0, S_END)
    ax.set_ylim(0.0, 7.0)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(ctx.fig_dir / "cylinder_entry_cs.png", dpi=120)
    plt.close(fig)
    res.figures.append("cylinder_entry_cs.png")
    return res
