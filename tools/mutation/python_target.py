"""Mutation testing of the harness's check and metric code with mutmut (`make mutate-harness`).

mutmut mutates the modules named in pyproject's [tool.mutmut] only_mutate and runs, for each
mutant, the tests that reach it. It runs in a scratch copy of the committed tree (with the
built extension), never in the user's tree. The quick-verify tier (tests/test_verify_quick.py,
minutes per run) and the Dask tests (tests/test_parallel_dask.py, verify on clusters, a minute) are
left out of mutmut's runs (pyproject: pytest_add_cli_args_test_selection),
so the rate is that of the unit tests alone: a lower bound of what `make test` kills.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from collections import Counter, defaultdict
from datetime import UTC, datetime
from pathlib import Path

from tools.mutation.execute import EXTENSIONS

REPO = Path(__file__).resolve().parents[2]
LINE = re.compile(r"^\s*(\S+?)__mutmut_\d+: (\w[\w ]*)$", re.M)


def main(jobs: int | None = None) -> int:
    rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.strip()
    work = Path(os.environ.get("CPDI_MUTATE_SCRATCH", "/tmp")) / f"cpdi-mutmut-{rev[:12]}"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    tar = subprocess.run(["git", "archive", "--format=tar", rev], cwd=REPO, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(work)], input=tar, check=True)
    (work / ".venv").symlink_to(REPO / ".venv")
    for name, home in EXTENSIONS.items():
        for so in (REPO / home).glob(f"{name}.*.so"):
            shutil.copy2(so, work / home / so.name)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop("PYTEST_ADDOPTS", None)
    n = jobs or len(os.sched_getaffinity(0))
    print(f"mutate-harness: mutmut in {work} ({n} processes)", file=sys.stderr)
    run = subprocess.run([str(work / ".venv" / "bin" / "mutmut"), "run", "--max-children", str(n)], cwd=work,
                         env=env, stdout=subprocess.DEVNULL)
    if run.returncode != 0:
        print("error: mutmut run failed (its own message is above)", file=sys.stderr)
        return 1
    return summarize(work, rev, env)


def summarize(work: Path, rev: str, env: dict) -> int:
    """The report from mutmut's results in the scratch copy `work` (of commit `rev`). A mutant no
    test reaches ("no tests") counts as a survivor: nothing in the unit tests would catch it."""
    res = subprocess.run([str(work / ".venv" / "bin" / "mutmut"), "results", "--all", "true"], cwd=work, env=env,
                         capture_output=True, text=True).stdout
    per: dict[str, Counter] = defaultdict(Counter)
    for name, verdict in LINE.findall(res):
        module = name.rsplit(".x_", 1)[0] if ".x_" in name else name.rsplit(".", 1)[0]
        per[module][verdict] += 1
    out = REPO / "reports" / "mutation" / f"{datetime.now(UTC):%Y-%m-%d}-{rev[:12]}"
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for module, c in sorted(per.items()):
        counted = c["killed"] + c["survived"] + c["timeout"] + c["no tests"]
        rows.append({"module": module, **c, "kill_rate": (c["killed"] + c["timeout"]) / counted if counted else None})
    tot = sum((Counter(per[m]) for m in per), Counter())
    counted = tot["killed"] + tot["survived"] + tot["timeout"] + tot["no tests"]
    rate = (tot["killed"] + tot["timeout"]) / counted if counted else float("nan")
    (out / "python.json").write_text(json.dumps({"rev": rev, "modules": rows, "total": dict(tot),
                                                 "kill_rate": rate}, indent=1) + "\n")
    md = [f"# Mutation testing of the harness (mutmut, {rev[:12]})", "",
          f"**Kill rate {100 * rate:.1f} %** of {counted} mutants (unit tests; the quick-verify tier is left out; "
          "a mutant no unit test reaches counts as surviving).",
          "", "| module | killed | survived | no tests | timeout | kill rate |", "|---|---|---|---|---|---|"]
    for r in rows:
        pct = "n/a" if r["kill_rate"] is None else f"{100 * r['kill_rate']:.1f} %"
        md.append(f"| {r['module']} | {r.get('killed', 0)} | {r.get('survived', 0)} | {r.get('no tests', 0)} | "
                  f"{r.get('timeout', 0)} | {pct} |")
    md += ["", "Survivors (mutmut show NAME in the scratch copy prints the diff):", "", "```",
           *[ln.strip() for ln in res.splitlines() if ln.strip().endswith((": survived", ": no tests"))], "```"]
    (out / "python.md").write_text("\n".join(md) + "\n")
    print(f"mutate-harness: kill rate {100 * rate:.1f} % of {counted}; {out / 'python.md'}")
    return 0
