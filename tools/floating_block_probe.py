"""One floating_block run with the check's own set-up and gates, plus what the subcycling trials
measured (docs/notes/fsi_subcycling.md).

``.venv/bin/python -m tools.floating_block_probe [--substeps off|auto|implicit] [--rho 500] [--cell 0.05]
[--t-end 4.0] [--set key=value ...]``

The case is harness.checks.floating_block's (its `overrides`: the block's density, the water
bodies around its release position), sampled every series_every as the check does; printed as one
JSON line: steps, wall seconds, the check's `measures` and its four gates, and, at six equal
times, the kinetic energy [J], the number of water particles inside the block's bounding box
(water that ran into the block) and the change of the tank's energy KE + strain + sum m g y [J];
also that change's largest value over every sample, and the same without the volume correction's
lift of the water (the energy plus the correction's gravity work, diagnostics `correction_work`:
the correction moves particles without a force, and sinking_block's energy_excess leaves it out).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from harness import cases, runner, water
from harness.checks import floating_block as fb


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--substeps", default="auto", choices=("auto", "off", "explicit", "implicit"))
    ap.add_argument("--rho", type=float, default=500.0, choices=[r for r, _ in fb.RUNS])
    ap.add_argument("--cell", type=float, default=0.05)
    ap.add_argument("--t-end", type=float, default=4.0)
    ap.add_argument("--set", action="append", default=[], help="further case overrides, key=value")
    a = ap.parse_args()
    bottom = dict(fb.RUNS)[a.rho]
    case = cases.load(fb.CASE, [*fb.overrides(a.rho, bottom, a.t_end), f"grid.cell={a.cell}",
                                f'solver.solid_substeps="{a.substeps}"', *a.set])
    width, every = case["grid"]["size"][0], case["solver"]["series_every"]
    sim, parts = runner.build(case)
    blk = parts.mat == 1
    ib = np.flatnonzero(blk)
    row = ib[parts.x[ib, 1] < parts.x[ib, 1].min() + 1e-9]
    g = float(np.linalg.norm(case["solver"]["gravity"]))
    e0 = sim.diagnostics()["strain_energy"] + g * float(np.sum(parts.mass * parts.x[:, 1]))
    rec = {k: [] for k in ("t", "far", "bottom", "tilt", "ke", "ke_block", "strain", "inside", "energy", "flow")}
    t0 = time.perf_counter()
    try:
        for i in range(1, int(round(a.t_end / every)) + 1):
            _, t = sim.advance(i * every)
            st, d = sim.state(), sim.diagnostics()
            x, v, r = st["x"], st["v"], st["r"]
            far = 0.5 * (water.surface_height(x[~blk], r[~blk], 0.0, fb.FAR)
                         + water.surface_height(x[~blk], r[~blk], width - fb.FAR, width))
            yb = x[row, 1] - np.abs(r[row, 1]) - np.abs(r[row, 3])
            lo, hi = x[blk].min(axis=0), x[blk].max(axis=0)
            rec["t"].append(t)
            rec["far"].append(far)
            rec["bottom"].append(float(yb.mean()))
            rec["tilt"].append(float(np.degrees(np.arctan(np.polyfit(x[row, 0], yb, 1)[0]))))
            rec["ke"].append(d["kinetic_energy"])
            rec["strain"].append(d["strain_energy"])
            rec["ke_block"].append(float(0.5 * np.sum(parts.mass[blk, None] * v[blk] ** 2)))
            rec["inside"].append(int(np.sum(np.all((x[~blk] > lo) & (x[~blk] < hi), axis=1))))
            rec["energy"].append(d["kinetic_energy"] + d["strain_energy"]
                                 + g * float(np.sum(parts.mass * x[:, 1])) - e0)
            rec["flow"].append(rec["energy"][-1] + d["correction_work"])
        steps = int(sim.diagnostics()["steps"])
    finally:
        sim.close()
    o = {k: np.asarray(val) for k, val in rec.items()}
    d = a.rho / fb.RHO_W * fb.HB
    o["err"] = (o["far"] - o["bottom"] - d) / fb.HB
    o.update(rho_s=a.rho, d=d, m_b=float(parts.mass[blk].sum()), m_all=float(parts.mass.sum()), steps=steps)
    m = fb.measures(o)
    bound = 0.05 if a.cell >= 0.05 else 0.025
    gates = {"draft_err": m["draft_err"] <= bound, "tilt_max_deg": m["tilt_max_deg"] < 1.0,
             "decay_ratio": m["decay_ratio"] <= 1.0, "ke_end": m["ke_end"] <= 1e-5}
    at = [len(o["t"]) * k // 6 - 1 for k in range(1, 7)]
    print(json.dumps({"substeps": a.substeps, "rho_s": a.rho, "cell": a.cell, "t_end": a.t_end, "steps": steps,
                      "wall_s": round(time.perf_counter() - t0, 1),
                      "t": [round(float(o["t"][j]), 3) for j in at],
                      "ke_J": [round(float(o["ke"][j]), 4) for j in at],
                      "water_inside_block": [int(o["inside"][j]) for j in at],
                      "energy_change_J": [round(float(o["energy"][j]), 4) for j in at],
                      "energy_max_J": round(float(o["energy"].max()), 4),
                      "energy_less_correction_J": [round(float(o["flow"][j]), 4) for j in at],
                      "energy_less_correction_max_J": round(float(o["flow"].max()), 4),
                      **{k: float(f"{val:.4g}") for k, val in m.items()},
                      "gates": gates, "passed": all(gates.values())}))


if __name__ == "__main__":
    main()
