"""``python -m harness verify``: run every check, write a report, exit non-zero on failure.

Each check runs in isolation: an exception inside one marks it failed (with the reason)
and the others still run. The report directory is ``reports/<UTC stamp>/`` and
``reports/latest`` points at the newest.
"""

from __future__ import annotations

import importlib
import os
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from harness import provenance, report
from harness.checks.base import CheckContext, CheckResult

REPO = Path(__file__).resolve().parent.parent
CHECKS = ["convergence", "vibrating_bar", "water_column", "hydrostatic_locking"]


def run_checks(names: list[str], out_dir: Path, quick: bool, progress: bool) -> list[CheckResult]:
    results = []
    for name in names:
        mod = importlib.import_module(f"harness.checks.{name}")
        ctx = CheckContext(out_dir=out_dir, quick=quick, runs_dir=REPO / "runs" / "verify" / name,
                           progress=progress)
        ctx.runs_dir.mkdir(parents=True, exist_ok=True)
        print(f"[verify] {name}: {mod.REQUIREMENT}", flush=True)
        t0 = time.perf_counter()
        try:
            res = mod.run(ctx)
        except Exception as exc:  # one broken check must not hide the others
            res = CheckResult(name=name, requirement=mod.REQUIREMENT, error=f"{type(exc).__name__}: {exc}")
        res.wall_s = time.perf_counter() - t0
        print(f"[verify] {name}: {'PASS' if res.passed else 'FAIL'} - {res.verdict} ({res.wall_s:.1f} s)",
              flush=True)
        results.append(res)
    return results


def _point_latest(out_dir: Path) -> None:
    latest = REPO / "reports" / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(os.path.relpath(out_dir, latest.parent))
    except OSError:
        pass


def main(quick: bool = False, only: list[str] | None = None, out: Path | None = None, progress: bool = True) -> int:
    names = CHECKS if not only else only
    unknown = [n for n in names if n not in CHECKS]
    if unknown:
        print(f"error: unknown check(s) {', '.join(unknown)}; available: {', '.join(CHECKS)}", file=sys.stderr)
        return 2
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    out_dir = out or REPO / "reports" / (stamp + ("-quick" if quick else ""))
    out_dir.mkdir(parents=True, exist_ok=True)
    prov = provenance.collect(REPO, REPO / "build")
    prov["tier"] = "quick" if quick else "full"
    results = run_checks(names, out_dir, quick, progress)
    metrics = report.write_report(out_dir, results, prov, quick)
    if out is None:
        _point_latest(out_dir)
    width = max(len(r.name) for r in results)
    print("\n" + "check".ljust(width) + "  result  verdict")
    for r in results:
        print(f"{r.name.ljust(width)}  {'PASS' if r.passed else 'FAIL'}    {r.verdict}")
    print(f"\nreport: {out_dir}/index.html ({'quick' if quick else 'full'} tier)")
    return 0 if metrics["passed"] else 1
