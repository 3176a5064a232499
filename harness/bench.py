"""``python -m harness bench``: dam-break throughput per interpolation, size and thread count.

The case is the Martin & Moyce column (L wide, 2L high, tank 4L) with the real bulk modulus
of water, MUSL, 2x2 particles per cell and the cell-wise volumetric projection on (the
gated dam-break configuration). Each (size, shape, threads) runs REPEATS times, each in its
own subprocess (so its peak memory is its own and OMP_NUM_THREADS takes effect), stepped a
fixed number of steps after a short warm-up; throughput is particles x steps / wall seconds
and the median of the repeats is reported, with the solver's own phase timers. Repeats are
interleaved across configurations so one slow spell of a shared machine does not sink all
repeats of one row.

Memory per particle is the growth of peak resident memory over the interpreter with the
solver library loaded, with (bytes_per_particle) and without (solver_bytes_per_particle)
the harness's own copy of the seeded particles: the second is the solver's particle, shape,
grid, projection and scheduling arrays.

Outputs: reports/bench/bench.json (the contract in DESIGN.md), bench.png (particle-updates
per second against particles, 1 and 2 threads) and phases.png (where a step's time goes).
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "reports" / "bench"
L = 0.146
SIZES = {"2k": 16, "8k": 32, "32k": 64, "128k": 128}  # L / h, with 2x2 particles per cell
STEPS = {"2k": 400, "8k": 200, "32k": 100, "128k": 50}
SHAPES = ("mpm", "gimp", "cpdi")
THREADS = (1, 2)
REPEATS = 3
PROJECTION = "cell"
PHASES = ("shape", "p2g", "grid", "g2p", "deformation", "stress", "projection")


def dam_break_case(n_per_l: int, shape: str, projection: str = PROJECTION) -> dict:
    h = L / n_per_l
    return {
        "case": {"name": f"bench_{shape}_{n_per_l}", "requirement": "benchmark"},
        "grid": {"size": [4 * L, 3 * L], "cell": h,
                 "walls": {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"}},
        "solver": {"shape": shape, "update": "musl", "cfl": 0.5, "t_end": 10.0, "gravity": [0.0, -9.81],
                   "projection": projection},
        "materials": [{"name": "water", "model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 2.13e9,
                       "viscosity": 1e-3}],
        "bodies": [{"material": "water", "ppc": 2, "geometry": {"type": "rectangle", "min": [0.0, 0.0],
                                                                  "max": [L, 2 * L]}}],
    }


def _rss_mb() -> float:
    """Current resident memory of this process [MB] (Linux)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def measure(size: str, shape: str, steps: int) -> dict:
    """Run one benchmark in this process and return its bench.json row."""
    from harness import cases, runner, solver
    from harness.seeding import seed

    n_per_l = SIZES[size]
    case = cases.from_dict(dam_break_case(n_per_l, shape))
    base_mb = _rss_mb()  # interpreter, numpy and the solver library, before any particle exists
    parts = seed(case)
    seeded_mb = _rss_mb()  # plus the harness's own copy of the seeded particles
    sim, parts = runner.build(case, parts)
    sim.advance(10.0, max_steps=10)  # warm-up: first touch of every array
    t0_timers = sim.timers()
    t0 = time.perf_counter()
    done, _ = sim.advance(10.0, max_steps=steps)
    wall = time.perf_counter() - t0
    timers = {k: v - t0_timers[k] for k, v in sim.timers().items()}
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    sim.close()
    g = case["grid"]
    cells = round(g["size"][0] / g["cell"]) * round(g["size"][1] / g["cell"])
    updates = parts.n * done
    return {"name": f"dam_break_{size}", "size": size, "shape": shape, "projection": PROJECTION,
            "particles": parts.n, "cells": cells, "steps": done, "threads": solver.threads(),
            "wall_s": wall, "particle_updates_per_s": updates / wall,
            "peak_rss_mb": peak_mb, "base_rss_mb": base_mb,
            "bytes_per_particle": (peak_mb - base_mb) * 2**20 / parts.n,
            "solver_bytes_per_particle": (peak_mb - seeded_mb) * 2**20 / parts.n,
            "phase_s": timers, "phase_ns_per_update": {k: v / updates * 1e9 for k, v in timers.items()}}


def _run_one(size: str, shape: str, threads: int) -> dict:
    code = ("import json; from harness.bench import measure; "
            f"print(json.dumps(measure({size!r}, {shape!r}, {STEPS[size]})))")
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    p = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"benchmark {size}/{shape}/{threads} thread(s) crashed:\n{p.stderr.strip()}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def _median_row(runs: list[dict]) -> dict:
    """The run with the median throughput, with the spread of all repeats."""
    runs = sorted(runs, key=lambda r: r["particle_updates_per_s"])
    row = dict(runs[len(runs) // 2])
    row["repeats"] = len(runs)
    row["particle_updates_per_s_all"] = [r["particle_updates_per_s"] for r in runs]
    row["particle_updates_per_s"] = statistics.median(row["particle_updates_per_s_all"])
    row["peak_rss_mb"] = max(r["peak_rss_mb"] for r in runs)
    row["bytes_per_particle"] = max(r["bytes_per_particle"] for r in runs)
    row["solver_bytes_per_particle"] = max(r["solver_bytes_per_particle"] for r in runs)
    return row


def summary(rows: list[dict]) -> dict:
    """The issue's targets, evaluated on the CPDI rows (median throughputs)."""
    def pups(size, threads):
        r = [x for x in rows if x["shape"] == "cpdi" and x["size"] == size and x["threads"] == threads]
        return r[0]["particle_updates_per_s"] if r else None

    out = {}
    one, two = pups("32k", 1), pups("32k", 2)
    if one:
        out["cpdi_32k_1thread_mups"] = one / 1e6
    if one and two:
        out["cpdi_32k_speedup_2threads"] = two / one
    small, big = pups("8k", 1), pups("128k", 1)
    if small and big:
        out["cpdi_time_per_update_128k_over_8k"] = small / big
    big_cp = [x for x in rows if x["shape"] == "cpdi" and x["particles"] >= 32000]
    if big_cp:  # peak RSS growth per particle: whole process, and without the harness's seeded copy
        out["cpdi_max_bytes_per_particle"] = max(x["bytes_per_particle"] for x in big_cp)
        out["cpdi_max_solver_bytes_per_particle"] = max(x["solver_bytes_per_particle"] for x in big_cp)
    return out


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    from harness import plots  # noqa: F401  (sets the Agg backend)

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for i, shape in enumerate(SHAPES):
        for threads, style in zip(THREADS, ("-o", "--s"), strict=True):
            r = sorted((x for x in rows if x["shape"] == shape and x["threads"] == threads),
                       key=lambda x: x["particles"])
            if r:
                ax.semilogx([x["particles"] for x in r], [x["particle_updates_per_s"] / 1e6 for x in r], style,
                            color=f"C{i}", label=f"{shape.upper()}, {threads} thread{'s' * (threads > 1)}")
    ax.set_xlabel("particles")
    ax.set_ylabel("M particle-updates / s (median of repeats)")
    ax.set_title(f"Dam break, K = 2.13 GPa, MUSL, projection {PROJECTION}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_phases(rows: list[dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    from harness import plots  # noqa: F401

    sel = [x for x in rows if x["threads"] == 1]
    sel.sort(key=lambda x: (SHAPES.index(x["shape"]), x["particles"]))
    fig, ax = plt.subplots(figsize=(7.5, 4.4))
    bottom = [0.0] * len(sel)
    for j, ph in enumerate(PHASES):
        vals = [x["phase_ns_per_update"].get(ph, 0.0) for x in sel]
        ax.bar(range(len(sel)), vals, bottom=bottom, color=f"C{j}", label=ph)
        bottom = [b + v for b, v in zip(bottom, vals, strict=True)]
    ax.set_xticks(range(len(sel)), [f"{x['shape']}\n{x['size']}" for x in sel], fontsize=8)
    ax.set_ylabel("ns per particle-update (1 thread)")
    ax.set_title("Where a step's time goes (solver phase timers)")
    ax.legend(fontsize=8, ncol=2)
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(quick: bool = False) -> int:
    from harness import provenance

    sizes = ["2k", "8k"] if quick else list(SIZES)
    OUT.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        tqdm = None
    jobs = [(size, shape, threads) for size in sizes for shape in SHAPES for threads in THREADS]
    bar = tqdm(total=len(jobs) * REPEATS, desc="bench", unit="run", leave=False, disable=None) if tqdm else None
    # Repeats are interleaved (round 1 of every job, then round 2, ...): on a shared VM a slow
    # spell of tens of seconds then hits one repeat of several jobs, not all repeats of one.
    runs: dict[tuple, list[dict]] = {j: [] for j in jobs}
    for _ in range(REPEATS):
        for job in jobs:
            try:
                runs[job].append(_run_one(*job))
            except RuntimeError as exc:
                if bar:
                    bar.close()
                print(f"error: {exc}", file=sys.stderr)
                return 1
            if bar:
                bar.update()
    for (size, shape, threads) in jobs:
        row = _median_row(runs[(size, shape, threads)])
        rows.append(row)
        ph = row["phase_ns_per_update"]
        msg = (f"{row['name']:>16s} {shape:5s} {threads}T {row['particles']:7d} p {row['steps']:4d} steps "
               f"{row['particle_updates_per_s'] / 1e6:6.2f} M updates/s (median of {REPEATS})  "
               f"{row['bytes_per_particle']:5.0f} B/p ({row['solver_bytes_per_particle']:4.0f} solver)  ns/update: "
               + " ".join(f"{k} {ph.get(k, 0.0):.0f}" for k in PHASES))
        (bar.write if bar else print)(msg)
    if bar:
        bar.close()
    from harness import bench_water

    data = {"cases": rows, "summary": summary(rows), "repeats": REPEATS, "projection": PROJECTION,
            "provenance": provenance.collect(REPO, REPO / "build"), "quick": quick,
            "water_models": bench_water.run(quick)}
    (OUT / "bench.json").write_text(json.dumps(data, indent=2) + "\n")
    _plot(rows, OUT / "bench.png")
    _plot_phases(rows, OUT / "phases.png")
    targets = ", ".join(f"{k} = {v:.3g}" for k, v in data["summary"].items() if v is not None)
    print("summary: " + (targets or "the issue's targets need the 32k and 128k rows (run without --quick)"))
    print(f"wrote {OUT / 'bench.json'}, {OUT / 'bench.png'} and {OUT / 'phases.png'}")
    return 0
