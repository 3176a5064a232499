"""The bench's 2-thread speed-up gate counts only windows in which the machine delivered two
cores to two independent processes (its control), and says INCONCLUSIVE, not PASS or FAIL,
when it never did (harness.bench.speedup_windows; no solver runs: the runs are stubbed)."""

from __future__ import annotations

import itertools

import pytest

from harness import bench


class _Fake:
    """Stub runs: per window a solo 1-thread rate, a control pair and a 2-thread rate."""

    def __init__(self, windows):
        self.rates = itertools.chain.from_iterable(
            (solo, a, b, two) for solo, a, b, two in windows)

    def run_one(self, size, shape, threads, repo=None):
        return {"particle_updates_per_s": next(self.rates)}

    def spawn(self, size, shape, threads, repo=None):
        return next(self.rates)

    def collect(self, p, what):
        return {"particle_updates_per_s": p}


def _measure(monkeypatch, windows, need=3, most=5):
    f = _Fake(windows)
    monkeypatch.setattr(bench, "_run_one", f.run_one)
    monkeypatch.setattr(bench, "_spawn", f.spawn)
    monkeypatch.setattr(bench, "_collect", f.collect)
    return bench.speedup_windows("32k", lambda msg: None, need=need, most=most)


def test_windows_where_the_machine_gave_one_core_do_not_count(monkeypatch):
    # two windows in a slow spell (control 1.0: two processes at half speed each), then three good
    row = _measure(monkeypatch, [(10, 5, 5, 10)] * 2 + [(10, 10, 9.8, 19.0)] * 3)
    assert [w["counted"] for w in row["windows"]] == [False, False, True, True, True]
    assert row["speedup"] == pytest.approx(1.9)
    assert row["verdict"] == "PASS"
    assert row["speedup_all_median"] == pytest.approx(1.9)


def test_a_slow_code_fails_on_a_machine_that_delivers(monkeypatch):
    row = _measure(monkeypatch, [(10, 10, 10, 12.0)] * 3)
    assert row["speedup"] == pytest.approx(1.2) and row["verdict"] == "FAIL"


def test_never_two_cores_is_inconclusive_not_a_pass(monkeypatch):
    row = _measure(monkeypatch, [(10, 5, 5, 25.0)] * 5)   # even a 2.5x reading counts for nothing
    assert row["counted"] == 0 and row["speedup"] is None and row["verdict"] == "INCONCLUSIVE"
    assert len(row["windows"]) == 5


def test_the_control_threshold_is_the_documented_one(monkeypatch):
    just_below = bench.CONTROL_MIN - 1e-9
    row = _measure(monkeypatch, [(1.0, just_below / 2, just_below / 2, 2.0)] * 5)
    assert row["verdict"] == "INCONCLUSIVE"
