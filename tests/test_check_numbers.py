"""A check reads its problem from its case file (issue 39 item 2): no number of a check module may
equal a number its case file(s) hold, so that editing a case cannot silently put its check out of
step.

What the scan does not count (each is the check's own arithmetic, not a fact of the case):
- 0.5 and whole numbers below 10 (indices, halves, counts, the mean of three stresses);
- a power of ten that multiplies or divides (a unit: Pa -> kPa, s -> ms);
- a gate's bound (`Gate.at_most(metric, value, bound, ...)`: the check's requirement);
- plotting styles (lw, alpha, zorder, ...);
- a line that says why: `# not the case's: <reason>`.
"""

from __future__ import annotations

import ast
import math
import re
import tomllib

import pytest

from harness import paths
from harness.checks import registry

# the case files a check runs that its source does not name as CASES / "x.toml"
INDIRECT = {"dam_break_front": ("dam_break.toml",), "hydrostatic_locking": ("water_column.toml",)}
STYLE = {"lw", "linewidth", "linewidths", "alpha", "zorder", "s", "ms", "markersize", "fontsize", "vmin",
         "vmax", "width"}
MARK = "# not the case's:"


def case_files(check: str, src: str) -> list[str]:
    named = re.findall(r'(?:CASES / |registry\.requirement\()"([a-z_]+\.toml)"', src)
    return sorted(set(named) | set(INDIRECT.get(check, ())))


def case_numbers(files: list[str]) -> set[float]:
    out: set[float] = set()

    def walk(o):
        if isinstance(o, bool):
            return
        if isinstance(o, int | float):
            out.add(abs(float(o)))
        elif isinstance(o, dict):
            for v in o.values():
                walk(v)
        elif isinstance(o, list):
            for v in o:
                walk(v)

    for f in files:
        walk(tomllib.loads((paths.CASES / f).read_text()))
    return out


def _exempt_nodes(tree: ast.AST) -> set[int]:
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult | ast.Div):
            for side in (node.left, node.right):
                if isinstance(side, ast.Constant) and isinstance(side.value, int | float) and side.value > 0 \
                        and abs(math.log10(side.value) - round(math.log10(side.value))) < 1e-12:
                    skip.add(id(side))
        if isinstance(node, ast.Dict):   # style dicts: bbox={"alpha": 0.8, ...}
            for k, v in zip(node.keys, node.values, strict=True):
                if isinstance(k, ast.Constant) and k.value in STYLE:
                    skip |= {id(n) for n in ast.walk(v)}
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Attribute) and f.attr in ("at_most", "at_least") and len(node.args) >= 3:
                skip |= {id(n) for n in ast.walk(node.args[2])}
            for kw in node.keywords:
                if kw.arg in STYLE:
                    skip |= {id(n) for n in ast.walk(kw.value)}
    return skip


def retyped(check: str) -> list[str]:
    path = paths.SOURCE_ROOT / "harness" / "checks" / f"{check}.py"
    src = path.read_text()
    numbers = case_numbers(case_files(check, src))
    tree = ast.parse(src)
    lines = src.split("\n")
    skip = _exempt_nodes(tree)
    found = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Constant) and isinstance(node.value, int | float)) or isinstance(node.value, bool):
            continue
        v = abs(float(node.value))
        if v == 0.5 or (v.is_integer() and v < 10) or id(node) in skip:
            continue
        line = lines[node.lineno - 1]
        if MARK in line or (node.lineno >= 2 and lines[node.lineno - 2].strip().startswith(MARK)):
            continue
        if v in numbers:
            found.append(f"{path.name}:{node.lineno}: {node.value!r} is also in its case file: {line.strip()}")
    return found


@pytest.mark.parametrize("check", [r.name for r in registry.all_checks()])
def test_check_holds_no_number_of_its_case(check):
    found = retyped(check)
    assert not found, ("read these from the case file (or, if the equality is a coincidence, say why with "
                       f"'{MARK} <reason>' on the line):\n" + "\n".join(found))


def test_the_scan_finds_a_retyped_number(tmp_path, monkeypatch):
    """The scan itself: a density typed into a check is found; the same number as a unit is not."""
    fake = tmp_path / "harness" / "checks"
    fake.mkdir(parents=True)
    (fake / "probe.py").write_text('CASE = paths.CASES / "resting_tank.toml"\nRHO = 1000.0\nkpa = p / 1000.0\n')
    monkeypatch.setattr(paths, "SOURCE_ROOT", tmp_path)
    found = retyped("probe")
    assert len(found) == 1 and "RHO = 1000.0" in found[0]


@pytest.mark.parametrize("case", ["water_column.toml", "dam_break.toml"])
def test_hydrostatic_measures_hold_the_water_of_the_cases_they_measure(case):
    """harness.problems.hydrostatic reads rho and g from hydrostatic_column.toml; the collapsing columns it
    also measures must hold the same water, or their pressure noise would be scaled by another case's."""
    from harness import cases
    from harness.problems import hydrostatic as hs

    c = cases.load(paths.CASES / case)
    assert (c["materials"][0]["density"], -c["solver"]["gravity"][1]) == (hs.RHO, hs.G)
