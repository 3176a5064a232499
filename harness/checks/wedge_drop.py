"""Check `wedge_drop`: a free-falling wedge entering calm water (issue 40, free-fall cases), against the
velocity Yettou, Desrochers & Champoux (2006) measured (deadrise 25 degrees, breadth 1.2 m, 94 kg, 5.05 m/s
at impact; the trace digitised from Sun et al. (2015), reference/data/
yettou_2006_wedge_drop_velocity_sun2015_digitized.csv, whose header gives the source and the checks made).

The case (cases/wedge_drop.toml): the whole wedge as a free rigid body (model = "rigid_body", three degrees
of freedom), keel on the surface at t = 0 moving down at 5.05 m/s, gravity on, a tank 4 m wide with water
2 m deep, incompressible inviscid water, no air. 2D: the 94 kg are per metre of wedge length; the check sets
the wedge's density so that its SEEDED particles (whole sub-cell squares inside the polygon) weigh 94 kg
per metre at every h (the seeded area differs from the polygon's 0.16787 m^2 by the staircase, 0.3 % at
h = 0.02).

- velocity_error_max: the largest |v_run - v_exp| / v_exp over the record's points in 0 <= t <= 40 ms, the
  run's downward velocity (centre of mass, series every 0.5 ms) interpolated linearly to the record's times
  (t = 0 at first contact: the keel starts on the surface). Gate <= 5 % at the finest h (the issue's), marked a
  known limitation of the model: the 2-D fully nonlinear potential-flow solution (BEM of Zhao & Faltinsen
  1993, as plotted by Sun et al. 2015; reference/data/zhao_faltinsen_1993_bem_wedge_drop_velocity_sun2015_
  digitized.csv), the same physics as ours (2-D, incompressible, inviscid, no air), lies above the record by
  up to 9.1 % (at 19.8 ms), so no converged run of this model can meet 5 % there.
- bem_error_max: the same measure against the BEM's velocity (its points in 0-40 ms), gate <= 5 % at the
  finest h: the code against the model's own solution.
- The other levels are reported (resolution study), with the velocity at 40 ms and the largest horizontal
  velocity (the wedge is symmetric: a drift measures the asymmetry of the discretisation).
"""

from __future__ import annotations

import numpy as np

from harness import cases, parallel, paths, plots, refdata, runner, seeding
from harness.checks import registry
from harness.checks.base import CheckContext, CheckResult, Gate, run_completed

NAME = "wedge_drop"
CASE = paths.CASES / "wedge_drop.toml"
REQUIREMENT = registry.requirement(CASE)   # one source: the case file
DATA = "yettou_2006_wedge_drop_velocity_sun2015_digitized.csv"
BEM = "zhao_faltinsen_1993_bem_wedge_drop_velocity_sun2015_digitized.csv"
LIMITATION = ("the 2-D incompressible inviscid model's own solution (BEM, Zhao & Faltinsen 1993, digitised in Sun et "
              "al. 2015) lies up to 9.1 % above the record (19.8 ms): docs/notes/wedge_drop.md")
MASS = 94.0        # kg per metre of wedge length
WINDOW = 0.040     # s, the window
GATE = 0.05
QUICK = (cases.load(CASE)["grid"]["cell"],)   # the case's h
LEVELS = (QUICK[0], 0.0125, 0.01)   # h [m]; the full tier runs all three, the gates read the finest


def record(name: str = DATA) -> tuple[np.ndarray, np.ndarray]:
    """The measured trace (or the BEM's, name=BEM): time from first contact [s], downward velocity [m/s]."""
    d = refdata.read(name)
    return d["t_ms"] * 1e-3, d["v"]


def seeded_density(case: dict, body: str = "wedge", mass: float = MASS) -> float:
    """The density that makes the body's seeded particles weigh `mass` (per metre)."""
    parts = seeding.seed(case)
    mat = [m["name"] for m in case["materials"]].index(body)
    return float(mass / parts.vol[parts.mat == mat].sum())


def velocity_errors(t_run, v_run, t_exp, v_exp, window: float = WINDOW) -> tuple[np.ndarray, np.ndarray]:
    """(record times within [0, window], relative errors |v_run - v_exp| / v_exp there), the run
    interpolated linearly to the record's times. Record points beyond the run's last sample are dropped."""
    t_exp, v_exp = np.asarray(t_exp, float), np.asarray(v_exp, float)
    keep = (t_exp >= 0.0) & (t_exp <= window + 1e-12) & (t_exp <= np.max(t_run))
    v = np.interp(t_exp[keep], t_run, v_run)
    return t_exp[keep], np.abs(v - v_exp[keep]) / np.abs(v_exp[keep])


def simulate(h: float, out) -> dict:
    """One run at cell size h: the downward velocity against time and the metrics."""
    base = cases.load(CASE, [f"grid.cell={h}"])
    rho = seeded_density(base)
    case = cases.load(CASE, [f"grid.cell={h}", f"materials.1.density={rho!r}"])
    r = runner.run(case, out, progress=False)
    s = r.series
    t, v = s["t"], -s["wedge_vy"]
    te, ve = record()
    tk, err = velocity_errors(t, v, te, ve)
    _, err_bem = velocity_errors(t, v, *record(BEM))
    m = {"velocity_error_max": float(err.max()), "bem_error_max": float(err_bem.max()),
         "bem_error_rms": float(np.sqrt(np.mean(err_bem ** 2))),
         "velocity_error_rms": float(np.sqrt(np.mean(err ** 2))),
         "t_error_max": float(tk[np.argmax(err)]), "v_40ms": float(np.interp(WINDOW, t, v)),
         "vx_max": float(np.max(np.abs(s["wedge_vx"]))), "density": rho,
         "wedge_mass": float(r.parts.mass[r.parts.mat == 1].sum())}
    return {"metrics": m, "t": t, "v": v, "err": (tk, err), "summary": r.summary}


@registry.check(order=4,
                experimental=("within 5 % of the 2D BEM at h = 0.01 (2.7 %), not at the quick tier's h = 0.02 "
                              "(5.15 %)"),
                notes="docs/notes/wedge_drop.md")
def run(ctx: CheckContext) -> CheckResult:
    res = CheckResult(NAME, REQUIREMENT)
    levels = QUICK if ctx.quick else LEVELS
    outs = parallel.pmap(simulate, [(h, ctx.runs_dir / f"h{h:g}") for h in levels[::-1]])[::-1]
    te, ve = record()
    curves, rows = {}, []
    for h, out in zip(levels, outs, strict=True):
        tag = f"_h{h:g}"
        if not run_completed(res, tag, f"the h = {h:g} run", out):
            continue
        m = out["metrics"]
        res.metrics.update({k + tag: v for k, v in m.items()})
        curves[f"h = {h:g} m (max error {100 * m['velocity_error_max']:.1f} %)"] = (out["t"] * 1e3, out["v"])
        s = out["summary"]
        rows.append(f"| {h:g} | {100 * m['velocity_error_max']:.2f} (at {1e3 * m['t_error_max']:.1f} ms) | "
                    f"{100 * m['velocity_error_rms']:.2f} | {100 * m['bem_error_max']:.2f} | {m['v_40ms']:.3f} | "
                    f"{m['vx_max']:.1e} | {s['particles']} | "
                    f"{s['steps']} | {s['wall_s']:.0f} |")
    finest = next((h for h, o in zip(levels[::-1], outs[::-1], strict=True) if not isinstance(o, Exception)), None)
    if finest is None:
        raise RuntimeError("no run completed")
    m = res.metrics
    res.metrics["velocity_error_max"] = m[f"velocity_error_max_h{finest:g}"]
    res.metrics["bem_error_max"] = m[f"bem_error_max_h{finest:g}"]
    res.gates.append(Gate.at_most("velocity_error_max", m["velocity_error_max"], GATE,
                                  f"finest run (h = {finest:g} m), record points 0-40 ms", known_limitation=LIMITATION))
    res.gates.append(Gate.at_most("bem_error_max", m["bem_error_max"], GATE,
                                  f"finest run (h = {finest:g} m) against the 2-D BEM, its points in 0-40 ms"))
    tb, vb = record(BEM)
    _, bem_vs_exp = velocity_errors(tb, vb, te, ve)
    res.tables.append("| h [m] | max error vs record [%] | rms vs record [%] | max error vs BEM [%] | v(40 ms) [m/s] "
                      "| max abs vx [m/s] | particles | steps | wall [s] |\n|---|---|---|---|---|---|---|---|---|\n"
                      + "\n".join(rows) + f"\n\nRecord: v(40 ms) = {np.interp(WINDOW, te, ve):.3f} m/s. The BEM "
                      f"against the record: max {100 * bem_vs_exp.max():.1f} %, rms "
                      f"{100 * np.sqrt(np.mean(bem_vs_exp ** 2)):.1f} %.")
    plots.time_series(ctx.fig_dir / "wedge_drop_velocity.png", None, curves,
                      points={"Yettou et al. (2006), digitised in Sun et al. (2015)": (te * 1e3, ve)},
                      exact=(tb * 1e3, vb), exact_label="2-D BEM, Zhao & Faltinsen (1993), in Sun et al. (2015)",
                      xlabel="t from first contact [ms]", ylabel="downward velocity [m/s]", legend_loc="below",
                      title="Free-falling wedge, deadrise 25 deg, 94 kg/m, 5.05 m/s",
                      annotate=f"h = {finest:g} m: max error {100 * m['velocity_error_max']:.1f} % vs record, "
                               f"{100 * m['bem_error_max']:.1f} % vs BEM (gates {100 * GATE:.0f} %)")
    res.figures.append("wedge_drop_velocity.png")
    res.notes.insert(0, __doc__.split("\n\n", 1)[1].strip())
    return res
