"""Pressure-solver benchmark: MIC(0)-CG against multigrid-CG on the Lobovsky dam break.

``.venv/bin/python -m tools.pressure_bench [--cells 0.01 0.005 0.0025] [--tstar 1.0] [--steps 20]``

For each cell size the case (cases/dam_break_pressure.toml, incompressible, APIC) is stepped with
the multigrid preconditioner to t* = ``--tstar`` (the collapsing column: a moving surface), its
full state is kept, and then ``--steps`` steps are run from that same state with each
preconditioner. Printed per preconditioner: CG iterations of the step's physical solve (mean,
max), iterations of all the step's solves (volume correction included), and seconds in the
pressure solves per step (the solver's own timer, which includes assembly of the preconditioner).
The numbers of docs/notes/pressure_multigrid.md come from here.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))   # a developer tool: the repository's harness

from harness import cases, paths, runner  # noqa: E402
from harness.solver import PRECONDS, _call  # noqa: E402

H, G = 0.3, 9.81


def measure(cell: float, tstar: float, steps: int) -> dict:
    case = cases.load(paths.CASES / "dam_break_pressure.toml",
                      [f"grid.cell={cell}", 'solver.pressure_precond="multigrid"'])
    sim, parts = runner.build(case)
    t0 = tstar / math.sqrt(G / H)
    sim.advance(t0, land=False)
    full = sim.get_full_state()
    ncell = round(case["grid"]["size"][0] / cell) * round(case["grid"]["size"][1] / cell)
    out = {"cell": cell, "H_over_h": round(H / cell), "cells": ncell, "particles": len(parts.x), "t_star": tstar,
           "water_cells": None}
    for name in ("mic0", "multigrid"):
        _call("cpdi_set_option", sim._handle, "pressure_precond", [float(PRECONDS[name])])
        sim.set_full_state(full["particles"], full["scalars"])
        phys, total, solve_s = [], [], []
        wall0 = time.perf_counter()
        for _ in range(steps):
            before = sim.timers()["pressure_solve"]
            sim.advance(10.0, max_steps=1, land=False)
            solve_s.append(sim.timers()["pressure_solve"] - before)
            phys.append(sim.pressure_stats()["iterations"])
            total.append(sim.diagnostics()["cg_iterations"])
        wall = time.perf_counter() - wall0
        grid = sim.grid_pressure()
        out["water_cells"] = int((grid["water"] == 1).sum())
        out[name] = {"iterations_mean": float(np.mean(phys)), "iterations_max": int(np.max(phys)),
                     "iterations_all_solves_mean": float(np.mean(total)),
                     "solve_s_per_step": float(np.mean(solve_s)), "step_wall_s": wall / steps}
    sim.close()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="tools/pressure_bench.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", type=float, nargs="+", default=[0.01, 0.005, 0.0025])
    ap.add_argument("--tstar", type=float, default=1.0)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--json", type=str, default=None, help="also write the rows to this file")
    a = ap.parse_args(argv)
    rows = []
    for cell in a.cells:
        r = measure(cell, a.tstar, a.steps)
        rows.append(r)
        m, g = r["mic0"], r["multigrid"]
        print(f"H/{r['H_over_h']}: {r['cells']} cells, {r['water_cells']} water, {r['particles']} particles | "
              f"mic0 {m['iterations_mean']:.1f} it (max {m['iterations_max']}), {1e3 * m['solve_s_per_step']:.2f} ms | "
              f"multigrid {g['iterations_mean']:.1f} it (max {g['iterations_max']}), "
              f"{1e3 * g['solve_s_per_step']:.2f} ms | all solves/step {m['iterations_all_solves_mean']:.1f} vs "
              f"{g['iterations_all_solves_mean']:.1f}", flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
