"""Lobovsky dam break: runs for the sensor study of issue 38 (docs/notes/dam_break_pressure_sensor4.md).

``.venv/bin/python -m tools.dam_break_pressure_study OUT.npz --cell 0.01 [--set key=value ...]``

Steps cases/dam_break_pressure.toml (with the overrides) in 0.01 t* windows, as the check does,
and stores per sample: t*, the check's sensor (the wall column's cell pressure), the right-hand
3 columns of cell pressure and fill, the volume change (harness.water.volume_change), and the
water particles within 30 mm of the downstream wall and below 150 mm (position, pressure), so
that other sensor definitions can be evaluated afterwards. Prints the wall time, the cell
sensor means over 3 <= t* <= 5.5 and the volume change.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))   # a developer tool: the repository's harness

from harness import cases, paths, runner, water  # noqa: E402
from harness.checks import dam_break_pressure as dbp  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--cell", type=float, default=0.01)
    ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    case = cases.load(paths.CASES / "dam_break_pressure.toml", [f"grid.cell={a.cell}", *a.set])
    g = case["grid"]
    h, t_end = g["cell"], case["solver"]["t_end"]
    xw = g["origin"][0] + g["size"][0]
    sim, parts = runner.build(case)
    t0 = time.perf_counter()
    t, ts, cell_s, cols, fills, px, pp, pn, vch = 0.0, [], [], [], [], [], [], [], []
    ncell = (round(g["size"][0] / h), round(g["size"][1] / h))
    while t < t_end * (1 - 1e-12):
        _, t = sim.advance(min(t + 0.01 / dbp.TSTAR, t_end), land=False)
        gp = sim.grid_pressure()
        cp = gp["pressure"]
        st = sim.state()
        x, p = st["x"], -(st["sigma"][:, 0] + st["sigma"][:, 1] + st["sigma"][:, 3]) / 3.0
        sel = (x[:, 0] > xw - 0.03) & (x[:, 1] < 0.15)
        ts.append(t * dbp.TSTAR)
        cell_s.append([water.wall_sensor(cp, g["origin"], h, "right", z, dbp.DIAMETER) for z in dbp.SENSORS.values()])
        cols.append(cp[-3:, :].copy())
        fills.append(gp["fill"][-3:, :].copy())
        px.append(x[sel].copy())
        pp.append(p[sel].copy())
        pn.append(int(sel.sum()))
        vch.append(water.volume_change(x, st["vol"], g["origin"], h, ncell))
    wall = time.perf_counter() - t0
    d = sim.diagnostics()
    sim.close()
    tt = np.array(ts)
    cs = np.array(cell_s) / (dbp.RHO * dbp.G * dbp.H)
    off = np.concatenate([[0], np.cumsum(pn)])
    np.savez_compressed(a.out, tstar=tt, cell_sensor=cs, cols=np.array(cols), fills=np.array(fills),
                        px=np.concatenate(px), pp=np.concatenate(pp), offsets=off, cell=h, wall=wall,
                        steps=d["steps"], cg=d["cg_iterations_total"], dp=h / case["bodies"][0]["ppc"],
                        settings=np.array(a.set), volume_change=np.array(vch))
    w = (tt >= 3) & (tt <= 5.5)
    print(f"h={h} steps={int(d['steps'])} wall={wall:.1f}s cg/step={d['cg_iterations_total'] / d['steps']:.1f} "
          f"cell-sensor means s3={cs[w, 0].mean():.3f} s4={cs[w, 1].mean():.3f} "
          f"volume change at t*=3, 5.5, 6: {vch[np.argmin(abs(tt - 3))]:.4f} {vch[np.argmin(abs(tt - 5.5))]:.4f} "
          f"{vch[-1]:.4f}")


if __name__ == "__main__":
    main()
