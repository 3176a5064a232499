"""Bench rows for the two water models on the Lobovsky et al. (2014) dam break (issue 20).

cases/dam_break_pressure.toml at h = 0.01 m (7200 particles) to t* = 6 (t = 1.05 s), run in
this process on the solver's current threads:

* incompressible water (the case as it is): whole run; wall time, steps, CG iterations/step;
* weakly compressible, reduced K giving c = 10 sqrt(2 g H) (the engineering shortcut): whole run;
* weakly compressible, real water (K = 2.13 GPa): its acoustic step (about 2.7e-6 s) needs
  about 4e5 steps, an hour of this machine, so it runs the first WINDOW_S of simulated time
  and its steps and wall time are extrapolated linearly to t_end (the step is set by the sound
  speed, which the flow hardly changes), and labelled so.

The speed-ups printed are the incompressible run's wall time against each of the others.
"""

from __future__ import annotations

import time

from harness import cases, runner
from harness.checks.dam_break_pressure import CASE, K_REDUCED, WC_SETTINGS

WINDOW_S = 0.01
T_END = 1.0486


def _time(case, t_end: float) -> dict:
    sim, parts = runner.build(case)
    try:
        t0 = time.perf_counter()
        steps, t = sim.advance(t_end)
        wall = time.perf_counter() - t0
        d = sim.diagnostics()
    finally:
        sim.close()
    return {"particles": parts.n, "steps": steps, "t": t, "wall_s": wall,
            "cg_per_step": d["cg_iterations_total"] / max(steps, 1)}


def run(quick: bool = False) -> list[dict]:
    h = 0.023 if quick else 0.01
    grid = [f"grid.cell={h}", "solver.max_estimated_steps=1e9"]
    rows = []
    specs = [("incompressible", [], T_END, False),
             (f"weakly compressible, K = {K_REDUCED:.3g} Pa (c = 10 sqrt(2gH))", WC_SETTINGS, T_END, False),
             ("weakly compressible, K = 2.13e9 Pa (real water)",
              [*WC_SETTINGS[:-1], "materials.0.bulk_modulus=2.13e9"], WINDOW_S, True)]
    for name, over, t_run, extrapolated in specs:
        r = _time(cases.load(CASE, [*over, *grid]), t_run)
        scale = T_END / r["t"] if extrapolated else 1.0
        rows.append({"name": name, "cell": h, "particles": r["particles"], "t_end": T_END,
                     "steps": round(r["steps"] * scale), "wall_s": r["wall_s"] * scale,
                     "cg_iterations_per_step": r["cg_per_step"],
                     "extrapolated_from_s": r["t"] if extrapolated else None})
    base = rows[0]["wall_s"]
    for row in rows:
        row["speedup_of_incompressible"] = row["wall_s"] / base
        note = f" (extrapolated from the first {row['extrapolated_from_s']:g} s)" if row["extrapolated_from_s"] else ""
        print(f"lobovsky h={h:g} {row['name']:>58s}: {row['steps']:8d} steps {row['wall_s']:9.1f} s wall"
              f"{note}; incompressible is {row['speedup_of_incompressible']:.3g}x faster"
              + (f"; {row['cg_iterations_per_step']:.0f} CG iterations/step" if row is rows[0] else ""))
    return rows
