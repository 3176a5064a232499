"""harness.gate on hand-made metrics and gold (test_gate.py covers the repository's gold): the
tolerance table, the comparison at and around the tolerance for each direction, missing and new
metrics, NaN, the gold file's round trip and the summary lines."""

from __future__ import annotations

import json
import math

import pytest

from harness import gate

# --------------------------------------------------------------------------- tolerance_for


@pytest.mark.parametrize("metric, abs_tol, rel_tol, better", [
    ("particle_updates_per_s", math.inf, math.inf, "either"),
    ("wall_s", math.inf, math.inf, "either"),
    ("order_l2_axis_aligned", 0.1, 0.0, "higher"),
    ("l2_ratio_no_projection_to_projection", 0.0, 0.10, "higher"),  # "ratio" before the error prefixes
    ("error_l2_finest", 1e-6, 0.05, "lower"),
    ("l2_rel_error_projection", 1e-6, 0.05, "lower"),
    ("max_abs_pressure", 1e-6, 0.05, "lower"),
    ("oscillation_index_projection", 1e-6, 0.05, "lower"),
    ("gci_fine", 1e-6, 0.05, "lower"),
    ("dambreak_pressure_noise", 1e-6, 0.05, "lower"),
    ("energy_excess", 1e-6, 0.05, "lower"),
    ("ritter_margin_min", 0.05, 0.0, "higher"),
    ("completed", 0.0, 0.0, "either"),
    ("particles", 0.0, 0.0, "either"),
    ("particles_moved", 0.0, 0.05, "either"),  # anchored: not the exact count
    ("front_Z_final", 0.0, 0.05, "either"),
    ("reorder_count", 0.0, 0.05, "either"),  # "order_" only at the start
    ("final_error_l2", 0.0, 0.05, "either"),  # "error_" only at the start
])
def test_tolerance_table(metric, abs_tol, rel_tol, better):
    t = gate.tolerance_for(metric)
    assert (t["abs_tol"], t["rel_tol"], t["better"]) == (abs_tol, rel_tol, better)
    assert isinstance(t["reason"], str) and len(t["reason"]) > 10


# --------------------------------------------------------------------------- compare_metric


def gold(value, abs_tol=0.0, rel_tol=0.25, better="either", reason="because"):
    return {"value": value, "abs_tol": abs_tol, "rel_tol": rel_tol, "better": better, "reason": reason}


# gold 8 with rel 0.25 and abs 0.5: tolerance 2 (binary-exact, so "at" is exactly at)
@pytest.mark.parametrize("better, value, expect", [
    ("either", 8.0, "ok"), ("either", 10.0, "ok"), ("either", 6.0, "ok"),
    ("either", 10.0625, "regressed"), ("either", 5.9375, "regressed"),
    ("lower", 10.0, "ok"), ("lower", 10.0625, "regressed"), ("lower", 5.9375, "improved"), ("lower", 6.0, "ok"),
    ("higher", 6.0, "ok"), ("higher", 5.9375, "regressed"), ("higher", 10.0625, "improved"), ("higher", 10.0, "ok"),
])
def test_compare_metric_at_and_beyond_the_relative_tolerance(better, value, expect):
    row = gate.compare_metric("c", "m", value, gold(8.0, abs_tol=0.5, better=better))
    assert row["status"] == expect
    assert (row["check"], row["metric"], row["value"], row["gold"]) == ("c", "m", value, 8.0)
    assert (row["abs_tol"], row["rel_tol"]) == (0.5, 0.25)


@pytest.mark.parametrize("value, expect", [(-6.0, "ok"), (-10.0, "ok"), (-5.9375, "improved"), (-10.0625, "regressed")])
def test_relative_tolerance_of_a_negative_gold_uses_its_magnitude(value, expect):
    assert gate.compare_metric("c", "m", value, gold(-8.0, better="higher"))["status"] == expect


@pytest.mark.parametrize("better, value, expect", [
    ("lower", 1.5, "ok"), ("lower", 1.5078125, "regressed"), ("lower", 0.4921875, "improved"),
    ("higher", 0.5, "ok"), ("higher", 0.4921875, "regressed"), ("higher", 1.5078125, "improved"),
])
def test_absolute_tolerance_when_it_is_the_larger(better, value, expect):
    # gold 1, abs 0.5, rel 0.25: tolerance 0.5
    assert gate.compare_metric("c", "m", value, gold(1.0, abs_tol=0.5, better=better))["status"] == expect


def test_zero_tolerance_is_exact_and_near_zero_gold_keeps_its_absolute_floor():
    exact = gold(1000.0, rel_tol=0.0)
    assert gate.compare_metric("c", "particles", 1000, exact)["status"] == "ok"
    assert gate.compare_metric("c", "particles", 1001, exact)["status"] == "regressed"
    floor = gold(0.0, abs_tol=1e-6, rel_tol=0.05, better="lower")
    assert gate.compare_metric("c", "e", 5e-7, floor)["status"] == "ok"
    assert gate.compare_metric("c", "e", 2e-6, floor)["status"] == "regressed"


def test_missing_direction_counts_either_way_and_reason_is_carried():
    g = gold(8.0)
    del g["better"]
    assert gate.compare_metric("c", "m", 5.0, g)["status"] == "regressed"
    assert gate.compare_metric("c", "m", 11.0, g)["status"] == "regressed"
    assert gate.compare_metric("c", "m", 8.5, g)["reason"] == "because"
    del g["reason"]
    assert gate.compare_metric("c", "m", 8.5, g)["reason"] == ""


def test_nan_and_none():
    both = gate.compare_metric("c", "m", None, gold(None))
    assert both["status"] == "ok" and math.isnan(both["value"]) and math.isnan(both["gold"])
    assert gate.compare_metric("c", "m", math.nan, gold(None))["status"] == "ok"
    lost = gate.compare_metric("c", "m", None, gold(1.0, better="lower"))
    assert lost["status"] == "regressed" and "NaN" in lost["reason"]
    assert gate.compare_metric("c", "m", math.nan, gold(1.0, better="higher"))["status"] == "regressed"
    new = gate.compare_metric("c", "m", 3.0, gold(None, better="lower"))
    assert new["status"] == "improved" and "regenerate gold" in new["reason"]


# --------------------------------------------------------------------------- compare


def run(checks):
    return {"schema": 1, "quick": True, "checks": {c: {"metrics": m} for c, m in checks.items()}}


GOLD = {"schema": 1, "tiers": {
    "quick": {"a": {"x": gold(8.0), "y": gold(1.0, better="lower")}, "b": {"z": gold(2.0)}},
    "full": {"a": {"x": gold(100.0)}},
}}


def test_compare_rows_per_gold_metric_of_the_checks_run():
    rows = gate.compare(run({"a": {"x": 9.0, "y": 0.5, "new_metric": 7.0}}), GOLD, "quick")
    got = {(r["check"], r["metric"]): r["status"] for r in rows}
    # b was not run: no rows; a metric the run has and gold has not: no row
    assert got == {("a", "x"): "ok", ("a", "y"): "improved"}


def test_compare_uses_the_tier_asked_for():
    assert [r["status"] for r in gate.compare(run({"a": {"x": 9.0}}), GOLD, "full")] == ["regressed"]
    assert gate.compare(run({"a": {"x": 9.0}}), GOLD, "nightly") == []
    assert gate.compare(run({"a": {"x": 9.0}}), {}, "quick") == []


def test_a_metric_missing_from_the_run_is_a_regression():
    rows = gate.compare(run({"a": {"x": 8.0}, "b": {}}), GOLD, "quick")
    by = {(r["check"], r["metric"]): r for r in rows}
    assert by[("a", "x")]["status"] == "ok"
    for key, g in ((("a", "y"), 1.0), (("b", "z"), 2.0)):
        r = by[key]
        assert r["status"] == "regressed" and "missing" in r["reason"]
        assert math.isnan(r["value"]) and r["gold"] == g
        assert (r["abs_tol"], r["rel_tol"]) == (0.0, 0.25)
    # a check that ran but has no metrics key at all
    rows = gate.compare({"checks": {"b": {}}}, GOLD, "quick")
    assert [(r["metric"], r["status"]) for r in rows] == [("z", "regressed")]


# --------------------------------------------------------------------------- gold file


def metrics_doc():
    return run({"hydro": {"error_l2": 0.002, "order_l2": 1.9, "wall_s": 12.0, "front": math.nan, "particles": 400},
                "empty": {}})


def test_gold_entries_carry_value_and_tolerance_and_skip_timing():
    e = gate.gold_entries(metrics_doc())
    assert set(e) == {"hydro", "empty"} and e["empty"] == {}
    assert set(e["hydro"]) == {"error_l2", "order_l2", "front", "particles"}  # wall_s is not gated
    assert e["hydro"]["error_l2"] == {"value": 0.002, **gate.tolerance_for("error_l2")}
    assert e["hydro"]["front"]["value"] is None
    assert e["hydro"]["particles"]["value"] == 400.0


def test_write_gold_then_load_gold_round_trip(tmp_path):
    path = tmp_path / "new" / "dir" / "metrics.json"
    assert gate.load_gold(path) == {}
    gate.write_gold({"quick": metrics_doc()}, {"commit": "abc"}, path)
    g = gate.load_gold(path)
    assert g["tiers"]["quick"] == gate.gold_entries(metrics_doc())
    assert g["provenance"]["quick"] == {"commit": "abc"}
    assert "regen-gold" in g["note"]
    assert json.loads(path.read_text()) == g  # strict JSON: the NaN went in as null
    # the run it was made from passes against it, NaN included
    assert {r["status"] for r in gate.compare(metrics_doc(), g, "quick")} == {"ok"}
    # writing another tier keeps this one; rewriting this one replaces it
    gate.write_gold({"full": run({"other": {"error_x": 1.0}})}, {"commit": "def"}, path)
    g = gate.load_gold(path)
    assert set(g["tiers"]) == {"quick", "full"} and g["tiers"]["quick"] == gate.gold_entries(metrics_doc())
    assert g["provenance"] == {"quick": {"commit": "abc"}, "full": {"commit": "def"}}
    gate.write_gold({"quick": run({"hydro": {"error_l2": 0.003}})}, {"commit": "ghi"}, path)
    g = gate.load_gold(path)
    assert g["tiers"]["quick"] == {"hydro": {"error_l2": {"value": 0.003, **gate.tolerance_for("error_l2")}}}
    assert set(g["tiers"]) == {"quick", "full"} and g["provenance"]["quick"] == {"commit": "ghi"}


# --------------------------------------------------------------------------- summary_lines


def row(status, value=10.5, g=-8.0, abs_tol=0.5, rel_tol=0.25, reason="why"):
    return {"check": "c", "metric": "m", "value": value, "gold": g, "abs_tol": abs_tol, "rel_tol": rel_tol,
            "status": status, "reason": reason}


def test_summary_lines_only_for_rows_not_ok():
    lines = gate.summary_lines([row("ok"), row("regressed"), row("ok"), row("improved", value=-5.0)])
    assert len(lines) == 2
    assert lines[0].startswith("REGRESSION: c.m = 10.5 vs gold -8 ")
    assert "(tolerance 2)" in lines[0] and lines[0].endswith("why")
    assert lines[1].startswith("improved: regenerate gold: c.m = -5 vs gold -8 ")
    assert "REGRESSION" not in lines[1]
    assert "(tolerance 0.75)" in gate.summary_lines([row("regressed", g=3.0, abs_tol=0.75, rel_tol=0.1)])[0]
    assert "(tolerance nan)" in gate.summary_lines([row("improved", g=math.nan)])[0]
    assert gate.summary_lines([row("ok")]) == []
