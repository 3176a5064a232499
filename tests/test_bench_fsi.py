"""The bench's FSI rows (tools.bench_fsi, issue 37): sinking_block is compared with the same tank
without the block (bench_fsi.without: the water, grid and solver of the case, no solid), and the
gates read the runs' steps and walls as documented. The runs themselves are stubbed here
(bench_fsi._run); only the case building and seeding are real."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from harness import cases, seeding
from harness.checks import sinking_block as sb
from tools import bench, bench_fsi


def test_the_tank_without_the_block_has_the_same_water_and_no_solid():
    full = cases.load(sb.CASE)
    tank = bench_fsi.without(full, "block")
    assert [b["name"] for b in tank["bodies"]] == ["water"]
    assert [m["model"] for m in tank["materials"]] == ["newtonian_fluid"]
    assert all(p.get("material") != "block" for p in tank["probes"].values())
    for key in ("grid", "solver", "contact"):
        assert tank[key] == full[key]
    p, q = seeding.seed(full), seeding.seed(tank)
    water = p.mat == [m["name"] for m in full["materials"]].index("water")
    assert q.n == water.sum() < p.n
    assert np.array_equal(q.mat, np.zeros(q.n, dtype=q.mat.dtype))
    for a in ("x", "v", "mass", "vol", "r"):
        assert np.array_equal(getattr(q, a), getattr(p, a)[water]), a
    assert len(full["bodies"]) == 2   # the case itself is untouched


def test_the_rigid_variants_tank_is_the_same_tank():
    a = bench_fsi.without(cases.load(sb.CASE), "block")
    b = bench_fsi.without(cases.load(sb.CASE, [sb.RIGID]), "block")
    assert a.data == b.data


def test_an_unknown_body_is_refused():
    with pytest.raises(ValueError, match="no body named 'plate'"):
        bench_fsi.without(cases.load(sb.CASE), "plate")


def _fake_runs(steps: dict, walls: dict | None = None, log: list | None = None):
    """A stand-in for bench_fsi._run: steps per run kind, walls popped in order, kinds logged."""
    walls = {k: list(v) for k, v in (walls or {}).items()}

    def run(spec, repo=bench.REPO, what=""):
        s = json.loads(spec)
        if "sinking" in s["case"]:
            key = "tank" if s["drop"] else "rigid" if sb.RIGID in s["overrides"] else "hencky"
        else:
            assert s["check_overrides"].endswith("elastic_obstacle.INCOMPRESSIBLE")
            assert "grid.cell=0.004" in s["overrides"] and "contact.enabled=false" in s["overrides"]
            key = "base" if repo != bench.REPO else "new"
        if log is not None:
            log.append(key)
        return {"steps": steps[key], "simulated_time": 5.0, "wall_s": walls[key].pop(0) if key in walls else 1.0,
                "pressure_solve_s": 0.1, "solid_particles": 0 if key == "tank" else 9, "water_particles": 90,
                "steps_by_second": [steps[key] // 5] * 5}
    return run


def test_the_tank_gate_is_steps_over_the_tanks_steps(monkeypatch):
    monkeypatch.setattr(bench_fsi, "_run", _fake_runs({"tank": 100, "hencky": 200, "rigid": 201}))
    data, gates = bench_fsi.run(True, None, lambda *_: None)
    assert data["elastic_obstacle_incompressible"] is None   # the quick path: item 1 only
    g = gates["sinking_block_hencky_steps_over_tank"]
    assert g["value"] == pytest.approx(2.0) and g["max"] == 2.0 and g["pass"]
    g = gates["sinking_block_rigid_body_steps_over_tank"]
    assert g["value"] == pytest.approx(2.01) and not g["pass"]
    assert set(gates) == {"sinking_block_hencky_steps_over_tank", "sinking_block_rigid_body_steps_over_tank"}


def test_the_base_runs_interleave_and_gate_the_median_wall_ratio(monkeypatch, tmp_path):
    log = []
    walls = {"base": [50.0, 60.0, 55.0], "new": [10.0, 12.0, 11.0]}
    monkeypatch.setattr(bench_fsi, "_run", _fake_runs({"base": 8000, "new": 1500}, walls, log))
    monkeypatch.setattr(bench, "prepare_base", lambda sha: Path(tmp_path) / "abc123")
    row = bench_fsi.obstacle_rows("abc123", lambda *_: None, repeats=3)
    assert log == ["base", "new", "new", "base", "base", "new"]
    assert row["speedup_base_over_new"] == pytest.approx(55.0 / 11.0) and row["pass"]
    assert row["base_commit"] == "abc123" and len(row["base"]) == len(row["new"]) == 3
    monkeypatch.setattr(bench_fsi, "_run", _fake_runs({"tank": 100, "hencky": 150, "rigid": 150, "new": 1500}))
    data, gates = bench_fsi.run(False, None, lambda *_: None)
    row = data["elastic_obstacle_incompressible"]
    assert row["base"] is None and row["new"][0]["steps"] == 1500   # no base: reported, not gated
    assert "elastic_obstacle_incompressible_speedup_over_base" not in gates
