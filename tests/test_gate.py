"""The regression gate: doctored metrics must fail, naming the check and the metric."""

import copy
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from harness import gate, report
from harness.checks.base import CheckResult

REPO = Path(__file__).resolve().parent.parent
GOLD = gate.load_gold()


def metrics_from_gold(tier="quick"):
    """A metrics.json document whose values equal gold exactly."""
    checks = {}
    for check, entries in GOLD["tiers"][tier].items():
        checks[check] = {"passed": True, "requirement": "", "gates": [],
                         "metrics": {m: (math.nan if e["value"] is None else e["value"]) for m, e in entries.items()}}
    return {"schema": 1, "passed": True, "quick": tier == "quick", "provenance": {}, "checks": checks}


def status(rows, check, metric):
    return next(r for r in rows if r["check"] == check and r["metric"] == metric)


def test_gold_exists_with_tolerances_and_reasons():
    assert set(GOLD["tiers"]) == {"full", "quick"}
    for tier in GOLD["tiers"].values():
        for check, entries in tier.items():
            assert entries, check
            for metric, e in entries.items():
                assert e["reason"] and e["better"] in ("lower", "higher", "either"), metric
                assert e["abs_tol"] >= 0 and e["rel_tol"] >= 0


def test_gold_values_pass():
    rows = gate.compare(metrics_from_gold(), GOLD, "quick")
    assert rows and all(r["status"] == "ok" for r in rows)


@pytest.mark.parametrize("check, metric, factor, expect", [
    ("hydrostatic_locking", "l2_rel_error_projection", 1000.0, "regressed"),  # projection dropped
    ("hydrostatic_locking", "l2_ratio_no_projection_to_projection", 0.001, "regressed"),
    ("convergence", "error_l2_finest_axis_aligned_cpdi", 3.0, "regressed"),
    ("convergence", "error_l2_finest_axis_aligned_cpdi", 0.5, "improved"),
    ("water_column", "energy_excess", 1.0, "ok"),
])
def test_doctored_metric(check, metric, factor, expect):
    m = metrics_from_gold()
    m["checks"][check]["metrics"][metric] *= factor
    if metric == "energy_excess":  # near zero: shift by less than its absolute floor
        m["checks"][check]["metrics"][metric] += 5e-7
    row = status(gate.compare(m, GOLD, "quick"), check, metric)
    assert row["status"] == expect
    if expect != "ok":
        line = gate.summary_lines([row])[0]
        assert f"{check}.{metric}" in line
        assert ("REGRESSION" in line) == (expect == "regressed")


def test_order_drop_and_missing_metric_and_nan_are_regressions():
    m = metrics_from_gold()
    m["checks"]["convergence"]["metrics"]["order_l2_axis_aligned_cpdi"] -= 0.5
    del m["checks"]["hydrostatic_locking"]["metrics"]["oscillation_index_projection"]
    m["checks"]["water_column"]["metrics"]["front_Z_final"] = math.nan
    rows = gate.compare(m, GOLD, "quick")
    assert status(rows, "convergence", "order_l2_axis_aligned_cpdi")["status"] == "regressed"
    assert status(rows, "hydrostatic_locking", "oscillation_index_projection")["status"] == "regressed"
    assert status(rows, "water_column", "front_Z_final")["status"] == "regressed"


def test_regression_fails_the_report():
    rows = [{"check": "c", "metric": "x", "value": 2.0, "gold": 1.0, "abs_tol": 0.0, "rel_tol": 0.05,
             "status": "regressed", "reason": "test"}]
    res = [CheckResult(name="c", requirement="r", metrics={"x": 2.0})]
    assert report.build_metrics(res, {}, True)["passed"] is True
    assert report.build_metrics(res, {}, True, gate_summary=rows)["passed"] is False


def test_gate_command_fails_on_a_doctored_metrics_file(tmp_path):
    m = metrics_from_gold()
    good = tmp_path / "good.json"
    good.write_text(json.dumps(m, allow_nan=True))
    bad_m = copy.deepcopy(m)
    bad_m["checks"]["hydrostatic_locking"]["metrics"]["l2_rel_error_projection"] = 6.25e-3  # projection lost
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(bad_m, allow_nan=True))
    ok = subprocess.run([sys.executable, "-m", "harness", "gate", str(good)], cwd=REPO, capture_output=True, text=True)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    p = subprocess.run([sys.executable, "-m", "harness", "gate", str(bad)], cwd=REPO, capture_output=True, text=True)
    assert p.returncode == 1
    assert "REGRESSION: hydrostatic_locking.l2_rel_error_projection" in p.stdout
