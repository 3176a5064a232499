"""``python -m harness verify``: run every check, write a report, exit non-zero on failure.

Each check runs in isolation: an exception inside one marks it failed (with the reason)
and the others still run. The report directory is ``reports/<UTC stamp>/`` and
``reports/latest`` points at the newest.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path

from harness import gate, parallel, paths, provenance, report
from harness.checks.base import CheckContext, CheckResult

CHECKS = ["convergence", "vibrating_bar", "water_column", "hydrostatic_locking", "dam_break_front",
          "elastic_obstacle", "rigid_obstacle", "resting_tank", "dam_break_pressure", "floating_block",
          "sinking_block"]
# Runnable with --only but not yet part of the gated set (see the issue notes for why).
# wedge_entry (issue 40 item 4): its self-similarity gate fails at every h tried, 0.02-0.0025 (the profiles
# part at the spray root, which sits about half a cell too high at every time; docs/notes/wedge_entry.md),
# so it would fail the quick tier of make test.
# accelerated_tank (issue 38 item 4): passes at the case's h = 0.05 (8 x 8 particles per cell), but at
# h = 0.025 a surface current next to the left wall moves particles 12 h (docs/notes/accelerated_tank.md).
# cylinder_entry (issue 40): its Cs lies 10-30 % above Campbell & Weynberg's fit (a secondary source's
# reading of DNV's), converged in h (docs/notes/cylinder_entry.md).
# wedge_drop (issue 40): within 5 % of the 2D BEM only at h = 0.01 (the quick tier's h = 0.02: 7.4 %);
# cylinder_drop (issue 40): 0.33 D deeper than Greenhow & Lin's record, 0.2 D beyond the 2D SPH once
# submerged, cause not found (docs/notes/wedge_drop.md, cylinder_drop.md).
EXPERIMENTAL: list[str] = ["wedge_entry", "accelerated_tank", "cylinder_entry", "wedge_drop", "cylinder_drop"]


def _check_bar(total: int, progress: bool, file=None):
    """Live per-check progress (checks done / total, the current check, elapsed), on stderr (or
    ``file``); off with --no-progress and where stderr is not a terminal (CI logs keep the plain lines)."""
    from tqdm import tqdm

    disable = (None if file is None else False) if progress else True
    return tqdm(total=total, desc="verify", unit="check", disable=disable, file=file, dynamic_ncols=True,
                bar_format="{desc}: {n}/{total} checks done{postfix} |{bar}| [{elapsed}]")


def run_checks(names: list[str], out_dir: Path, quick: bool, progress: bool) -> list[CheckResult]:
    from tqdm import tqdm

    results = []
    pool = parallel.active()
    mods = {name: importlib.import_module(f"harness.checks.{name}") for name in names}
    ctxs = {name: CheckContext(out_dir=out_dir, quick=quick, runs_dir=paths.work_root() / "runs" / "verify" / name,
                               progress=progress) for name in names}
    for name, mod in mods.items():   # a check's longest runs start now, beside every check before it
        ctxs[name].runs_dir.mkdir(parents=True, exist_ok=True)
        if hasattr(mod, "start_early"):
            try:
                mod.start_early(ctxs[name])
            except Exception:   # only a head start: the check's run meets the same error and reports it
                ctxs[name].early.clear()
    with _check_bar(len(names), progress) as bar:
        for name in names:
            mod, ctx = mods[name], ctxs[name]
            bar.set_postfix_str(f"running {name}")
            tqdm.write(f"[verify] {name}: {mod.REQUIREMENT}", file=sys.stdout)
            t0 = time.perf_counter()
            seen = len(pool.reruns) if pool else 0
            if pool:
                pool.context = name
            try:
                res = mod.run(ctx)
            except Exception as exc:  # one broken check must not hide the others
                res = CheckResult(name=name, requirement=mod.REQUIREMENT, error=f"{type(exc).__name__}: {exc}")
            res.wall_s = time.perf_counter() - t0
            if pool and pool.reruns[seen:]:
                res.notes.append(_rerun_note(pool.reruns[seen:]))
            tqdm.write(f"[verify] {name}: {'PASS' if res.passed else 'FAIL'} - {res.verdict} ({res.wall_s:.1f} s)",
                       file=sys.stdout)
            sys.stdout.flush()
            results.append(res)
            if len(results) == len(names):
                bar.set_postfix_str("", refresh=False)
            bar.update(1)
    if pool:
        pool.context = ""
    return results


def _rerun_note(reruns: list[parallel.Rerun]) -> str:
    return (f"**Re-run:** {parallel.reruns_text([asdict(r) | {'context': ''} for r in reruns])}. The results "
            "above are complete, from the re-runs (a run gives the same bits wherever it runs).")


def _point_latest(out_dir: Path) -> None:
    latest = paths.work_root() / "reports" / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(os.path.relpath(out_dir, latest.parent))
    except OSError:
        pass


def verify(quick: bool, names: list[str], out_dir: Path, progress: bool, jobs: int | None = None,
           scheduler: str | None = None) -> tuple[dict, list[dict]]:
    """Run the checks, compare with gold, write the report; returns (metrics, gate rows). The checks'
    independent runs go to the active parallel.cluster, or to one opened here (jobs, scheduler)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    prov = provenance.collect(paths.SOURCE_ROOT, paths.build_dir())
    active = parallel.active()
    with contextlib.nullcontext(active) if active else parallel.cluster(jobs, scheduler) as pool:
        print(f"[verify] independent runs: {pool.describe()}", flush=True)
        since = pool.mark()
        results = run_checks(names, out_dir, quick, progress)
        execution = pool.summary(since)
    draft = report.build_metrics(results, prov, quick)
    rows = gate.compare(draft, gate.load_gold(), "quick" if quick else "full")
    metrics = report.write_report(out_dir, results, prov, quick, gate_summary=rows or None,
                                  bench_dir=paths.work_root() / "reports" / "bench", execution=execution)
    width = max(len(r.name) for r in results)
    print("\n" + "check".ljust(width) + "  result  verdict")
    for r in results:
        print(f"{r.name.ljust(width)}  {'PASS' if r.passed else 'FAIL'}    {r.verdict}")
    for line in gate.summary_lines(rows):
        print(line)
    if not rows:
        print("gold: no baseline for this tier (make regen-gold writes one)")
    else:
        bad = sum(r["status"] == "regressed" for r in rows)
        print(f"gold: {len(rows)} metrics compared, {bad} regressed, "
              f"{sum(r['status'] == 'improved' for r in rows)} improved")
    print(f"runs: {parallel.execution_text(execution).replace('**', '')}")
    print(f"\nreport: {out_dir}/index.html ({'quick' if quick else 'full'} tier)")
    return metrics, rows


def _stamp(quick: bool) -> str:
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ") + ("-quick" if quick else "")


def main(quick: bool = False, only: list[str] | None = None, out: Path | None = None, progress: bool = True,
         regen_gold: bool = False, jobs: int | None = None, scheduler: str | None = None) -> int:
    names = CHECKS if not only else only
    unknown = [n for n in names if n not in CHECKS + EXPERIMENTAL]
    if unknown:
        extra = f" (experimental: {', '.join(EXPERIMENTAL)})" if EXPERIMENTAL else ""
        print(f"error: unknown check(s) {', '.join(unknown)}; available: {', '.join(CHECKS)}{extra}",
              file=sys.stderr)
        return 2
    if regen_gold:
        if only:
            print("error: --regen-gold runs every check; drop --only", file=sys.stderr)
            return 2
        tiers = {}
        with parallel.cluster(jobs, scheduler):  # one cluster for both tiers
            for tier_quick in (False, True):
                out_dir = paths.work_root() / "reports" / _stamp(tier_quick)
                metrics, _ = verify(tier_quick, CHECKS, out_dir, progress)
                failed = [n for n, c in metrics["checks"].items() if not c["passed"]]
                if failed:
                    print(f"error: gold not written: checks failed in the {'quick' if tier_quick else 'full'} "
                          f"tier: {', '.join(failed)}; fix them first", file=sys.stderr)
                    return 1
                tiers["quick" if tier_quick else "full"] = metrics
        gate.write_gold(tiers, metrics["provenance"])
        print(f"wrote {gate.GOLD}: review the diff and commit it")
        return 0
    out_dir = out or paths.work_root() / "reports" / _stamp(quick)
    metrics, _ = verify(quick, names, out_dir, progress, jobs, scheduler)
    if out is None:
        _point_latest(out_dir)
    return 0 if metrics["passed"] else 1
