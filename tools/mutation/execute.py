"""Build and test each mutant in scratch copies of the committed tree, in parallel, resumably."""

from __future__ import annotations

import io
import json
import os
import queue
import random
import re
import shutil
import subprocess
import sys
import tarfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from tools.mutation.generate import Mutant
from tools.mutation.summary import equivalent_keys

# The fast tier: unit-level tests of kernels, transfers, constitutive models, walls and the
# incompressible step (each file runs in seconds, ~30 s in all). The full tier is what
# `make test` runs.
FAST_TESTS = [  # most specific first: with -x the first failure names the killing test
    "tests/test_constitutive.py", "tests/test_walls.py", "tests/test_log_strain.py",
    "tests/test_shape_functions.py", "tests/test_projection.py", "tests/test_incompressible.py",
    "tests/test_incompressible_flow.py", "tests/test_fsi_incompressible.py", "tests/test_timers.py",
    "tests/test_objectivity.py", "tests/test_conservation.py", "tests/test_rigid_and_scaling.py",
    "tests/test_vibrating_bar.py", "tests/test_bad_input.py", "tests/test_incompressible_input.py",
    "tests/test_determinism.py", "tests/test_contact.py", "tests/test_bench_windows.py",
]
# The full tier is the rest of `make test` (the fast tier already passed, and so did the Fortran
# unit tests): every other tests/test_*.py, the slow ones last (with -x a kill by a quick file ends
# the run within a minute; a survivor runs them all either way). The quick-verify tier alone is
# most of the full tier's time (docs/mutation_testing.md).
FULL_LAST = ["tests/test_parallel_dask.py", "tests/test_verify_quick.py"]
FAILED = re.compile(r"^(?:FAILED|ERROR) (\S+)", re.M)


def _env(work: Path) -> dict:
    env = dict(os.environ)
    env["PATH"] = f"{work / '.venv' / 'bin'}:{env.get('PATH', '')}"
    env["OMP_NUM_THREADS"] = "1"          # one core per worker: the workers share the machine
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env.pop("PYTEST_ADDOPTS", None)
    return env


def _run(cmd: list[str], cwd: Path, timeout: float) -> tuple[int | None, str, float]:
    """(exit code or None on time-out, combined output, seconds)."""
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=cwd, env=_env(cwd), capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout + p.stderr, time.perf_counter() - t0
    except subprocess.TimeoutExpired as exc:
        out = (exc.stdout or b"") + (exc.stderr or b"")
        return None, out.decode(errors="replace") if isinstance(out, bytes) else str(out), time.perf_counter() - t0


# The f2py extensions and where make build copies them (the Makefile's build target): the solver's,
# the tests' and the bench's, each rebuilt from the mutated core.
EXTENSIONS = {"_cpdi": "harness", "_cpdi_test": "tests", "_cpdi_bench": "tools"}


class Worker:
    """One scratch copy of the committed tree with its own build directory."""

    def __init__(self, repo: Path, root: Path, index: int):
        self.repo, self.dir = repo, root / f"w{index}"

    def setup(self, rev: str) -> None:
        if self.dir.exists():
            shutil.rmtree(self.dir)
        self.dir.mkdir(parents=True)
        archive = subprocess.run(["git", "archive", "--format=tar", rev], cwd=self.repo, capture_output=True,
                                 check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(self.dir, filter="data")
        (self.dir / ".venv").symlink_to(self.repo / ".venv")
        meson = str(self.repo / ".venv" / "bin" / "meson")
        code, out, _ = _run([meson, "setup", "build", ".", "--python.install-env=auto",
                             "-Dpython.bytecompile=-1"], self.dir, 600)
        if code != 0:
            raise RuntimeError(f"meson setup failed in {self.dir}:\n{out[-2000:]}")
        if self.build(1800) is not True:
            raise RuntimeError(f"the unmutated tree does not build in {self.dir}")

    def build(self, timeout: float) -> bool | None:
        """True if it built (the extensions copied where make build puts them), False if not, None on
        time-out."""
        code, _, _ = _run([str(self.repo / ".venv" / "bin" / "meson"), "compile", "-C", "build"], self.dir, timeout)
        if code != 0:
            return None if code is None else False
        for name, home in EXTENSIONS.items():
            for so in (self.dir / home).glob(f"{name}.*.so"):
                so.unlink()
            for so in (self.dir / "build" / "fortran").glob(f"{name}.*.so"):
                shutil.copy2(so, self.dir / home / so.name)
        return True

    def tier(self, tests: list[str], timeout: float, fortran: bool = True) -> tuple[str, str, float]:
        """Run the Fortran unit tests (if fortran), then pytest (-x) on `tests`. Returns
        (verdict: 'pass' | 'fail' | 'timeout', the first failing test, seconds)."""
        t1 = 0.0
        if fortran:
            meson = str(self.repo / ".venv" / "bin" / "meson")
            code, out, t1 = _run([meson, "test", "-C", "build", "--no-rebuild", "-q"], self.dir, timeout)
            if code is None:
                return "timeout", "meson test (Fortran unit tests)", t1
            if code != 0:
                return "fail", meson_failure(self.dir / "build" / "meson-logs" / "testlog.json"), t1
        py = str(self.repo / ".venv" / "bin" / "python")
        present = [t for t in tests if (self.dir / t).is_file()]
        cmd = [py, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-o", "addopts=-rfE", *present]
        code, out, t2 = _run(cmd, self.dir, max(timeout - t1, 10))
        if code is None:
            return "timeout", "pytest (time limit)", t1 + t2
        if code == 0:
            return "pass", "", t1 + t2
        m = FAILED.search(out)
        return "fail", m.group(1) if m else f"pytest exit {code}", t1 + t2

    def verify(self, timeout: float) -> tuple[str, str, float]:
        """`make verify` on the built mutant (every check, compared with gold)."""
        code, out, t = _run([str(self.repo / ".venv" / "bin" / "python"), "-m", "harness", "verify"], self.dir,
                            timeout)
        if code is None:
            return "timeout", "make verify (time limit)", t
        return ("pass", "", t) if code == 0 else ("fail", verify_failure(code, out), t)


VERIFY_FAILED = re.compile(r"^(REGRESSION: \S+|\S+\s+FAIL\b)", re.M)


def full_tier(work: Path) -> list[str]:
    """The test files of `make test` outside the fast tier, FULL_LAST last."""
    rest = sorted(str(p.relative_to(work)) for p in (work / "tests").glob("test_*.py"))
    rest = [t for t in rest if t not in FAST_TESTS and t not in FULL_LAST]
    return rest + [t for t in FULL_LAST if (work / t).is_file()]


def verify_failure(code: int, out: str) -> str:
    """What `harness verify` found broken: its first failing check or regressed gold metric."""
    m = VERIFY_FAILED.search(out)
    return "make verify: " + (" ".join(m.group(1).split()) if m else f"exit {code}")


def meson_failure(log: Path) -> str:
    """The first failing Fortran unit test and its first FAIL line (what broke), from meson's
    testlog.json; `meson test` in general where the log cannot be read."""
    try:
        for line in log.read_text().splitlines():
            t = json.loads(line)
            if t.get("result") != "OK":
                what = next((ln.strip() for ln in t.get("stdout", "").splitlines() if ln.startswith("FAIL")),
                            f"{t.get('result', 'FAIL').lower()} (exit {t.get('returncode')})")
                return f"meson test {t.get('name', '?')}: {what}"
    except (OSError, ValueError):
        pass
    return "meson test (Fortran unit tests)"


def journal_rows(journal: Path, mutants: list[Mutant]) -> list[dict]:
    """The journal's rows of these mutants, in the mutants' order."""
    done = {}
    if journal.is_file():
        for line in journal.read_text().splitlines():
            if line.strip():
                row = json.loads(line)
                done[row["id"]] = row
    # a row's key is the mutant's content key as this tree computes it (rows journalled before the
    # keys existed, or under another normalisation, then still meet their marks)
    return [{**done[m.id], "key": m.key} for m in mutants if m.id in done]


def pending(mutants: list[Mutant], done: dict[str, dict], marked: set[str], verify: bool,
            only: set[str] | None = None) -> list[Mutant]:
    """What a run still has to do: every mutant not in the journal, in a fixed shuffled order (a
    run cut short then leaves a random part of the sample tested, whose partial report speaks for
    every file, not the first files); with verify, then the journalled survivors of make test
    that are not marked (the verify tier only). `only` (ids): just these of them."""
    todo = [m for m in mutants if m.id not in done]
    random.Random(len(mutants)).shuffle(todo)
    if verify:
        todo += [m for m in mutants if m.id in done and m.key not in marked and done[m.id]["verdict"] == "survived"
                 and done[m.id].get("tier") == "full"]
    return [m for m in todo if only is None or m.id in only]


def run_all(repo: Path, rev: str, mutants: list[Mutant], journal: Path, jobs: int, fast_timeout: float,
            full_timeout: float, full: bool, progress, verify_timeout: float | None = None,
            only: set[str] | None = None) -> list[dict]:
    """Test every mutant not yet in the journal (of `only`, if given); returns all journal rows
    (old and new). With verify_timeout, a survivor of the whole `make test` (also one journalled
    before) then runs `make verify` (the verify tier), limited to verify_timeout s."""
    done = {r["id"]: r for r in journal_rows(journal, mutants)}
    marked = set(equivalent_keys())   # equivalent by hand: the fast tier only (a kill there contradicts the mark)
    todo = pending(mutants, done, marked, bool(verify_timeout), only)
    if not todo:
        return [done[m.id] for m in mutants if m.id in done]
    root = Path(os.environ.get("CPDI_MUTATE_SCRATCH", "/tmp")) / f"cpdi-mutate-{rev[:12]}"
    workers = [Worker(repo, root, i) for i in range(min(jobs, len(todo)))]
    progress(f"setting up {len(workers)} scratch builds of {rev[:12]} under {root} (a full build each)")
    with ThreadPoolExecutor(len(workers)) as ex:
        list(ex.map(lambda w: w.setup(rev), workers))
    base = workers[0].tier(FAST_TESTS, 1800)
    if base[0] != "pass":
        raise RuntimeError(f"the unmutated tree fails the fast tier ({base[1]}): fix the suite before mutating")
    fast_timeout = max(fast_timeout, 3 * base[2])
    progress(f"fast tier of the unmutated tree: {base[2]:.0f} s; time limit per mutant {fast_timeout:.0f} s")
    free: queue.Queue[Worker] = queue.Queue()
    for w in workers:
        free.put(w)
    lock = threading.Lock()

    def one(m: Mutant) -> dict:
        w = free.get()
        try:
            return _test_one(w, m, fast_timeout, full_timeout, full and m.key not in marked,
                             verify_timeout if m.key not in marked else None, done.get(m.id))
        finally:
            free.put(w)

    with ThreadPoolExecutor(len(workers)) as ex, journal.open("a") as jf:
        for fut in as_completed([ex.submit(one, m) for m in todo]):  # journal each as it ends
            row = fut.result()
            with lock:
                jf.write(json.dumps(row) + "\n")
                jf.flush()
                done[row["id"]] = row
                progress(row)
    return [done[m.id] for m in mutants if m.id in done]


def _test_one(w: Worker, m: Mutant, fast_timeout: float, full_timeout: float, full: bool,
              verify_timeout: float | None = None, survived: dict | None = None) -> dict:
    """Build mutant m in worker w and run the tiers (fast, then full if full and it survived, then
    verify if verify_timeout and it survived again). `survived`: its journal row as a survivor of
    make test, so that only the verify tier runs."""
    path = w.dir / m.file
    original = path.read_text(encoding="utf-8")
    lines = original.splitlines(keepends=True)
    assert lines[m.line - 1].rstrip("\n") == m.before, f"{m.id}: the source changed since the mutants were made"
    lines[m.line - 1] = m.after + "\n"
    row = {**m.to_dict(), "verdict": "", "killed_by": "", "tier": "", "seconds": 0.0}
    t0 = time.perf_counter()
    try:
        path.write_text("".join(lines), encoding="utf-8")
        built = w.build(600)
        if built is not True:
            row.update(verdict="no-compile" if built is False else "timeout-build")
            return row
        if survived:
            verdict, test = "pass", ""
            row["tier"] = survived["tier"]
        else:
            verdict, test, _ = w.tier(FAST_TESTS, fast_timeout)
            row["tier"] = "fast"
            if verdict == "pass" and full:
                verdict, test, _ = w.tier(full_tier(w.dir), full_timeout, fortran=False)
                row["tier"] = "full"
        if verdict == "pass" and row["tier"] == "full" and verify_timeout:
            verdict, test, _ = w.verify(verify_timeout)
            row["tier"] = "verify"
        row.update(verdict={"fail": "killed", "timeout": "killed (time limit)", "pass": "survived"}[verdict],
                   killed_by=test)
        return row
    finally:
        path.write_text(original, encoding="utf-8")
        row["seconds"] = round(time.perf_counter() - t0, 1)


def say(msg) -> None:
    print(msg if isinstance(msg, str) else f"  {msg['id']:<34} {msg['verdict']:<20} {msg['killed_by'][:60]} "
          f"({msg['seconds']:.0f} s)", file=sys.stderr, flush=True)
