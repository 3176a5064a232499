"""`python -m tools.mutation`: generate, sample, run and report (see the package docstring)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from harness import paths, provenance
from tools.mutation import execute, generate, summary

REPO = Path(__file__).resolve().parents[2]


def main(sample: int = 220, jobs: int | None = None, seed: int = 20, full: bool = True, resume: str | None = None,
         fast_timeout: float = 120.0, full_timeout: float = 1200.0, only: list[str] | None = None,
         report_only: bool = False, ids: list[str] | None = None, verify_timeout: float | None = None) -> int:
    t0 = time.perf_counter()
    rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.strip()
    if subprocess.run(["git", "status", "--porcelain", "fortran", "tests"], cwd=REPO, capture_output=True,
                      text=True).stdout.strip():
        print("note: fortran/ or tests/ have uncommitted changes; mutants are made from and run against the "
              f"committed tree {rev[:12]} (commit first to include them)", file=sys.stderr)
    files = only or generate.sources(REPO)
    every = {f: generate.file_mutants(_committed(rev), f) for f in files}
    if ids and not resume:  # exactly these mutants (ids from a report's mutants.json), no sample
        chosen = [m for f in files for m in every[f] if m.id in ids]
        missing = sorted(set(ids) - {m.id for m in chosen})
        if missing:
            raise SystemExit(f"error: no such mutant at {rev[:12]}: {', '.join(missing)} (an id names "
                             "file:line:hash of the mutated line; a changed source line changes it)")
    else:
        chosen = generate.sample(every, sample, seed)
        missing = sorted(set(ids or []) - {m.id for m in chosen})
        if missing:  # --ids with --resume: run only these of the report's sample; it still covers all
            raise SystemExit(f"error: not in the sample of {resume} (seed {seed}, {sample} mutants) at "
                             f"{rev[:12]}: {', '.join(missing)}")
    sampling = (f"stratified sample of {len(chosen)} of {sum(map(len, every.values()))} mutants over {len(files)} "
                f"files (share ~ sqrt of each file's count, at least 3, seed {seed})")
    if ids and not resume:
        sampling = f"the {len(chosen)} mutants asked for by id (--ids)"
    meta = {"rev": rev, "date": datetime.now(UTC).strftime("%Y-%m-%d"), "seed": seed, "sampling": sampling,
            "tiers": "fast (Fortran unit tests + " + str(len(execute.FAST_TESTS)) + " unit-level pytest files, -x) "
                     + ("then the rest of make test for survivors" if full else "only")
                     + ("; make verify for make test's survivors" if verify_timeout else "")}
    stale = summary.stale_marks(_committed(rev), files, {m.key for ms in every.values() for m in ms})
    if stale:
        meta["stale_marks"] = sorted(stale)
        print(f"warning: {len(stale)} mark(s) in tools/mutation/equivalent.toml name no mutant at {rev[:12]}:\n  "
              + "\n  ".join(stale.values()), file=sys.stderr)
    name = f"{meta['date']}-{rev[:12]}" + ("-ids" if ids else "")   # an id run never mixes into a sample's report
    out = Path(resume) if resume else REPO / "reports" / "mutation" / name
    out.mkdir(parents=True, exist_ok=True)
    meta["earlier"] = earlier_runs(out / "mutants.json")
    print(f"mutate: {meta['sampling']}; report in {out}", file=sys.stderr)
    meta["provenance"] = provenance.collect(REPO, paths.build_dir())
    if report_only:  # summarise what the journal holds so far (an interrupted run), run nothing
        rows = execute.journal_rows(out / "journal.jsonl", chosen)
    else:
        jobs = jobs or len(os.sched_getaffinity(0))
        old = {r["id"]: r for r in execute.journal_rows(out / "journal.jsonl", chosen)}
        rows = execute.run_all(REPO, rev, chosen, out / "journal.jsonl", jobs, fast_timeout, full_timeout, full,
                               execute.say, verify_timeout, set(ids) if ids and resume else None)
        meta["run"] = {"seconds": round(time.perf_counter() - t0, 1), "jobs": jobs, "tested": len(rows) - len(old),
                       "resumed_with": len(old), "verified": verified_now(old, rows)}
    if len(rows) < len(chosen):  # an interrupted run's journal, or --ids on one not yet whole
        meta["sampling"] += f"; partial: {len(rows)} of {len(chosen)} tested"
    sc = summary.write(out, rows, meta)["overall"]
    print(f"mutate: kill rate {100 * sc['kill_rate']:.1f} % of {sc['counted']} counted mutants "
          f"({sc['no_compile']} did not compile, {sc['equivalent']} equivalent); fast tier killed "
          f"{100 * sc['killed_by_fast_tier']:.1f} % of the killed; {out / 'index.html'}")
    return 0


def earlier_runs(report: Path) -> list[dict]:
    """The runs a resumed report holds already (their rev, date, timing and provenance), oldest
    first: a resumed run adds its own line to the report instead of replacing the first run's."""
    if not report.exists():
        return []
    meta = json.loads(report.read_text()).get("meta", {})
    this = [{k: meta[k] for k in ("rev", "date", "run", "provenance") if k in meta}] if "run" in meta else []
    return meta.get("earlier", []) + this


def verified_now(old: dict[str, dict], rows: list[dict]) -> int:
    """Mutants this run took through the verify tier (a resumed run's survivors of make test too)."""
    return sum(r.get("tier") == "verify" and old.get(r["id"], {}).get("tier") != "verify" for r in rows)


def _committed(rev: str) -> Path:
    """A read-only export of the committed fortran/src of rev (mutants are made from it)."""
    dest = Path(os.environ.get("CPDI_MUTATE_SCRATCH", "/tmp")) / f"cpdi-mutate-{rev[:12]}" / "src"
    if not dest.exists():
        dest.mkdir(parents=True)
        tar = subprocess.run(["git", "archive", "--format=tar", rev, "fortran/src"], cwd=REPO, capture_output=True,
                             check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=tar, check=True)
    return dest
