"""The mutation report names the Fortran unit test that killed a mutant, and what it found
broken (the first FAIL line it printed), from meson's test log; the two tiers together are
exactly `make test`'s test files."""

from __future__ import annotations

import json
from pathlib import Path

from tools.mutation.execute import FAST_TESTS, FULL_LAST, full_tier, meson_failure, verify_failure
from tools.mutation.summary import score

REPO = Path(__file__).resolve().parents[1]


def _log(tmp_path, *tests):
    p = tmp_path / "testlog.json"
    p.write_text("\n".join(json.dumps(t) for t in tests) + "\n")
    return p


def test_the_failing_test_and_its_first_fail_line_are_named(tmp_path):
    log = _log(tmp_path, {"name": "fortran-kernels", "result": "OK", "stdout": "fortran kernels: 0 failures\n"},
               {"name": "fortran-coupling", "result": "FAIL", "returncode": 1,
                "stdout": "coupling: hydrostatic ok\nFAIL coupling A vs C^T rel 1e-3\nFAIL second\n"})
    assert meson_failure(log) == "meson test fortran-coupling: FAIL coupling A vs C^T rel 1e-3"


def test_a_crash_without_a_fail_line_names_the_result(tmp_path):
    log = _log(tmp_path, {"name": "fortran-kernels", "result": "ERROR", "returncode": -11, "stdout": ""})
    assert meson_failure(log) == "meson test fortran-kernels: error (exit -11)"


def test_no_log_still_names_meson(tmp_path):
    assert meson_failure(tmp_path / "missing.json") == "meson test (Fortran unit tests)"


def test_fast_and_full_tiers_partition_the_test_files():
    """A survivor of the fast tier is 'survived make test' only if the full tier runs every other
    test file once: the tiers are disjoint and together every tests/test_*.py."""
    every = sorted(str(p.relative_to(REPO)) for p in (REPO / "tests").glob("test_*.py"))
    full = full_tier(REPO)
    assert all((REPO / t).is_file() for t in FAST_TESTS + FULL_LAST)
    assert len(set(full)) == len(full) and not set(full) & set(FAST_TESTS)
    assert sorted(full + FAST_TESTS) == every
    assert full[-len(FULL_LAST):] == FULL_LAST


def test_make_verify_names_the_failed_check_or_the_regressed_metric():
    out = ("check                result  verdict\nhydrostatic_locking  PASS    ok\n"
           "dam_break            FAIL    front position 12 % off\n"
           "REGRESSION: dam_break.front_error = 0.12 vs gold 0.01 (tolerance 0.005) worse\n")
    assert verify_failure(1, out) == "make verify: dam_break FAIL"
    assert verify_failure(1, "REGRESSION: sloshing.period = 1.2 vs gold 1.1\n") == \
        "make verify: REGRESSION: sloshing.period"
    assert verify_failure(-9, "killed\n") == "make verify: exit -9"


def test_kill_rates_by_make_test_and_with_make_verify():
    """A mutant killed only by the verify tier counts for the rate with make verify, not for
    make test's; no-compile mutants count for neither."""
    def row(i, verdict, tier):
        return {"id": f"cpdi_x:{i}:0", "file": "fortran/src/cpdi_x.f90", "verdict": verdict, "tier": tier}
    rows = [row(1, "killed", "fast"), row(2, "killed", "full"), row(3, "killed", "verify"),
            row(4, "survived", "verify"), row(5, "no-compile", "")]
    o = score(rows)["overall"]
    assert (o["counted"], o["killed"], o["killed_with_verify"], o["verify_runs"]) == (4, 2, 3, 2)
    assert o["kill_rate"] == 0.5 and o["kill_rate_with_verify"] == 0.75
    assert o["killed_by_fast_tier"] == 0.5


def test_a_resumed_verify_run_counts_the_survivors_it_verified():
    """A run resumed with --verify tests no new mutant but takes the journal's survivors of make
    test through make verify; the report's run line must say how many, not '0 mutants'."""
    from tools.mutation.main import verified_now
    from tools.mutation.summary import _run_lines

    old = {"a": {"id": "a", "tier": "full", "verdict": "survived"}, "b": {"id": "b", "tier": "fast"},
           "c": {"id": "c", "tier": "verify", "verdict": "killed"}}
    rows = [{"id": "a", "tier": "verify", "verdict": "killed"}, old["b"], old["c"]]
    assert verified_now(old, rows) == 1
    line = _run_lines({"run": {"seconds": 600, "jobs": 1, "tested": 0, "resumed_with": 3, "verified": 1}})[0]
    assert "make verify on 1 survivors" in line and "resumed: 3" in line


def test_a_resumed_run_with_ids_runs_only_those_and_keeps_the_sample():
    """--resume DIR --ids X --verify takes only X of DIR's survivors through make verify (one
    survivor, not all of them at 45 min each); without ids, every unmarked survivor of make test
    and every mutant not yet journalled is pending, the new ones first."""
    from tools.mutation.execute import pending
    from tools.mutation.generate import Mutant

    ms = [Mutant(f"f:{i}:h", "fortran/src/f.f90", i, "a ==> b", "a", "b", f"f:r:k{i}") for i in range(5)]
    done = {"f:0:h": {"verdict": "survived", "tier": "full"}, "f:1:h": {"verdict": "survived", "tier": "full"},
            "f:2:h": {"verdict": "killed", "tier": "fast"}, "f:3:h": {"verdict": "survived", "tier": "full"}}
    marked = {"f:r:k3"}   # marks name content keys
    assert [m.id for m in pending(ms, done, marked, verify=False)] == ["f:4:h"]
    assert [m.id for m in pending(ms, done, marked, verify=True)] == ["f:4:h", "f:0:h", "f:1:h"]
    assert [m.id for m in pending(ms, done, marked, verify=True, only={"f:1:h"})] == ["f:1:h"]
    assert pending(ms, done, marked, verify=True, only={"f:3:h"}) == []   # marked: fast tier only


def test_a_resumed_run_keeps_the_first_runs_timing_in_the_report(tmp_path):
    """Resuming a report (say, the verify tier on its survivors) adds the new run's line; the
    first run's rev, timing and provenance stay in the report (they are the sample's numbers)."""
    from tools.mutation.main import earlier_runs
    from tools.mutation.summary import _run_lines

    first = {"rev": "a" * 40, "date": "2026-11-27", "provenance": {"git_sha": "a" * 40},
             "run": {"seconds": 2820, "jobs": 2, "tested": 224, "resumed_with": 0}}
    report = tmp_path / "mutants.json"
    assert earlier_runs(report) == []
    report.write_text(json.dumps({"meta": first}))
    second = {"rev": "b" * 40, "date": "2026-11-28", "earlier": earlier_runs(report),
              "run": {"seconds": 6600, "jobs": 2, "tested": 0, "resumed_with": 224, "verified": 2}}
    report.write_text(json.dumps({"meta": second}))
    assert [e["rev"] for e in earlier_runs(report)] == ["a" * 40, "b" * 40]
    lines = _run_lines(second)
    assert lines[0].startswith("Run: 110.0 min") and "make verify on 2 survivors" in lines[0]
    assert lines[1] == ("Earlier run of this report (aaaaaaaaaaaa, 2026-11-27): 47.0 min wall time for 224 mutants "
                        "with 2 parallel scratch builds.")
