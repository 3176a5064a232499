"""``python -m harness bench``: dam-break throughput per interpolation and size.

Each (size, shape) runs in its own subprocess so its peak resident memory is its own. The
case is the Martin & Moyce column (L wide, 2L high, tank 4L) with the real bulk modulus
of water; it is stepped a fixed number of steps after a short warm-up, and throughput is
particles x steps / wall seconds. Results go to reports/bench/bench.json (the contract in
DESIGN.md) with a plot of particle-updates per second against particles.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "reports" / "bench"
L = 0.146
SIZES = {"2k": 16, "8k": 32, "32k": 64, "128k": 128}  # L / h, with 2x2 particles per cell
SHAPES = ("mpm", "gimp", "cpdi")


def dam_break_case(n_per_l: int, shape: str) -> dict:
    h = L / n_per_l
    return {
        "case": {"name": f"bench_{shape}_{n_per_l}", "requirement": "benchmark"},
        "grid": {"size": [4 * L, 3 * L], "cell": h,
                 "walls": {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"}},
        "solver": {"shape": shape, "update": "musl", "cfl": 0.5, "t_end": 10.0, "gravity": [0.0, -9.81]},
        "materials": [{"name": "water", "model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 2.13e9,
                       "viscosity": 1e-3}],
        "bodies": [{"material": "water", "ppc": 2, "geometry": {"type": "rectangle", "min": [0.0, 0.0],
                                                                  "max": [L, 2 * L]}}],
    }


def measure(size: str, shape: str, steps: int) -> dict:
    """Run one benchmark in this process and return its bench.json row."""
    from harness import cases, runner

    n_per_l = SIZES[size]
    case = cases.from_dict(dam_break_case(n_per_l, shape))
    sim, parts = runner.build(case)
    sim.advance(10.0, max_steps=10)  # warm-up: first touch of every array
    t0 = time.perf_counter()
    done, _ = sim.advance(10.0, max_steps=steps)
    wall = time.perf_counter() - t0
    timers = sim.timers()
    sim.close()
    g = case["grid"]
    cells = round(g["size"][0] / g["cell"]) * round(g["size"][1] / g["cell"])
    return {"name": f"dam_break_{size}", "shape": shape, "particles": parts.n, "cells": cells, "steps": done,
            "threads": int(os.environ.get("OMP_NUM_THREADS", "1")), "wall_s": wall,
            "particle_updates_per_s": parts.n * done / wall,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "phase_s": timers}


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    from harness import plots  # noqa: F401  (sets the Agg backend)

    fig, ax = plt.subplots(figsize=(6, 4.2))
    for shape in SHAPES:
        r = sorted((x for x in rows if x["shape"] == shape), key=lambda x: x["particles"])
        ax.semilogx([x["particles"] for x in r], [x["particle_updates_per_s"] / 1e6 for x in r], "-o",
                    label=shape.upper())
    ax.set_xlabel("particles")
    ax.set_ylabel("M particle-updates / s")
    ax.set_title("Dam-break throughput (K = 2.13 GPa, MUSL, 1 thread)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(quick: bool = False) -> int:
    from harness import provenance

    sizes = ["2k", "8k"] if quick else list(SIZES)
    OUT.mkdir(parents=True, exist_ok=True)
    rows = []
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    for size in sizes:
        steps = {"2k": 400, "8k": 200, "32k": 100, "128k": 50}[size]
        for shape in SHAPES:
            code = ("import json; from harness.bench import measure; "
                    f"print(json.dumps(measure({size!r}, {shape!r}, {steps})))")
            p = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True)
            if p.returncode != 0:
                print(f"error: benchmark {size}/{shape} crashed:\n{p.stderr.strip()}", file=sys.stderr)
                return 1
            row = json.loads(p.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(f"{row['name']:>16s} {shape:5s} {row['particles']:7d} particles {row['steps']:4d} steps "
                  f"{row['wall_s']:7.3f} s  {row['particle_updates_per_s'] / 1e6:6.2f} M updates/s  "
                  f"{row['peak_rss_mb']:7.1f} MB", flush=True)
    data = {"cases": rows, "provenance": provenance.collect(REPO, REPO / "build"), "quick": quick}
    (OUT / "bench.json").write_text(json.dumps(data, indent=2) + "\n")
    _plot(rows, OUT / "bench.png")
    print(f"wrote {OUT / 'bench.json'} and {OUT / 'bench.png'}")
    return 0
