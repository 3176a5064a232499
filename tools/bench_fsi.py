"""Bench rows for the solids in the incompressible water (issue 37, "Performance").

1. sinking_block against the same tank without the block: cases/sinking_block.toml as the check
   runs it (harness.checks.sinking_block: the Hencky block, and the block as a free rigid body,
   RIGID), and the case with the block's body removed (without: its body, its probes and its
   material go, the water and everything else stay). The water steps once per coupled step with
   one pressure solve (cpdi_incompressible; the volume correction's second solve only where the
   water over-fills, in both runs alike), and the solver counts steps, not solves: so the measure is
   steps per simulated second, and the gate is steps(with the block) / steps(the tank alone) <=
   GATE_TANK for each variant, over the case's t_end (5 s; the quick path runs the same, 12 s of
   wall: over the first second alone the ratio reads higher, the impact's share). The tank alone
   is the same run for both variants (the block's material goes with the block). Steps are
   deterministic; wall times, the pressure solve's timer and the steps of each simulated second
   are reported beside them. The water's step is cfl h / (sqrt(2) max|v| + sqrt(g h)) (cpdi_fsi),
   so a tank at rest steps at sqrt(g h) alone and the block's run pays for the fastest particle.

2. elastic_obstacle with the incompressible water at h = 4 mm (the check's variant: its
   INCOMPRESSIBLE overrides, contact off, grid.cell = 0.004): with `--base SHA`, at the base
   commit (its own checkout from tools.bench.prepare_base, its own harness, case file and check's
   overrides) and at this one, on one thread, in turns (base first in even pairs, new first in
   odd ones, BASE_REPEATS pairs), gate median wall(base) / median wall(new) >= GATE_BASE_SPEEDUP.
   Without a base, this checkout's wall time and steps only (no gate). Not on the quick path.

Every run is a fresh one-thread process (tools.bench.python), so a crash is reported with its
error and the thread count is the one asked for.
"""

from __future__ import annotations

import copy
import json
import statistics
from pathlib import Path

from harness import cases
from tools import bench

GATE_TANK = 2.0            # steps per simulated second: with the block / the tank alone, at most
GATE_BASE_SPEEDUP = 5.0    # elastic_obstacle incompressible 4 mm: wall(base) / wall(new), at least
BASE_REPEATS = 2           # interleaved base/new pairs of item 2
EO_CELL = 0.004

# A run in a fresh process of any checkout (a base's harness may lack tools/bench_fsi): the case
# file, its overrides, and optionally the overrides of a check's module (looked up in that
# checkout) and a body to drop (this checkout only). Prints the run's summary as JSON.
CHILD = """
import importlib, json, sys
from harness import cases, runner
spec = json.loads(sys.argv[1])
over = list(spec["overrides"])
if spec.get("check_overrides"):
    mod, name = spec["check_overrides"].rsplit(".", 1)
    over = [*getattr(importlib.import_module(mod), name), *over]
case = cases.load(spec["case"], over)
if spec.get("drop"):
    from tools.bench_fsi import without
    case = without(case, spec["drop"])
fluids = [m["model"] == "newtonian_fluid" for m in case["materials"]]
try:
    r = runner.run(case, None, progress=False, snapshots=False)
except runner.RunFailed as exc:
    print(json.dumps({"error": str(exc), **{k: exc.summary.get(k) for k in ("steps", "simulated_time")}}))
    sys.exit(0)
s = r.summary
solid = sum(1 for m in r.parts.mat if not fluids[m])
t, n = r.series["t"], r.series["steps"]   # steps so far at each sample: the steps of every whole second
per_s = [int(n[t <= k + 1e-9][-1]) for k in range(1, int(s["simulated_time"] + 1e-9) + 1)]
print(json.dumps({"particles": s["particles"], "solid_particles": solid, "water_particles": s["particles"] - solid,
                  "steps": s["steps"], "simulated_time": s["simulated_time"], "wall_s": s["wall_s"],
                  "pressure_solve_s": s["timers"].get("pressure_solve"), "overrides": over,
                  "steps_by_second": [b - a for a, b in zip([0, *per_s], per_s)]}))
"""


def without(case: cases.Case, body: str) -> cases.Case:
    """The same case without the body named `body`: its probes and its material go with it when
    nothing else uses them; the rest (the water, the grid, the solver) is the case's own."""
    data = copy.deepcopy(case.data)
    names = [b.get("name") for b in data["bodies"]]
    if body not in names:
        raise ValueError(f"{case.name} has no body named {body!r} (bodies: {names})")
    mat = data["bodies"].pop(names.index(body))["material"]
    if all(b["material"] != mat for b in data["bodies"]):
        data["materials"] = [m for m in data["materials"] if m["name"] != mat]
        data["probes"] = {k: p for k, p in data["probes"].items() if p.get("material") != mat}
    data["case"]["name"] = f"{case.name}_without_{body}"
    out = cases.from_dict(data)
    out.path, out.overrides = case.path, [*case.overrides, f"(body {body} removed)"]
    return out


def _spec(case: Path | str, overrides=(), check_overrides: str | None = None, drop: str | None = None) -> str:
    return json.dumps({"case": str(case), "overrides": list(overrides), "check_overrides": check_overrides,
                       "drop": drop})


def _run(spec: str, repo: Path = bench.REPO, what: str = "") -> dict:
    out = bench._collect(bench.python(CHILD, 1, repo, (spec,)), what)
    if "error" in out:
        raise RuntimeError(f"{what}: {out['error']}")
    return out


def tank_rows(say) -> dict:
    """Item 1: sinking_block (Hencky block, free rigid body) against the tank without the block."""
    from harness.checks import sinking_block as sb

    t_end = cases.load(sb.CASE)["solver"]["t_end"]
    over = [f"solver.t_end={t_end}"]
    runs = {"tank": _run(_spec(sb.CASE, over, drop="block"), what="sinking_block without the block")}
    for name, extra in (("hencky", ()), ("rigid_body", (sb.RIGID,))):
        runs[name] = _run(_spec(sb.CASE, [*over, *extra]), what=f"sinking_block ({name})")
    tank = runs["tank"]
    rows = []
    for name in ("hencky", "rigid_body"):
        r = runs[name]
        ratio = (r["steps"] / r["simulated_time"]) / (tank["steps"] / tank["simulated_time"])
        rows.append({"variant": name, "t_end": t_end, "steps": r["steps"], "tank_steps": tank["steps"],
                     "steps_per_s": r["steps"] / r["simulated_time"],
                     "tank_steps_per_s": tank["steps"] / tank["simulated_time"], "ratio": ratio,
                     "wall_s": r["wall_s"], "tank_wall_s": tank["wall_s"],
                     "pressure_solve_s": r["pressure_solve_s"], "tank_pressure_solve_s": tank["pressure_solve_s"],
                     "solid_particles": r["solid_particles"], "tank_solid_particles": tank["solid_particles"],
                     "water_particles": r["water_particles"], "tank_water_particles": tank["water_particles"],
                     "steps_by_second": r["steps_by_second"], "tank_steps_by_second": tank["steps_by_second"],
                     "gate": GATE_TANK, "pass": ratio <= GATE_TANK})
        say(f"  sinking_block {name} (t_end {t_end:g} s, h 0.05): {r['steps']} steps against {tank['steps']} "
            f"without the block (x{ratio:.2f}; per second {r['steps_by_second']} / {tank['steps_by_second']}; "
            f"wall {r['wall_s']:.1f} / {tank['wall_s']:.1f} s)  "
            f"gate <= {GATE_TANK}: {'PASS' if ratio <= GATE_TANK else 'FAIL'}")
    return {"rows": rows, "runs": runs}


def obstacle_rows(base: str | None, say, repeats: int = BASE_REPEATS) -> dict:
    """Item 2: elastic_obstacle, incompressible water, 4 mm, one thread; against the base if given."""
    over = [f"grid.cell={EO_CELL}", "contact.enabled=false"]
    chk = "harness.checks.elastic_obstacle.INCOMPRESSIBLE"
    case = Path("cases") / "elastic_obstacle.toml"      # relative: each checkout's own file
    if base is None:
        r = _run(_spec(case, over, chk), what="elastic_obstacle incompressible (new)")
        say(f"  elastic_obstacle incompressible h {EO_CELL:g}: {r['steps']} steps, {r['wall_s']:.1f} s wall "
            "(no --base: no gate)")
        return {"cell": EO_CELL, "new": [r], "base": None}
    d = bench.prepare_base(base)
    new, old = [], []
    for i in range(repeats):
        for which in (("base", "new") if i % 2 == 0 else ("new", "base")):
            repo = d if which == "base" else bench.REPO
            r = _run(_spec(case, over, chk), repo, f"elastic_obstacle incompressible ({which})")
            (old if which == "base" else new).append(r)
            say(f"    elastic_obstacle {which}: {r['steps']} steps, {r['wall_s']:.1f} s")
    speedup = statistics.median(r["wall_s"] for r in old) / statistics.median(r["wall_s"] for r in new)
    row = {"cell": EO_CELL, "base_commit": d.name, "repeats": repeats, "new": new, "base": old,
           "speedup_base_over_new": speedup, "gate": GATE_BASE_SPEEDUP, "pass": speedup >= GATE_BASE_SPEEDUP}
    say(f"  elastic_obstacle incompressible h {EO_CELL:g} base {d.name[:12]}: wall base/new x{speedup:.2f} "
        f"(steps {old[0]['steps']} -> {new[0]['steps']}, median of {repeats} interleaved)  gate >= "
        f"{GATE_BASE_SPEEDUP}: {'PASS' if row['pass'] else 'FAIL'}")
    return row


def run(quick: bool, base: str | None, say) -> tuple[dict, dict]:
    """The bench.json 'fsi' entry and its gates."""
    tank = tank_rows(say)
    obstacle = None if quick else obstacle_rows(base, say)
    gates = {f"sinking_block_{r['variant']}_steps_over_tank": {"value": r["ratio"], "max": GATE_TANK,
                                                               "pass": r["pass"]} for r in tank["rows"]}
    if obstacle and obstacle["base"] is not None:
        gates["elastic_obstacle_incompressible_speedup_over_base"] = {
            "value": obstacle["speedup_base_over_new"], "min": GATE_BASE_SPEEDUP, "pass": obstacle["pass"]}
    return {"sinking_block_tank": tank, "elastic_obstacle_incompressible": obstacle}, gates


if __name__ == "__main__":
    import argparse

    a = argparse.ArgumentParser(prog="python -m tools.bench_fsi", description="the FSI rows of make bench alone")
    a.add_argument("--quick", action="store_true")
    a.add_argument("--base", metavar="SHA")
    args = a.parse_args()
    data, gates = run(args.quick, args.base, print)
    bench.OUT.mkdir(parents=True, exist_ok=True)
    (bench.OUT / "fsi.json").write_text(json.dumps({"fsi": data, "gates": gates}, indent=2) + "\n")
    print(f"wrote {bench.OUT / 'fsi.json'}")
