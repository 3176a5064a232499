"""Check `vibrating_bar`: 1D elastic bar, centre-of-mass velocity against the analytic mode.

Expected order: 1. The measured quantity is a velocity, and MUSL's particle velocities are
leapfrog half-step values: compared with the exact v_cm at whole steps they carry an O(dt)
offset, and dt is tied to h by a fixed CFL, so the error falls as h^1
(tests/test_vibrating_bar.py shows the rate rising towards 2 when the CFL is cut tenfold).
Positions are second order: see the `convergence` check, where the bar's displacement
error converges at 2.0.
"""

from __future__ import annotations

import numpy as np

from harness import metrics, plots
from harness.checks import registry
from harness.checks.base import CheckContext, CheckResult, Gate
from harness.problems import vibrating_bar as bar

NAME = "vibrating_bar"
REQUIREMENT = ("The 1D vibrating bar (L = 25, E = 100, rho = 1) reproduces the analytic centre-of-mass velocity, "
               "and its error falls at least at first order under refinement for CPDI.")


@registry.check(order=2)
def run(ctx: CheckContext) -> CheckResult:
    levels = [13, 26, 52] if ctx.quick else [13, 26, 52, 104]
    res = CheckResult(NAME, REQUIREMENT)
    curves = {}
    for shape in ("mpm", "gimp", "cpdi"):
        h = np.array([bar.L / n for n in levels])
        e = np.array([bar.rms_error(shape, n) for n in levels])
        p = metrics.observed_orders(h, e)
        curves[shape] = (h, e)
        res.metrics[f"error_finest_bar_{shape}"] = float(e[-1])
        res.metrics[f"order_bar_{shape}"] = float(p[-1])
        res.tables.append(f"**{shape.upper()}** (RMS over 50 samples of v_cm error / v0, 0 < t <= 10 s)\n\n"
                          + metrics.convergence_table(h, e, "rms error / v0"))
    res.gates.append(Gate.at_least("order_bar_cpdi", res.metrics["order_bar_cpdi"], 0.8,
                                   "expected order 1 (half-step velocity offset O(dt), dt ~ h) minus 0.2"))
    res.gates.append(Gate.at_most("error_finest_bar_cpdi", res.metrics["error_finest_bar_cpdi"], 1.2e-3))
    fig = "vibrating_bar_convergence.png"
    plots.loglog_convergence(ctx.fig_dir / fig, curves, ref_orders=(1, 2),
                             title="Vibrating bar: v_cm error vs cell size",
                             ylabel="RMS(v_cm - exact) / v0",
                             annotate=f"CPDI order (finest pair) = {res.metrics['order_bar_cpdi']:.2f}")
    t, v = bar.simulate("cpdi", levels[-1])
    fig2 = "vibrating_bar_vcm.png"
    plots.time_series(ctx.fig_dir / fig2, t, {"CPDI, finest": v / 1e-3},
                      exact=(np.linspace(0, 10, 400), bar.vcm_exact(np.linspace(0, 10, 400), 1e-3) / 1e-3),
                      xlabel="t [s]", ylabel="v_cm / v0", title="Vibrating bar, centre-of-mass velocity",
                      annotate=f"RMS error / v0 = {res.metrics['error_finest_bar_cpdi']:.2e}")
    res.figures += [fig, fig2]
    res.notes.append(__doc__.split("\n\n", 1)[1].strip())
    return res
