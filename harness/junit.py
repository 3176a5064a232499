"""JUnit XML of a verify run, for CI systems (GitLab, GitHub Actions, Jenkins).

Written beside metrics.json as ``junit.xml`` and built from the same document, so the counts
agree by construction: every check is a ``<testsuite>`` and every gate of it a
``<testcase>``. A missed gate is a ``<failure>`` whose message names the metric, its value,
the bound and what the bound refers to; a gate marked as a known limitation that is missed
(XFAIL) is ``<skipped>`` with the limitation as its message; a check that could not run is
one ``<error>`` testcase. The comparison with the gold baselines is one more suite,
``regression_vs_gold``, a testcase per compared metric (a regression is a failure).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

GOLD_SUITE = "regression_vs_gold"
_OPS = {"max": "<=", "min": ">=", "gold": "~"}


def _num(v: Any) -> str:
    return "nan" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{float(v):.6g}"


def _gate_case(check: str, requirement: str, g: dict) -> ET.Element:
    case = ET.Element("testcase", classname=f"verify.{check}", name=g["metric"], time="0")
    ref = g.get("note") or requirement
    text = f"{g['metric']} = {_num(g['value'])}, bound {_OPS.get(g['kind'], g['kind'])} {_num(g['bound'])}"
    if g.get("known_limitation"):
        if not g["passed"]:
            ET.SubElement(case, "skipped", message=f"XFAIL, known limitation: {g['known_limitation']}").text = text
        return case
    if not g["passed"]:
        ET.SubElement(case, "failure", message=f"{text} ({ref})", type="gate").text = f"{text}\nreference: {ref}"
    return case


def _suite(name: str, cases: list[ET.Element], time_s: float = 0.0) -> ET.Element:
    s = ET.Element("testsuite", name=name, tests=str(len(cases)),
                   failures=str(sum(c.find("failure") is not None for c in cases)),
                   errors=str(sum(c.find("error") is not None for c in cases)),
                   skipped=str(sum(c.find("skipped") is not None for c in cases)), time=f"{time_s:.3f}")
    s.extend(cases)
    return s


def build(metrics: dict, gate_summary: list[dict] | None) -> ET.ElementTree:
    """The JUnit document of a metrics.json dict and the gold comparison rows."""
    suites = []
    for name, c in metrics.get("checks", {}).items():
        if c.get("error"):
            case = ET.Element("testcase", classname=f"verify.{name}", name="run", time="0")
            ET.SubElement(case, "error", message=str(c["error"]).splitlines()[0][:500], type="run").text = c["error"]
            cases = [case]
        else:
            cases = [_gate_case(name, c.get("requirement", ""), g) for g in c.get("gates", [])]
        suites.append(_suite(name, cases, float(c.get("wall_s") or 0.0)))
    if gate_summary:
        cases = []
        for row in gate_summary:
            case = ET.Element("testcase", classname=f"{GOLD_SUITE}.{row['check']}", name=row["metric"], time="0")
            if row.get("status") == "regressed":
                ET.SubElement(case, "failure", type="regression",
                              message=f"{row['check']}.{row['metric']} = {_num(row['value'])} against gold "
                                      f"{_num(row['gold'])} (tolerance abs {row['abs_tol']}, rel {row['rel_tol']}): "
                                      f"{row.get('reason', '')}")
            cases.append(case)
        suites.append(_suite(GOLD_SUITE, cases))
    root = ET.Element("testsuites", name="cpdi-verify " + ("quick" if metrics.get("quick") else "full"),
                      tests=str(sum(int(s.get("tests")) for s in suites)),
                      failures=str(sum(int(s.get("failures")) for s in suites)),
                      errors=str(sum(int(s.get("errors")) for s in suites)),
                      skipped=str(sum(int(s.get("skipped")) for s in suites)))
    root.extend(suites)
    ET.indent(root)
    return ET.ElementTree(root)


def write(path: Path, metrics: dict, gate_summary: list[dict] | None) -> None:
    build(metrics, gate_summary).write(path, encoding="utf-8", xml_declaration=True)
