"""The bench's 2-thread speed-up gate counts only windows in which a compute-bound control, taken
before and after the timed runs, found two cores, and says INCONCLUSIVE, not PASS or FAIL, when
too few did (harness.bench.speedup_windows and core_control; no solver runs and no timed busy
loops: both are stubbed, only the smoke test starts real, tiny loops)."""

from __future__ import annotations

import itertools
import math

import pytest

from harness import bench


class _Fake:
    """Stub window: (control before, 1-thread rate, 2-thread rate, control after)."""

    def __init__(self, windows):
        self.values = itertools.chain.from_iterable(windows)
        self.log = []

    def control(self):
        self.log.append("control")
        return next(self.values)

    def run_one(self, size, shape, threads, repo=None):
        self.log.append(f"run {threads}")
        return {"particle_updates_per_s": next(self.values)}


def _measure(monkeypatch, windows, need=3, most=5):
    f = _Fake(windows)
    monkeypatch.setattr(bench, "core_control", f.control)
    monkeypatch.setattr(bench, "_run_one", f.run_one)
    return bench.speedup_windows("32k", lambda msg: None, need=need, most=most), f.log


GOOD = (2.0, 10.0, 19.0, 1.98)


def test_a_window_with_a_bad_control_before_or_after_does_not_count(monkeypatch):
    # a slow spell before the runs, one after them (both with a poor speed-up), then three good
    row, _ = _measure(monkeypatch, [(1.0, 10, 12.0, 2.0), (2.0, 10, 12.0, 1.0)] + [GOOD] * 3)
    assert [w["counted"] for w in row["windows"]] == [False, False, True, True, True]
    assert [(w["control_before"], w["control_after"]) for w in row["windows"][:2]] == [(1.0, 2.0), (2.0, 1.0)]
    assert row["speedup"] == pytest.approx(1.9) and row["verdict"] == "PASS"
    assert row["speedup_all_median"] == pytest.approx(1.9)


def test_the_control_brackets_the_timed_runs(monkeypatch):
    _, log = _measure(monkeypatch, [GOOD] * 3)
    assert log == ["control", "run 1", "run 2", "control"] * 3   # stops at `need` counted windows


def test_a_slow_code_fails_on_a_machine_that_delivers(monkeypatch):
    row, _ = _measure(monkeypatch, [(2.0, 10, 12.0, 2.0)] * 3)
    assert row["speedup"] == pytest.approx(1.2) and row["verdict"] == "FAIL"


def test_never_two_cores_is_inconclusive_not_a_pass(monkeypatch):
    row, _ = _measure(monkeypatch, [(1.0, 10, 25.0, 1.0)] * 5)   # even a 2.5x reading counts for nothing
    assert row["counted"] == 0 and row["speedup"] is None and row["verdict"] == "INCONCLUSIVE"
    assert len(row["windows"]) == 5


def test_the_control_threshold_is_the_documented_one(monkeypatch):
    at, below = bench.CONTROL_MIN, bench.CONTROL_MIN - 1e-9
    row, _ = _measure(monkeypatch, [(at, 1, 2, below), (below, 1, 2, at), (at, 1, 2, at)], need=1, most=3)
    assert [w["counted"] for w in row["windows"]] == [False, False, True]


def _timed_control(monkeypatch, alone, a, b):
    """core_control with its loops' times stubbed; returns the control and the call order."""
    times, log = iter((alone, a, b)), []

    def spin():
        log.append("start")
        return next(times)

    def collect(p, what):
        log.append("wait")
        return {"loop_s": p}

    monkeypatch.setattr(bench, "_spin", spin)
    monkeypatch.setattr(bench, "_collect", collect)
    return bench.core_control(), log


@pytest.mark.parametrize(("alone", "a", "b", "control"), [
    (0.4, 0.4, 0.4, 2.0),     # two free cores
    (0.4, 0.8, 0.8, 1.0),     # one core (or two vCPUs at half speed each)
    (0.4, 0.4, 0.8, 1.0),     # the slower loop of the pair sets it
    (0.4, 0.5, 0.45, 1.6),
])
def test_core_control_arithmetic(monkeypatch, alone, a, b, control):
    assert _timed_control(monkeypatch, alone, a, b)[0] == pytest.approx(control)


def test_the_pair_of_loops_runs_at_once(monkeypatch):
    # the alone loop finishes before the pair starts; both of the pair start before either is waited for
    assert _timed_control(monkeypatch, 0.4, 0.4, 0.4)[1] == ["start", "wait", "start", "start", "wait", "wait"]


def test_the_real_control_loop_runs(monkeypatch):
    # smoke test only: a tiny loop, so the value says nothing about the machine
    monkeypatch.setattr(bench, "CONTROL_LOOP", 20_000)
    c = bench.core_control()
    assert math.isfinite(c) and c > 0
