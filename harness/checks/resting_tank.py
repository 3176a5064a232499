"""Check `resting_tank`: water at rest stays at rest (issue 20).

cases/resting_tank.toml: the sinking_block's tank and water without the block (2.5 m x 1.2 m
deep, h = 0.05 m), 10 s, no damping, incompressible water. Gates, from the issue:
KE/(M g H) <= 1e-5 at every series sample; final particle pressure against rho g (H - y),
relative L2 <= 1 %; mean free-surface drift <= 0.1 % of H; water volume change (occupied
against particle volume, harness.water.volume_change) <= 0.5 %; no particle moves more than 0.1 h in total.

Beside it, ungated, the weakly compressible model with the sinking_block's settings (cell
projection, beta 0.1, flip 0.999, K = 2e6 Pa), the set-up whose resting water issue 6
measured at 87 J and 23 kPa of noise after 3 s. The quick tier runs it for 3 s, the full tier
for 10 s; its figure shows both.
"""

from __future__ import annotations

import numpy as np

from harness import cases, parallel, paths, plots, runner, water
from harness.checks import registry
from harness.checks.base import CheckContext, CheckResult, Gate, body_bounds, gravity, material

NAME = "resting_tank"
CASE = paths.CASES / "resting_tank.toml"
REQUIREMENT = registry.requirement(CASE)   # one source: the case file
_CASE = cases.load(CASE)
H = body_bounds(_CASE, "water")[1][1]   # the depth at rest (accelerated_tank's mean depth too)
RHO, G = material(_CASE, "water")["density"], gravity(_CASE)
WC_SETTINGS = ['solver.fluid="weakly_compressible"', 'solver.projection="cell"', "solver.projection_stabilization=0.1",
               "solver.flip=0.999", "solver.cfl=0.4"]


def surface_slope(case) -> float:
    """The free surface's slope at rest, b_x / g, under the case's body acceleration b and gravity
    (0 without a body acceleration)."""
    s = case["solver"]
    return s["body_acceleration"][0] / -s["gravity"][1]


def measures(r: runner.RunResult, case) -> dict:
    """KE history and the final state's measures of one run. The surface at rest is
    y_s(x) = H + slope (x - L / 2) (slope: surface_slope, accelerated_tank) and the pressure
    rho g (y_s(x) - y)."""
    slope = surface_slope(case)
    g = case["grid"]
    h = g["cell"]
    ncell = (round(g["size"][0] / h), round(g["size"][1] / h))
    xc = g["origin"][0] + 0.5 * g["size"][0]
    x0, f = r.parts.x, r.final
    mass = float(np.sum(r.parts.mass))
    ke = r.series["kinetic_energy"] / (mass * G * H)
    p = -(f["sigma"][:, 0] + f["sigma"][:, 1] + f["sigma"][:, 3]) / 3.0
    exact = RHO * G * (H + slope * (f["x"][:, 0] - xc) - f["x"][:, 1])
    cols_x, tops = water.surface_columns(f["x"], f["r"], 0.0, g["size"][0])
    out = {
        "t": r.series["t"], "ke": ke, "p": p, "y": f["x"][:, 1], "exact": exact,
        "ke_max": float(ke.max()),
        "pressure_rel_l2": float(np.linalg.norm(p - exact) / np.linalg.norm(exact)),
        "surface_drift": abs(float(np.mean(tops)) - H - slope * (float(np.mean(cols_x)) - xc)) / H,
        "volume_change": abs(water.volume_change(f["x"], f["vol"], g["origin"], h, ncell)),
        "overfill_change": abs(water.overfill_change(f["x"], f["vol"], g["origin"], h, ncell)),
        "max_displacement_h": float(np.max(np.linalg.norm(f["x"] - x0, axis=1)) / h),
        "pressure_noise_kpa": float(np.std(p - exact) / 1e3),
        "steps": r.summary["steps"], "wall_s": r.summary["wall_s"],
    }
    if slope:
        out["slope_rel_error"] = abs(float(np.polyfit(cols_x, tops, 1)[0]) - slope) / abs(slope)
    return out


@registry.check(order=8)
def run(ctx: CheckContext) -> CheckResult:
    return run_tank(ctx, NAME, REQUIREMENT, CASE)


def run_measured(case, out) -> dict:
    """One run of the tank and its measures (a worker's task)."""
    return measures(runner.run(case, out, progress=False), case)


def run_tank(ctx: CheckContext, name: str, requirement: str, case_path,
             gates: tuple[tuple[str, float, str], ...] = (), wc_overrides: tuple[str, ...] = ()) -> CheckResult:
    """Water at rest in a tank, incompressible (gated) and weakly compressible (reported): the
    resting_tank check, and, with a body acceleration in the case and extra gates (metric, bound,
    note), the accelerated_tank check. wc_overrides: further case overrides of the weakly
    compressible run only."""
    res = CheckResult(name, requirement)
    case = cases.load(case_path)
    slope = surface_slope(case)
    t_wc = 3.0 if ctx.quick else case["solver"]["t_end"]   # the weakly compressible run (quick: 3 s)
    wc_case = cases.load(case_path, [*WC_SETTINGS, f"solver.t_end={t_wc}", "solver.output_every=1.0", *wc_overrides])
    # the two water models side by side on the verify's workers
    inc, wc = parallel.pmap(run_measured, [(case, ctx.runs_dir / "incompressible"),
                                           (wc_case, ctx.runs_dir / "weakly_compressible")])
    for label, out in (("incompressible", inc), ("weakly compressible", wc)):
        if isinstance(out, Exception):
            raise RuntimeError(f"the {label} run failed: {out}")
    keys = ("ke_max", "pressure_rel_l2", "surface_drift", "volume_change", "overfill_change", "max_displacement_h",
            "pressure_noise_kpa") + tuple(k for k, _, _ in gates)
    for key in keys:
        res.metrics[key] = inc[key]
        res.metrics[f"wc_{key}"] = wc[key]
    res.metrics["steps"] = float(inc["steps"])
    res.metrics["wc_steps"] = float(wc["steps"])
    surface = "H" if not slope else "the surface at rest"
    res.gates += [
        Gate.at_most("ke_max", inc["ke_max"], 1e-5, "KE / (M g H) at every series sample"),
        Gate.at_most("pressure_rel_l2", inc["pressure_rel_l2"], 0.01,
                     "particle pressure vs rho g (H - y)" if not slope else "particle pressure vs rho g (y_s(x) - y)"),
        Gate.at_most("surface_drift", inc["surface_drift"], 0.001, f"mean free surface vs {surface}"),
        Gate.at_most("volume_change", inc["volume_change"], 0.005, "|occupied - particle volume| / particle volume"),
        Gate.at_most("max_displacement_h", inc["max_displacement_h"], 0.1, "largest particle displacement / h"),
    ] + [Gate.at_most(k, inc[k], bound, note) for k, bound, note in gates]
    plots.time_series(ctx.fig_dir / f"{name}_energy.png", inc["t"],
                      {"incompressible": np.maximum(inc["ke"], 1e-20),
                       "weakly compressible, sinking_block settings": (wc["t"], np.maximum(wc["ke"], 1e-20))},
                      xlabel="t [s]", ylabel="KE / (M g H)", title=f"{name}: kinetic energy (no damping)",
                      annotate=f"max KE/(MgH): incompressible {inc['ke_max']:.1e}, weakly compressible "
                               f"{wc['ke_max']:.1e}", logy=True)
    dd = np.linspace(0.0, H + abs(slope) * 0.5 * case["grid"]["size"][0], 2)
    plots.time_series(ctx.fig_dir / f"{name}_pressure.png", RHO * G * dd / 1e3,
                      {}, exact=(RHO * G * dd / 1e3, dd), exact_label="rho g d",
                      points={"weakly compressible (particles)": (wc["p"] / 1e3, wc["exact"] / (RHO * G)),
                              "incompressible (particles, drawn over)": (inc["p"] / 1e3, inc["exact"] / (RHO * G))},
                      xlabel="pressure [kPa]", ylabel="depth below the surface at rest, d [m]",
                      title="Pressure at the end (particles)",
                      annotate=f"rel. L2 error: incompressible {inc['pressure_rel_l2']:.1e}, "
                               f"weakly compressible {wc['pressure_rel_l2']:.1e}")
    res.figures += [f"{name}_energy.png", f"{name}_pressure.png"]
    extra = "".join(f" {k} |" for k, _, _ in gates)
    res.tables.append(
        "| water model | steps | max KE/(MgH) | pressure rel. L2 | noise [kPa] | surface drift / H | "
        f"volume change | max displacement / h |{extra}\n|---|---|---|---|---|---|---|---|{'---|' * len(gates)}\n"
        + "\n".join(f"| {label} | {m['steps']} | {m['ke_max']:.2e} | {m['pressure_rel_l2']:.2e} | "
                    f"{m['pressure_noise_kpa']:.3g} | {m['surface_drift']:.2e} | {m['volume_change']:.2e} | "
                    f"{m['max_displacement_h']:.2e} |" + "".join(f" {m[k]:.2e} |" for k, _, _ in gates)
                    for label, m in (("incompressible (gated), 10 s", inc),
                                     (f"weakly compressible, sinking_block settings, {t_wc:g} s", wc))))
    return res
