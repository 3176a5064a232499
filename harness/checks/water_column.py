"""Check `water_column`: a water column collapses in a slip-walled tank (foundation smoke check).

Runs cases/water_column.toml (incompressible water, APIC, CPDI weights). Gates: the run completes,
no energy is created (kinetic + strain - work of gravity never exceeds its initial value
by more than 1 % of the work done by gravity), and the surge front stays behind Ritter's
shallow-water bound Z = 1 + 2T. The Martin & Moyce (1952) points are shown for orientation;
the gated comparison belongs to the `dam_break_front` check.

The same column with the weakly compressible water (MUSL, K = 2e6 Pa, flip 0.99) runs beside
it under the same gates (prefix weakly_compressible_). The incompressible water's volume
correction moves particles without a velocity; the work of gravity on those moves is reported
as correction_work and kept out of the energy budget, which is the flow's.
"""

from __future__ import annotations

import h5py
import numpy as np

from harness import cases, paths, plots, refdata, runner
from harness.checks import registry
from harness.checks.base import CheckContext, CheckResult, Gate, body_bounds, gravity, grid_size

NAME = "water_column"
REQUIREMENT = registry.requirement("water_column.toml")   # one source: the case file
CASE = paths.CASES / "water_column.toml"
MM_FRONT = paths.REFERENCE / "data" / "martin_moyce_1952_front_n2eq2_a2.25in_table2.csv"
_CASE = cases.load(CASE)
L = body_bounds(_CASE, "column")[1][0]   # the column's width
G = gravity(_CASE)


def _measure(res: CheckResult, out, prefix: str = "") -> tuple:
    s, ser = out.summary, out.series
    e_total = ser["kinetic_energy"] + ser["strain_energy"] - ser["gravity_work"]
    wg = max(float(ser["gravity_work"][-1]), 1e-30)
    T = ser["t"] * np.sqrt(2 * G / L)
    Z = ser["front_x"] / L
    m = {
        "completed": 1.0 if s["status"] == "completed" else 0.0,
        "energy_excess": float(np.max(e_total - e_total[0]) / wg),
        "energy_dissipated": float((e_total[0] - e_total[-1]) / wg),
        "ritter_margin_min": float(np.min(1 + 2 * T - Z)),
        "front_Z_final": float(Z[-1]),
        "particles": float(s["particles"]),
        "particle_updates_per_s": float(s["particle_updates_per_s"]),
    }
    if not prefix:
        m["correction_work"] = float(ser["correction_work"][-1] / wg)
    res.metrics.update({prefix + k: v for k, v in m.items()})
    res.gates += [
        Gate.at_least(prefix + "completed", m["completed"], 1.0),
        Gate.at_most(prefix + "energy_excess", m["energy_excess"], 0.01, "no energy created (1 % of gravity work)"),
        Gate.at_least(prefix + "ritter_margin_min", m["ritter_margin_min"], 0.0, "front behind Z = 1 + 2T"),
    ]
    return T, Z, e_total


@registry.check(order=3)
def run(ctx: CheckContext) -> CheckResult:
    cell = _CASE["grid"]["cell"] * (2 if ctx.quick else 1)
    case = cases.load(CASE, [f"grid.cell={cell}"])
    res = CheckResult(NAME, REQUIREMENT)
    out = runner.run(case, ctx.runs_dir, progress=ctx.progress)
    s, ser = out.summary, out.series
    T, Z, e_total = _measure(res, out)
    wc_case = cases.load(CASE, [f"grid.cell={cell}", 'solver.fluid="weakly_compressible"', 'solver.transfer="flip"'])
    wc = runner.run(wc_case, ctx.runs_dir / "weakly_compressible", progress=ctx.progress)
    Tw, Zw, _ = _measure(res, wc, "weakly_compressible_")
    mm = refdata.read(MM_FRONT)
    plots.time_series(ctx.fig_dir / "water_column_front.png", T, {f"incompressible, h = L/{round(L / cell)}": Z,
                                                                  "weakly compressible": (Tw, Zw)},
                      exact=(T, 1 + 2 * T), exact_label="Ritter (1892) bound 1 + 2T",
                      points={"Martin & Moyce (1952), Table 2": (mm["T"], mm["Z"])},
                      xlabel="T = t sqrt(2g/L)", ylabel="Z = x_front / L", title="Surge front",
                      annotate=f"min margin to Ritter = {res.metrics['ritter_margin_min']:.2f}")
    plots.time_series(ctx.fig_dir / "water_column_energy.png", ser["t"],
                      {"kinetic": ser["kinetic_energy"], "strain": ser["strain_energy"],
                       "work of gravity": ser["gravity_work"], "kinetic + strain - work": e_total},
                      xlabel="t [s]", ylabel="J per m", title="Energy budget",
                      annotate=f"dissipated {res.metrics['energy_dissipated']:.1%} of the work of gravity")
    frames = []
    with h5py.File(ctx.runs_dir / "snapshots.h5", "r") as f:
        groups = sorted(f["snapshots"])
        for name in (groups[0], groups[len(groups) // 2], groups[-1]):
            g = f["snapshots"][name]
            frames.append((f"t = {g.attrs['time']:.2f} s", g["position"][:], g["pressure"][:] / 1e3))
    plots.particle_panels(ctx.fig_dir / "water_column_snapshots.png", frames, (0, grid_size(case)[0]), (0, 0.32),
                          "pressure [kPa]", "Water column collapse (incompressible water, CPDI weights, APIC)")
    res.figures += ["water_column_snapshots.png", "water_column_front.png", "water_column_energy.png"]
    res.notes.append(f"{s['particles']} particles, {s['steps']} steps, {s['wall_s']:.1f} s wall, "
                     f"{s['particle_updates_per_s'] / 1e6:.2f} M particle-updates/s.")
    return res
