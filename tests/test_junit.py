"""harness.junit on hand-made metrics.json documents (test_report.py checks junit.xml against
a written report): testcase outcomes, messages, per-suite and total counts, the gold suite."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import pytest

from harness import junit


def gate(metric, value, bound, kind="max", passed=True, note="", known_limitation=""):
    return {"metric": metric, "value": value, "bound": bound, "kind": kind, "passed": passed, "note": note,
            "known_limitation": known_limitation}


def doc(checks, quick=True):
    return {"quick": quick, "checks": checks}


def suites(tree):
    return {s.get("name"): s for s in tree.getroot().iter("testsuite")}


@pytest.mark.parametrize("v, text", [(None, "nan"), (math.nan, "nan"), (0.25, "0.25"), (1234567.0, "1.23457e+06"),
                                     (3, "3")])
def test_number_format(v, text):
    assert junit._num(v) == text


@pytest.mark.parametrize("kind, op", [("max", "<="), ("min", ">="), ("gold", "~"), ("odd", "odd")])
def test_failed_gate_is_a_failure_naming_metric_value_bound_and_reference(kind, op):
    case = junit._gate_case("chk", "the requirement", gate("err", 0.5, 0.25, kind, passed=False))
    assert (case.get("classname"), case.get("name")) == ("verify.chk", "err")
    fail = case.find("failure")
    assert fail.get("type") == "gate"
    assert fail.get("message") == f"err = 0.5, bound {op} 0.25 (the requirement)"
    assert fail.text == f"err = 0.5, bound {op} 0.25\nreference: the requirement"
    assert case.find("skipped") is None


def test_gate_note_is_the_reference_when_given():
    case = junit._gate_case("chk", "the requirement", gate("err", 0.5, 0.25, passed=False, note="Ritter 1892"))
    assert case.find("failure").get("message").endswith("(Ritter 1892)")


def test_passed_gate_and_met_known_limitation_have_no_outcome_element():
    assert len(junit._gate_case("chk", "r", gate("a", 0.1, 0.25))) == 0
    assert len(junit._gate_case("chk", "r", gate("a", 0.1, 0.25, known_limitation="2D"))) == 0


def test_missed_known_limitation_is_skipped_not_failed():
    case = junit._gate_case("chk", "r", gate("a", 0.5, 0.25, passed=False, known_limitation="2D model"))
    assert case.find("failure") is None
    skip = case.find("skipped")
    assert "XFAIL" in skip.get("message") and "2D model" in skip.get("message")
    assert skip.text == "a = 0.5, bound <= 0.25"


def test_counts_per_suite_and_in_total():
    metrics = doc({
        "one": {"requirement": "r", "wall_s": 2.5, "gates": [
            gate("a", 0.1, 1.0), gate("b", 2.0, 1.0, passed=False), gate("c", 2.0, 1.0, passed=False),
            gate("d", 2.0, 1.0, passed=False, known_limitation="k")]},
        "two": {"requirement": "r", "wall_s": None, "gates": [gate("e", 0.1, 1.0)]},
        "broken": {"requirement": "r", "error": "CpdiError: NaN at step 3\nTraceback ...", "gates": [gate("x", 1, 2)]},
    })
    tree = junit.build(metrics, None)
    root = tree.getroot()
    assert root.get("name") == "cpdi-verify quick"
    s = suites(tree)
    assert set(s) == {"one", "two", "broken"}
    one = s["one"]
    assert (one.get("tests"), one.get("failures"), one.get("skipped"), one.get("errors")) == ("4", "2", "1", "0")
    assert one.get("time") == "2.500" and s["two"].get("time") == "0.000"
    assert [c.get("name") for c in one.findall("testcase")] == ["a", "b", "c", "d"]
    br = s["broken"]
    assert (br.get("tests"), br.get("errors"), br.get("failures")) == ("1", "1", "0")
    err = br.find("testcase/error")
    assert br.find("testcase").get("name") == "run"
    assert err.get("message") == "CpdiError: NaN at step 3" and err.text.endswith("Traceback ...")
    assert (root.get("tests"), root.get("failures"), root.get("skipped"), root.get("errors")) == ("6", "2", "1", "1")
    assert junit.build(doc({}, quick=False), None).getroot().get("name") == "cpdi-verify full"


def test_error_message_is_cut_to_500_characters():
    tree = junit.build(doc({"c": {"error": "x" * 800}}), None)
    err = tree.getroot().find("testsuite/testcase/error")
    assert len(err.get("message")) == 500 and len(err.text) == 800


def row(metric, status, value=2.0, g=1.0):
    return {"check": "chk", "metric": metric, "value": value, "gold": g, "abs_tol": 0.0, "rel_tol": 0.05,
            "status": status, "reason": "errors: 5 %"}


def test_gold_suite_fails_only_regressions():
    rows = [row("a", "regressed"), row("b", "ok", 1.0), row("c", "improved", 0.5), row("d", "regressed", math.nan)]
    tree = junit.build(doc({"chk": {"gates": [gate("a", 0.1, 1.0)]}}), rows)
    gold = suites(tree)[junit.GOLD_SUITE]
    assert (gold.get("tests"), gold.get("failures"), gold.get("errors"), gold.get("skipped")) == ("4", "2", "0", "0")
    cases = {c.get("name"): c for c in gold.findall("testcase")}
    assert all(c.get("classname") == "regression_vs_gold.chk" for c in cases.values())
    assert cases["b"].find("failure") is None and cases["c"].find("failure") is None
    fail = cases["a"].find("failure")
    assert fail.get("type") == "regression"
    msg = fail.get("message")
    assert msg.startswith("chk.a = 2 against gold 1") and "abs 0.0" in msg and "rel 0.05" in msg
    assert msg.endswith("errors: 5 %")
    assert cases["d"].find("failure").get("message").startswith("chk.d = nan")
    root = tree.getroot()
    assert (root.get("tests"), root.get("failures")) == ("5", "2")


@pytest.mark.parametrize("rows", [None, []])
def test_no_gold_suite_without_rows(rows):
    assert junit.GOLD_SUITE not in suites(junit.build(doc({"c": {"gates": []}}), rows))


def test_write_is_utf8_xml_that_parses_back(tmp_path):
    path = tmp_path / "junit.xml"
    junit.write(path, doc({"ü": {"requirement": "Lobovský 2014", "gates": [gate("a", 2.0, 1.0, passed=False)]}}), None)
    raw = path.read_bytes()
    assert raw.startswith(b"<?xml version='1.0' encoding='utf-8'?>")
    root = ET.parse(path).getroot()
    assert root.find("testsuite").get("name") == "ü"
    assert "Lobovský 2014" in root.find("testsuite/testcase/failure").get("message")
