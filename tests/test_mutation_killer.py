"""The mutation report names the Fortran unit test that killed a mutant, and what it found
broken (the first FAIL line it printed), from meson's test log."""

from __future__ import annotations

import json

from harness.mutation.execute import meson_failure


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
