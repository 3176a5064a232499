"""Check `rigid_obstacle`: the seed paper's stiff bar (E = 10 GPa) and a rigid bar, struck by
a collapsing water column (geometry of the elastic obstacle), with frictionless contact
between water and bar (as one continuum the water's mass on the bar's top nodes drags the
corner particle by ~1e-4 m at h = 11.7 mm, far above the physical deflection of ~1e-8 m). The stiff bar's tip must stay
below 1e-4 m, and in both runs the water must pass over the bar (5 % of it beyond the bar at
the end) and reach the far wall (its right edge within one cell of the wall at some time).
Both bars run a second time with the incompressible water under the same gates: the rigid bar's
cells bound the water with its velocity; the stiff bar and the water are one continuum, the bar's
explicit steps subcycled inside the water's step (solid_substeps = "auto" chooses explicit for a
solid held by a prescribed rigid body; docs/fsi_incompressible.md). Its acoustic step would take
about 205k coupled steps; subcycled, the coupled step is the water's."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness import cases, parallel, paths, runner
from harness.checks import registry
from harness.checks.base import CheckContext, CheckResult, Gate, body_bounds, grid_size
from harness.problems import fsi

NAME = "rigid_obstacle"
CASE = paths.CASES / "rigid_obstacle.toml"
REQUIREMENT = registry.requirement(CASE)   # one source: the case file
_CASE = cases.load(CASE)
WIDTH = grid_size(_CASE)[0]
BAR_RIGHT = body_bounds(_CASE, "bar")[1][0]   # the bar's downstream face


INCOMPRESSIBLE = ["solver.fluid=incompressible", "solver.projection=none", "contact.enabled=false"]


def _run(cell: float, model: str, out: Path, extra: tuple[str, ...] = ()):
    case = cases.load(CASE, [f"grid.cell={cell}", f'materials.1.model="{model}"', *extra])
    r = runner.run(case, out, progress=False)
    water = r.parts.mat == 0
    x = r.final["x"][water]
    return {"t": r.series["t"], "tip": r.series["tip_dx"], "water_max_x": float(r.series["water_right"].max()),
            "beyond_bar": float(np.mean(x[:, 0] > BAR_RIGHT)), "summary": r.summary}


@registry.check(order=7)
def run(ctx: CheckContext) -> CheckResult:
    res = CheckResult(NAME, REQUIREMENT)
    cell = 0.0146 if ctx.quick else _CASE["grid"]["cell"]   # the quick tier: 40 cells across
    names = ("stiff", "rigid", "rigid_incompressible", "stiff_incompressible")
    outs = parallel.pmap(_run, [(cell, "hencky", ctx.runs_dir / "stiff"), (cell, "rigid", ctx.runs_dir / "rigid"),
                                (cell, "rigid", ctx.runs_dir / "rigid_incompressible", tuple(INCOMPRESSIBLE)),
                                (cell, "hencky", ctx.runs_dir / "stiff_incompressible", tuple(INCOMPRESSIBLE))])
    for name, out in zip(names, outs, strict=True):
        if isinstance(out, Exception):
            raise RuntimeError(f"the {name}-bar run failed: {out}")
        res.metrics[f"water_gap_to_far_wall_{name}"] = WIDTH - out["water_max_x"]
        res.metrics[f"water_fraction_beyond_bar_{name}"] = out["beyond_bar"]
        res.gates.append(Gate.at_most(f"water_gap_to_far_wall_{name}", WIDTH - out["water_max_x"], cell,
                                      "the water's right edge comes within one cell of the far wall"))
        res.gates.append(Gate.at_least(f"water_fraction_beyond_bar_{name}", out["beyond_bar"], 0.05,
                                       "water has passed over the bar"))
        s = out["summary"]
        res.notes.append(f"{name} bar: {s['particles']} particles, {s['steps']} steps, {s['wall_s']:.0f} s wall.")
    tips = {}
    for k, (suffix, water) in enumerate((("", "weakly compressible"), ("_stiff_incompressible", "incompressible"))):
        stiff = outs[3 * k]   # the stiff bar's runs: 0 and 3
        key = f"tip_max_abs_dx{suffix}"
        res.metrics[key] = float(np.abs(stiff["tip"]).max())
        res.gates.insert(k, Gate.at_most(key, res.metrics[key], 1e-4, f"stiff bar, {water} water"))
        tips[f"{water} water (max |u_x| = {res.metrics[key]:.2e} m)"] = (stiff["t"], stiff["tip"])
    from harness import plots

    plots.time_series(ctx.fig_dir / "rigid_obstacle_tip.png", outs[0]["t"], tips, xlabel="t [s]",
                      ylabel="tip displacement u_x [m]", title="Stiff bar (E = 10 GPa), top-left corner")
    for name in names:
        bar, _, water = name.partition("_")
        label = f"{bar} bar" + (", incompressible water" if water else "")
        # not the case's: the snapshots' times [s]
        frames = fsi.frames(ctx.runs_dir / name, (0.15, 0.25, 0.35, 0.4))
        fsi.fsi_panels(ctx.fig_dir / f"rigid_obstacle_{name}.png", frames, 0, (0, WIDTH), (0, 0.35),
                       f"Water over the {label}")
    res.figures += ["rigid_obstacle_tip.png"] + [f"rigid_obstacle_{name}.png" for name in names]
    res.notes.insert(0, __doc__.split("\n\n", 1)[0].strip())
    return res
