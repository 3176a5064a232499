"""Check `hydrostatic_locking`: volumetric locking of water, with the projection off and on.

Two set-ups. (1) cases/hydrostatic_column.toml: a 1 m water column (K = 2.13 GPa) settled
by local damping in a slip-walled box, for MPM, GIMP and CPDI at h/H = 1/10, 1/20, 1/40,
with projection none, cell and nodal. Without the projection the pressure is a staircase:
the particle rows of one cell carry the same pressure, +-rho g d/2 about the exact line (d
the particle spacing), the cell-constant pressure mode of bilinear interpolation and the
signature of volumetric locking; it converges only at first order and shows as a
row-to-row oscillation. The cell-wise constant projection keeps exactly that staircase (it
projects onto the same cell-constant space), so it does not change this case; its numbers
are in the table. The nodal projection represents the linear pressure exactly, and the
gated 'projection' figures use it. (2) A collapsing water column (cases/water_column.toml,
CPDI, t = 0.2 s): here the locking is real, a particle-to-particle pressure noise far above
the hydrostatic level without the projection; the RMS deviation from the local hydrostatic
pressure is gated with both projections.
"""

from __future__ import annotations

import numpy as np

from harness import cases, metrics, parallel, paths, plots, runner
from harness.checks import registry
from harness.checks.base import CheckContext, CheckResult, Gate, body_bounds, grid_size
from harness.problems import hydrostatic as hs
from harness.solver import pressure

NAME = "hydrostatic_locking"
REQUIREMENT = registry.requirement("hydrostatic_column.toml")   # one source: the case file
COLUMN = paths.CASES / "hydrostatic_column.toml"
DAM = paths.CASES / "water_column.toml"
_COLUMN, _DAM = cases.load(COLUMN), cases.load(DAM)
H = body_bounds(_COLUMN, "column")[1][1]   # the settled column's height
DAM_HEIGHT = body_bounds(_DAM, "column")[1][1]
SHAPES = ("mpm", "gimp", "cpdi")
PROJS = ("none", "cell", "nodal")


def run_column(shape: str, proj: str, n: int):
    case = cases.load(COLUMN, [f"grid.cell={H / n}", f'solver.shape="{shape}"', f'solver.projection="{proj}"'])
    r = runner.run(case, None, progress=False, snapshots=False)
    return r, hs.column_errors(r.final["x"], r.parts.x, r.final["sigma"], r.parts.mass, H)


def run_dam(proj: str, cell: float):
    """The collapsing column (weakly compressible, CPDI) to t = 0.2 s with projection proj."""
    case = cases.load(DAM, [f"grid.cell={cell}", 'solver.shape="cpdi"', f'solver.projection="{proj}"',
                            "solver.t_end=0.2", 'solver.fluid="weakly_compressible"', 'solver.transfer="flip"'])
    return runner.run(case, None, progress=False, snapshots=False)


@registry.check(order=4)
def run(ctx: CheckContext) -> CheckResult:
    levels = [10, 20] if ctx.quick else [10, 20, 40]
    res = CheckResult(NAME, REQUIREMENT)
    table = {}
    finest = {}
    cell_dam = _DAM["grid"]["cell"] * (2 if ctx.quick else 1)
    # every run at once on the verify's workers, the finest grids and the collapsing columns first
    cols = [(shape, proj, n) for n in levels[::-1] for shape in SHAPES for proj in PROJS]
    outs = parallel.pmap(parallel.call, [(run_dam, (proj, cell_dam)) for proj in PROJS]
                         + [(run_column, c) for c in cols])
    for what, out in zip([f"collapsing column, projection {p}" for p in PROJS] + [f"column {c}" for c in cols], outs,
                         strict=True):
        if isinstance(out, Exception):
            raise RuntimeError(f"the {what} run failed: {out}")
    dams = dict(zip(PROJS, outs[:len(PROJS)], strict=True))
    for (shape, proj, n), (r, e) in zip(cols, outs[len(PROJS):], strict=True):
        table[shape, proj, n] = e
        if shape == "cpdi" and n == levels[-1]:
            finest[proj] = r
    best = table["cpdi", "nodal", levels[-1]]
    none = table["cpdi", "none", levels[-1]]
    cell = table["cpdi", "cell", levels[-1]]
    res.metrics.update({
        "l2_rel_error_projection": best["l2"], "l2_rel_error_no_projection": none["l2"],
        "max_rel_error_projection": best["max"], "max_rel_error_no_projection": none["max"],
        "oscillation_index_projection": best["oscillation"], "oscillation_index_no_projection": none["oscillation"],
        "l2_rel_error_lagrangian_projection": best["l2_lagrangian"],
        "l2_rel_error_lagrangian_no_projection": none["l2_lagrangian"],
        "l2_rel_error_cell_projection": cell["l2"],
        "l2_ratio_no_projection_to_projection": none["l2"] / max(best["l2"], 1e-300),
    })
    res.gates += [
        Gate.at_most("l2_rel_error_projection", best["l2"], 0.005, "CPDI, nodal projection, finest grid"),
        Gate.at_least("l2_ratio_no_projection_to_projection", res.metrics["l2_ratio_no_projection_to_projection"],
                      4.0),
    ]
    # the collapsing column: where the pressure noise is
    noise, frames = {}, []
    for proj in PROJS:
        r = dams[proj]
        noise[proj] = hs.pressure_noise(r.final["x"], r.final["sigma"], cell_dam, cell_dam / 2, DAM_HEIGHT)
        frames.append((f"{proj}: noise {noise[proj]:.3f}", r.final["x"], pressure(r.final["sigma"]) / 1e3))
    res.metrics.update({f"dambreak_pressure_noise_{k}": v for k, v in noise.items()})
    for proj in ("cell", "nodal"):
        ratio = noise["none"] / max(noise[proj], 1e-300)
        res.metrics[f"dambreak_noise_ratio_{proj}"] = ratio
        res.gates.append(Gate.at_least(f"dambreak_noise_ratio_{proj}", ratio, 4.0,
                                       "collapsing column, CPDI, t = 0.2 s"))
    _tables(res, table, levels)
    _figures(ctx, res, table, levels, finest, frames)
    res.notes.append(__doc__.split("\n\n", 1)[1].strip())
    res.notes.append("Oscillation index: RMS over interior particle rows of the second difference of the "
                     "row-mean pressure error, divided by rho0 g H. Pressure noise of the collapsing column: "
                     "RMS of p minus rho g (local surface - y), local surface from vertical bins one cell wide, "
                     "divided by rho g 2L.")
    return res


def _tables(res, table, levels):
    head = "| shape | h/H | projection | L2 | max | L2 (Lagrangian) | oscillation |\n|---|---|---|---|---|---|---|\n"
    rows = [f"| {s.upper()} | 1/{n} | {p} | {e['l2']:.2e} | {e['max']:.2e} | {e['l2_lagrangian']:.2e} | "
            f"{e['oscillation']:.2e} |" for (s, p, n), e in sorted(table.items())]
    res.tables.append("Settled column, relative pressure errors (normalised by rho0 g H):\n\n" + head + "\n".join(rows))
    hh = np.array([H / n for n in levels])
    for proj in ("none", "nodal"):
        e = np.array([table["cpdi", proj, n]["l2"] for n in levels])
        res.tables.append(f"CPDI, projection {proj}: convergence of the L2 error\n\n"
                          + metrics.convergence_table(hh, e, "L2 / (rho0 g H)"))


def _figures(ctx, res, table, levels, finest, frames):
    import matplotlib.pyplot as plt

    n = levels[-1]
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2), sharey=True)
    for ax, proj in zip(axes, PROJS, strict=True):
        r = finest[proj]
        p = pressure(r.final["sigma"]) / 1e3
        y = r.final["x"][:, 1]
        ax.plot(p, y, ".", ms=2, label="particles")
        yy = np.linspace(0, H, 50)
        ax.plot(hs.RHO * hs.G * (H - yy) / 1e3, yy, "k--", lw=1, label="rho0 g (H - y)")
        ax.set_title(f"{proj}: L2 = {table['cpdi', proj, n]['l2']:.2e}", fontsize=10)
        ax.set_xlabel("pressure [kPa]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("y [m]")
    fig.suptitle(f"Settled column, CPDI, h = H/{n}: pressure against height")
    fig.tight_layout()
    fig.savefig(ctx.fig_dir / "hydrostatic_profile.png", dpi=110)
    plt.close(fig)

    col = [(f"{proj}", finest[proj].final["x"],
            (pressure(finest[proj].final["sigma"]) - hs.RHO * hs.G * (H - finest[proj].final["x"][:, 1]))
            / (hs.RHO * hs.G * H)) for proj in PROJS]
    plots.particle_panels(ctx.fig_dir / "hydrostatic_error_field.png", col, (0, grid_size(_COLUMN)[0]), (0, H),
                          "(p - rho0 g (H - y)) / (rho0 g H)", f"Settled column, CPDI, h = H/{n}")
    # not the case's: 0.2 m is the plot's height (the water below it at t = 0.2 s)
    plots.particle_panels(ctx.fig_dir / "dambreak_pressure_field.png", frames, (0, grid_size(_DAM)[0]), (0, 0.2),
                          "pressure [kPa]", "Collapsing column at t = 0.2 s (CPDI): projection none / cell / nodal")
    curves = {}
    for shape in SHAPES:
        for proj in ("none", "nodal"):
            curves[f"{shape} {proj}"] = (np.array([H / k for k in levels]),
                                         np.array([table[shape, proj, k]["l2"] for k in levels]))
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for name, (h, e) in curves.items():
        ax.loglog(h, e, "-o" if "none" in name else "-s", color=plots.COLORS[name.split()[0]],
                  alpha=1.0 if "nodal" in name else 0.5, label=name)
    ax.loglog(curves["cpdi none"][0], curves["cpdi none"][1][0] * (curves["cpdi none"][0] / curves["cpdi none"][0][0]),
              "k--", lw=0.8, label="slope 1")
    ax.set_xlabel("h [m]")
    ax.set_ylabel("L2 pressure error / (rho0 g H)")
    ax.set_title("Settled column: error against h")
    ax.text(0.98, 0.03, f"CPDI finest: {res.metrics['l2_rel_error_no_projection']:.2e} -> "
            f"{res.metrics['l2_rel_error_projection']:.2e}", transform=ax.transAxes, ha="right", fontsize=9,
            bbox=dict(boxstyle="round", fc="white", ec="0.7"))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(ctx.fig_dir / "hydrostatic_convergence.png", dpi=110)
    plt.close(fig)
    res.figures += ["hydrostatic_profile.png", "hydrostatic_error_field.png", "hydrostatic_convergence.png",
                    "dambreak_pressure_field.png"]
