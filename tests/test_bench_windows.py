"""The bench's 2-thread speed-up gate counts only windows in which a compute-bound control, taken
before and after the timed runs, found two cores, and a cache-line round trip between them cost
near the best the machine showed; it says INCONCLUSIVE, not PASS or FAIL, when too few did
(tools.bench.speedup_windows, core_control and round_trip_control; no solver runs and no timed
busy loops: they are stubbed, only the smoke tests start real, tiny loops and probes)."""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tools import bench, bench_interleave


class _Fake:
    """Stub window: (control before, 1-thread rate, 2-thread rate, control after); round trips
    [ns]: three at the start, then (before, after) per window (55 ns where not given)."""

    def __init__(self, windows, trips=None, start=(55.0, 55.0, 55.0)):
        self.values = itertools.chain.from_iterable(windows)
        self.trips = itertools.chain(start, itertools.chain.from_iterable(trips or []), itertools.repeat(55.0))
        self.log = []

    def control(self):
        self.log.append("control")
        return next(self.values)

    def round_trip(self):
        self.log.append("trip")
        return next(self.trips)

    def pair(self, size, shape, steps):
        self.log.append(f"1 and 2 threads in turns ({steps} steps)")
        one, two = next(self.values), next(self.values)   # rates: 100 particles x steps / wall
        return {"runs": [{"particles": 100, "steps": steps, "wall_s": 100 * steps / r} for r in (one, two)]}


def _measure(monkeypatch, windows, need=3, most=5, trips=None, start=(55.0, 55.0, 55.0)):
    f = _Fake(windows, trips, start)
    monkeypatch.setattr(bench, "core_control", f.control)
    monkeypatch.setattr(bench, "round_trip_control", f.round_trip)
    monkeypatch.setattr(bench_interleave, "pair", f.pair)
    return bench.speedup_windows("32k", lambda msg: None, need=need, most=most), f.log


GOOD = (2.0, 10.0, 19.0, 1.98)


def test_a_window_with_a_bad_control_before_or_after_does_not_count(monkeypatch):
    # a slow spell before the runs, one after them (both with a poor speed-up), then three good
    row, _ = _measure(monkeypatch, [(1.0, 10, 12.0, 2.0), (2.0, 10, 12.0, 1.0)] + [GOOD] * 3)
    assert [w["counted"] for w in row["windows"]] == [False, False, True, True, True]
    assert [(w["control_before"], w["control_after"]) for w in row["windows"][:2]] == [(1.0, 2.0), (2.0, 1.0)]
    assert row["speedup"] == pytest.approx(1.9) and row["verdict"] == "PASS"
    assert row["speedup_all_median"] == pytest.approx(1.9)


def test_the_controls_bracket_the_timed_runs(monkeypatch):
    _, log = _measure(monkeypatch, [GOOD] * 3)
    # three round trips set the machine's best, then each window; stops at `need` counted windows
    run = [f"1 and 2 threads in turns ({bench.WINDOW_STEPS['32k']} steps)"]
    assert log == ["trip"] * 3 + (["control", "trip"] + run + ["control", "trip"]) * 3


def test_a_window_with_the_cores_far_apart_does_not_count_and_is_reported(monkeypatch):
    # the host put the vCPUs where a round trip costs 345 ns, before or after the runs: the
    # speed-up of those windows is kept and reported apart, not gated
    row, _ = _measure(monkeypatch, [(2.0, 10, 16.0, 2.0)] * 2 + [GOOD] * 3,
                      trips=[(345.0, 55.0), (55.0, 345.0)])
    assert [w["round_trip_near"] for w in row["windows"]] == [False, False, True, True, True]
    assert [w["counted"] for w in row["windows"]] == [False, False, True, True, True]
    assert row["speedup"] == pytest.approx(1.9) and row["verdict"] == "PASS"
    assert row["speedup_far_median"] == pytest.approx(1.6) and row["round_trip_best_ns"] == 55.0


def test_windows_are_judged_again_when_the_machine_shows_a_better_round_trip(monkeypatch):
    # the bench starts in a slow stretch (300 ns): windows at 300 ns look near until 55 ns is seen
    row, _ = _measure(monkeypatch, [(2.0, 10, 16.0, 2.0)] * 2 + [GOOD] * 3, need=3, most=5,
                      trips=[(300.0, 300.0), (300.0, 300.0)], start=(300.0, 300.0, 300.0))
    assert row["round_trip_best_ns"] == 55.0
    assert [w["counted"] for w in row["windows"]] == [False, False, True, True, True]
    assert row["speedup"] == pytest.approx(1.9)


def test_the_round_trip_threshold_is_the_documented_one(monkeypatch):
    at = bench.ROUND_TRIP_FACTOR * 55.0
    row, _ = _measure(monkeypatch, [GOOD] * 3, need=1, most=3,
                      trips=[(at * (1 + 1e-9), 55.0), (55.0, at)])
    assert [w["counted"] for w in row["windows"]] == [False, True]


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


def test_the_real_round_trip_probe_runs():
    # smoke test: two threads of this process bounce a cache line; a broken hand-over would hang
    # until the probe's 5 s timeout and raise
    from tools import host_probe
    # (no two cores hand a line back and forth in under 1 ns; 0.1 s a trip allows for a busy machine)
    ns = host_probe.core_round_trip(500)
    assert math.isfinite(ns) and 1.0 < ns < 1.0e8


def test_the_round_trip_probe_refuses_a_bad_count():
    from harness.solver import CpdiError
    from tools import host_probe
    with pytest.raises(CpdiError, match="iters"):
        host_probe.core_round_trip(0)
    assert math.isfinite(host_probe.core_round_trip(1))   # one round trip is a measurement


def test_the_round_trip_probe_refuses_one_thread_at_once():
    """Under OMP_THREAD_LIMIT=1 the probe has no partner thread: it says so at once, and does not
    first wait out its 5 s partner timeout (the lone thread must not bounce)."""
    code = ("import time; from harness.solver import CpdiError; from tools import host_probe\n"
            "t = time.perf_counter()\n"
            "try:\n    host_probe.core_round_trip(100)\nexcept CpdiError as e:\n"
            "    print(round(time.perf_counter() - t, 3), e)\n")
    env = {**os.environ, "OMP_THREAD_LIMIT": "1"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60,
                         cwd=Path(__file__).resolve().parents[1]).stdout
    assert "needs 2 OpenMP threads" in out, out
    assert float(out.split()[0]) < 2.5, out   # 5 s when the lone thread waits for its partner
