"""Regression gate: compare a verify run's metrics with the gold baselines.

`reference/gold/metrics.json` holds, per tier (full, quick), every check's key metrics
with an absolute and a relative tolerance, the direction that counts as better, and the
reason for the tolerance. A metric worse than gold beyond max(abs_tol, rel_tol * |gold|)
is a regression and fails the run; one better beyond it is reported as
"improved: regenerate gold" and does not fail. Gold changes only through
`make regen-gold` (`python -m harness verify --regen-gold`) and a reviewed commit.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from harness import paths

GOLD = paths.REFERENCE / "gold" / "metrics.json"

# (metric pattern, abs_tol, rel_tol, better, reason); first match wins; better = lower|higher|either
TOLERANCES: list[tuple[str, float, float, str, str]] = [
    (r"particle_updates_per_s|wall", math.inf, math.inf, "either",
     "timing depends on the machine's load; speed is tracked by make bench, not gated here"),
    (r"^order_", 0.1, 0.0, "higher",
     "observed orders shift by a few hundredths with compiler or FMA differences; losing 0.1 is a real loss"),
    (r"ratio", 0.0, 0.10, "higher",
     "ratios of two errors: 10 % absorbs round-off differences in both, a lost projection costs factors"),
    (r"^(error_|l2_|max_|oscillation_|gci_|dambreak_pressure_noise|energy_)", 1e-6, 0.05, "lower",
     "errors: 5 % relative (floor 1e-6 for near-exact results) absorbs compiler and flag differences; "
     "a broken kernel or a dropped projection changes them by orders of magnitude"),
    (r"ritter_margin_min", 0.05, 0.0, "higher", "distance to Ritter's bound in Z; 0.05 = 1 % of the run-out"),
    (r"^completed$|^particles$", 0.0, 0.0, "either", "exact by construction"),
    (r".*", 0.0, 0.05, "either", "default: 5 % relative, either direction"),
]


def tolerance_for(metric: str) -> dict[str, Any]:
    for pattern, abs_tol, rel_tol, better, reason in TOLERANCES:
        if re.search(pattern, metric):
            return {"abs_tol": abs_tol, "rel_tol": rel_tol, "better": better, "reason": reason}
    raise AssertionError("the catch-all pattern always matches")


def _num(v) -> float:
    return float("nan") if v is None else float(v)


def compare_metric(check: str, metric: str, value, gold: dict[str, Any]) -> dict[str, Any]:
    g = _num(gold["value"])
    v = _num(value)
    row = {"check": check, "metric": metric, "value": v, "gold": g, "abs_tol": gold["abs_tol"],
           "rel_tol": gold["rel_tol"], "status": "ok", "reason": gold.get("reason", "")}
    if math.isnan(g) and math.isnan(v):
        return row
    if math.isnan(v):
        row.update(status="regressed", reason="metric became NaN (the run or the measurement failed)")
        return row
    if math.isnan(g):
        row.update(status="improved", reason="gold has no value (a run failed when gold was made); regenerate gold")
        return row
    tol = max(gold["abs_tol"], gold["rel_tol"] * abs(g))
    diff = v - g
    if abs(diff) <= tol:
        return row
    better = gold.get("better", "either")
    if better == "either":
        row["status"] = "regressed"
    elif (better == "lower") == (diff < 0):
        row["status"] = "improved"
    else:
        row["status"] = "regressed"
    return row


def compare(metrics: dict[str, Any], gold: dict[str, Any], tier: str) -> list[dict[str, Any]]:
    """Rows (check, metric, value, gold, abs_tol, rel_tol, status, reason) for every gold metric
    of the checks present in `metrics` (a metrics.json dict)."""
    rows = []
    base = gold.get("tiers", {}).get(tier, {})
    for check, entries in base.items():
        if check not in metrics.get("checks", {}):
            continue  # not run (e.g. verify --only)
        got = metrics["checks"][check].get("metrics", {})
        for metric, g in entries.items():
            if metric not in got:
                rows.append({"check": check, "metric": metric, "value": float("nan"), "gold": _num(g["value"]),
                             "abs_tol": g["abs_tol"], "rel_tol": g["rel_tol"], "status": "regressed",
                             "reason": "metric missing from the run"})
                continue
            rows.append(compare_metric(check, metric, got[metric], g))
    return rows


def load_gold(path: Path = GOLD) -> dict[str, Any]:
    if not path.is_file():
        return {}
    return json.loads(path.read_text())


def gold_entries(metrics: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Gold entries (value + tolerance + reason) for every gated metric of a metrics.json dict."""
    out: dict[str, dict[str, Any]] = {}
    for check, data in metrics["checks"].items():
        entries = {}
        for metric, value in data.get("metrics", {}).items():
            tol = tolerance_for(metric)
            if math.isinf(tol["abs_tol"]):
                continue
            v = _num(value)
            entries[metric] = {"value": None if math.isnan(v) else v, **tol}
        out[check] = entries
    return out


def write_gold(tiers: dict[str, dict[str, Any]], provenance: dict[str, Any], path: Path = GOLD) -> None:
    """Write gold for the given tiers ({tier: metrics.json dict}), keeping other tiers."""
    gold = load_gold(path) or {"schema": 1, "tiers": {}}
    gold["note"] = ("Regression baselines. Change only through `make regen-gold` and a reviewed commit; "
                    "each metric carries its tolerance and the reason for it.")
    for tier, metrics in tiers.items():
        gold["tiers"][tier] = gold_entries(metrics)
        gold.setdefault("provenance", {})[tier] = provenance
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(gold, indent=1, sort_keys=True, allow_nan=False) + "\n")


def summary_lines(rows: list[dict[str, Any]]) -> list[str]:
    lines = []
    for r in rows:
        if r["status"] == "ok":
            continue
        tol = max(r["abs_tol"], r["rel_tol"] * abs(r["gold"])) if not math.isnan(r["gold"]) else float("nan")
        word = "REGRESSION" if r["status"] == "regressed" else "improved: regenerate gold"
        lines.append(f"{word}: {r['check']}.{r['metric']} = {r['value']:.6g} vs gold {r['gold']:.6g} "
                     f"(tolerance {tol:.3g}) {r['reason']}")
    return lines
