"""The bench's loaded gate (2 threads beside busy processes never slower than GATE_LOAD x one
thread) compares the two runs of a pair only where the machine held still: a 1-thread busy loop
beside the same load, timed before, between and after the runs, agreed within LOAD_SPREAD
(harness.bench.loaded_rows; solver runs, busy processes and loops are stubbed)."""

from __future__ import annotations

import itertools

import pytest

from harness import bench


class _Fake:
    """Per pair: (control, first run's wall, control, second run's wall, control); the runs are in
    the pair's order (1 then 2 threads for even pairs, 2 then 1 for odd ones)."""

    def __init__(self, pairs):
        self.values = itertools.chain.from_iterable(pairs)
        self.log = []

    def loop(self):
        self.log.append("control")
        return next(self.values)

    def run_one(self, size, shape, threads, repo=None, steps=None):
        self.log.append(f"run {threads}")
        return {"wall_s": next(self.values)}

    def busy(self, n):
        self.log.append(f"busy {n}")
        return []


def _rows(monkeypatch, pairs, repeats=2, most=4):
    f = _Fake(pairs)
    monkeypatch.setattr(bench, "_loop_time", f.loop)
    monkeypatch.setattr(bench, "_run_one", f.run_one)
    monkeypatch.setattr(bench, "_busy", f.busy)
    monkeypatch.setattr(bench, "_stop", lambda hogs: None)
    return bench.loaded_rows(repeats, lambda msg: None, most=most), f.log


STILL = (0.2, 0.6, 0.2, 0.66, 0.2)   # the machine held still; 2T/1T 1.1 in an even pair (1 thread first)


def test_controls_bracket_each_run_and_the_order_alternates(monkeypatch):
    _, log = _rows(monkeypatch, [STILL] * 4)
    pair = ["control", "run {}", "control", "run {}", "control"]
    one = ["busy 1"] + [x.format(1) if i == 1 else x.format(2) if i == 3 else x for i, x in enumerate(pair)]
    two = ["busy 1"] + [x.format(2) if i == 1 else x.format(1) if i == 3 else x for i, x in enumerate(pair)]
    assert log[:12] == one + two


def test_a_pair_across_a_change_of_the_machine_is_kept_but_not_gated(monkeypatch):
    # first pair: the host slowed everything 1.5x after the 1-thread run (controls 0.2 -> 0.3):
    # its 1.5 ratio is the host's; the next two pairs held still
    moved = (0.2, 0.6, 0.3, 0.9, 0.3)
    rows, _ = _rows(monkeypatch, [moved, (0.2, 0.66, 0.2, 0.6, 0.2), STILL] * 2)
    one = rows[0]
    assert [p["counted"] for p in one["pairs"]] == [False, True, True]
    assert one["pairs"][0]["ratio"] == pytest.approx(1.5) and one["worst_ratio_all_pairs"] == pytest.approx(1.5)
    assert one["worst_ratio_2_over_1"] == pytest.approx(1.1) and one["verdict"] == "PASS"


def test_a_slow_second_thread_fails_when_the_machine_held_still(monkeypatch):
    rows, _ = _rows(monkeypatch, [(0.2, 0.6, 0.2, 0.9, 0.2), STILL] * 2)
    assert rows[0]["worst_ratio_2_over_1"] == pytest.approx(1.5) and rows[0]["verdict"] == "FAIL"
    assert not rows[0]["pass"]


def test_a_machine_that_never_holds_still_is_inconclusive(monkeypatch):
    moved = (0.2, 0.6, 0.3, 0.6, 0.2)
    rows, _ = _rows(monkeypatch, [moved] * 8, repeats=2, most=4)
    assert [r["verdict"] for r in rows] == ["INCONCLUSIVE", "INCONCLUSIVE"]
    assert rows[0]["worst_ratio_2_over_1"] is None and len(rows[0]["pairs"]) == 4 and not rows[0]["pass"]


def test_the_spread_threshold_is_the_documented_one(monkeypatch):
    at = 0.2 * bench.LOAD_SPREAD
    rows, _ = _rows(monkeypatch, [(0.2, 0.6, at * (1 + 1e-9), 0.6, 0.2), (0.2, 0.6, at, 0.6, 0.2),
                                  (0.2, 0.6, 0.2, 0.6, 0.2)] * 2, repeats=2, most=3)
    assert [p["counted"] for p in rows[0]["pairs"]] == [False, True, True]


def test_the_real_loop_control_runs(monkeypatch):
    monkeypatch.setattr(bench, "CONTROL_LOOP", 20_000)
    assert 0.0 < bench._loop_time() < 5.0
