"""harness.checks.base: a gate's bound at equality, the verdict, and the dict round trip that
results.json and the re-render rely on (test_report.py covers known limitations in the report)."""

from __future__ import annotations

import numpy as np
import pytest

from harness.checks.base import CheckResult, Gate


@pytest.mark.parametrize("value, passed", [(1.5, True), (1.0, True), (2.0, False)])
def test_at_most_includes_the_bound(value, passed):
    g = Gate.at_most("err", value, 1.5, "ref note", "why")
    assert (g.metric, g.value, g.bound, g.kind, g.passed) == ("err", value, 1.5, "max", passed)
    assert (g.note, g.known_limitation) == ("ref note", "why")


@pytest.mark.parametrize("value, passed", [(1.5, True), (2.0, True), (1.0, False)])
def test_at_least_includes_the_bound(value, passed):
    g = Gate.at_least("order", value, 1.5, "ref note", "why")
    assert (g.metric, g.value, g.bound, g.kind, g.passed) == ("order", value, 1.5, "min", passed)
    assert (g.note, g.known_limitation) == ("ref note", "why")


def test_gate_fields_are_plain_python_types():
    """numpy scalars would not serialise to JSON: the constructors convert them."""
    for g in (Gate.at_most("a", np.float32(0.5), np.int64(1)), Gate.at_least("b", np.float64(2.0), np.int32(1))):
        assert type(g.value) is float and type(g.bound) is float and type(g.passed) is bool
        assert g.passed and g.note == "" and g.known_limitation == ""


def test_verdict_lists_the_failed_gates_and_counts_the_others():
    r = CheckResult("c", "req", gates=[Gate.at_most("a", 0.5, 1.0), Gate.at_least("b", 0.25, 1.0),
                                       Gate.at_most("k", 3.0, 1.0, known_limitation="2D")])
    assert not r.passed
    assert r.verdict.startswith("FAILED: b=0.25 (min 1)")
    assert "a=" not in r.verdict.split(";")[0]
    assert "XFAIL" in r.verdict and "k=3 (max 1)" in r.verdict
    r.gates[1] = Gate.at_least("b", 1.0, 1.0)
    assert r.passed and r.verdict.startswith("passed (2 gates")
    assert CheckResult("c", "req").verdict == "passed (0 gates)"


def test_an_error_fails_the_check_whatever_its_gates():
    r = CheckResult("c", "req", gates=[Gate.at_most("a", 0.5, 1.0)], error="CpdiError: NaN")
    assert not r.passed and r.verdict == "FAILED to run: CpdiError: NaN"


def full_result():
    return CheckResult(name="c", requirement="req", metrics={"a": 0.5, "n": 3.0},
                       gates=[Gate.at_most("a", 0.5, 1.0, "note a"), Gate.at_least("b", 0.2, 1.0, "", "2D")],
                       figures=["f.png"], tables=["| x |\n|---|\n| 1 |"], notes=["para"], error="boom",
                       wall_s=12.5)


def test_to_dict_adds_passed_and_verdict():
    d = full_result().to_dict()
    assert d["passed"] is False and d["verdict"] == "FAILED to run: boom"
    assert d["gates"][1] == {"metric": "b", "value": 0.2, "bound": 1.0, "kind": "min", "passed": False,
                             "note": "", "known_limitation": "2D"}
    assert (d["name"], d["requirement"], d["wall_s"], d["figures"]) == ("c", "req", 12.5, ["f.png"])


def test_from_dict_round_trip():
    r = full_result()
    assert CheckResult.from_dict(r.to_dict()) == r
    ok = CheckResult("d", "r2", gates=[Gate.at_most("a", 0.5, 1.0)])
    assert CheckResult.from_dict(ok.to_dict()) == ok


def test_from_dict_of_a_minimal_or_older_document():
    r = CheckResult.from_dict({"name": "x"})
    assert r == CheckResult("x", "")
    assert r.error is None and r.wall_s == 0.0
    # a gate written before known_limitation existed, with derived keys (outcome) beside it
    d = {"name": "x", "requirement": "q", "wall_s": "3", "gates": [
        {"metric": "a", "value": 2.0, "bound": 1.0, "kind": "max", "passed": False, "outcome": "FAIL"}]}
    r = CheckResult.from_dict(d)
    assert r.gates == [Gate("a", 2.0, 1.0, "max", False)] and r.wall_s == 3.0 and r.requirement == "q"
    assert not r.passed
