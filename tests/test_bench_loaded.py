"""The bench's loaded gate (2 threads beside busy processes never slower than GATE_LOAD x one
thread) compares two fresh processes that step in turns (tools.bench_interleave.pair), so that a
slow spell of a shared machine falls on both runs alike: only one steps at a time, they alternate,
the first to go alternates, both take the same steps, and a child that fails is reported with its
own error. The fake children here follow the real protocol and log when they step."""

from __future__ import annotations

import sys

import pytest

from tools import bench, bench_interleave

# A child that speaks bench_interleave's protocol: each step sleeps 2 ms; it reports the monotonic
# times at which each of its warm-ups and turns began and ended (one clock for all processes).
FAKE = r'''
import json, sys, time
print("ready", flush=True)
spans, steps = [], 0
while True:
    cmd, _, n = sys.stdin.readline().strip().partition(" ")
    if cmd not in ("warm", "step"):
        break
    t0 = time.monotonic()
    time.sleep(0.002 * int(n))
    spans.append([cmd, t0, time.monotonic()])
    steps += int(n) if cmd == "step" else 0
    print("ok", flush=True)
print(json.dumps({"wall_s": 0.002 * steps * THREADS, "steps": steps, "chunk_s": [], "spans": spans}), flush=True)
'''


def _fake(size, shape, threads, repo):
    return [sys.executable, "-c", FAKE.replace("THREADS", str(threads))]


def _broken(size, shape, threads, repo):
    if threads == 2:
        return [sys.executable, "-c", "import sys; print('ready', flush=True); sys.stdin.readline(); "
                                      "sys.exit('error: the solver refused the case (particles left the grid)')"]
    return _fake(size, shape, threads, repo)


def test_the_runs_step_in_turns_never_at_once():
    p = bench_interleave.pair("32k", "cpdi", 25, chunk=5, warm=3, command=_fake)
    one, two = (r["spans"] for r in p["runs"])
    assert p["steps"] == [25, 25]
    events = sorted([(a, b, "1", c) for c, a, b in one] + [(a, b, "2", c) for c, a, b in two])
    for (_, b0, *_), (a1, *_) in zip(events, events[1:], strict=False):
        assert b0 <= a1   # one process at a time
    order = [who for *_, who, cmd in events if cmd == "step"]
    # warm-ups first, one after the other; then turns, the first to go alternating
    assert [(who, cmd) for *_, who, cmd in events[:2]] == [("1", "warm"), ("2", "warm")]
    assert order == ["1", "2", "2", "1", "1", "2", "2", "1", "1", "2"]


def test_the_ratio_is_the_second_run_over_the_first():
    p = bench_interleave.pair("32k", "cpdi", 10, chunk=5, warm=1, command=_fake)
    assert p["wall_2"] == pytest.approx(2 * p["wall_1"]) and p["ratio"] == pytest.approx(2.0)


def test_a_failing_child_is_reported_with_its_own_error():
    with pytest.raises(RuntimeError, match="(?s)2-thread run.*particles left the grid"):
        bench_interleave.pair("32k", "cpdi", 10, chunk=5, warm=1, command=_broken)


def _confused(size, shape, threads, repo):
    # answers nonsense and then hangs: it must be stopped, not waited for
    return [sys.executable, "-c", "import sys, time; print('ready', flush=True); sys.stdin.readline(); "
                                  "print('what?', flush=True); time.sleep(600)"]


def test_a_child_that_answers_wrong_is_stopped_and_reported():
    import time
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="1-thread run.*'what\\?' instead of 'ok'"):
        bench_interleave.pair("32k", "cpdi", 10, chunk=5, warm=1, command=_confused)
    assert time.monotonic() - t0 < 20


def test_the_real_children_run_the_bench_case():
    p = bench_interleave.pair("2k", "cpdi", 6, chunk=3, warm=2)
    assert p["steps"] == [6, 6] and p["wall_1"] > 0 and p["wall_2"] > 0
    assert len(p["chunk_s_1"]) == len(p["chunk_s_2"]) == 2
    assert [r["threads"] for r in p["runs"]] == [1, 2]


def _loaded(monkeypatch, ratios):
    it = iter(ratios)

    def pair(size, shape, steps):
        r = next(it)
        return {"wall_1": 1.0, "wall_2": r, "ratio": r, "chunk": 10, "chunk_s_1": [], "chunk_s_2": []}

    monkeypatch.setattr(bench_interleave, "pair", pair)
    monkeypatch.setattr(bench, "_busy", lambda n: [])
    monkeypatch.setattr(bench, "_stop", lambda hogs: None)
    return bench.loaded_rows(3, lambda msg: None)


def test_the_worst_pair_is_gated_at_the_documented_bounds(monkeypatch):
    rows = _loaded(monkeypatch, [1.0, bench.GATE_LOAD[1], 1.1, 1.0, bench.GATE_LOAD[2] + 1e-9, 1.0])
    assert [r["worst_ratio_2_over_1"] for r in rows] == [bench.GATE_LOAD[1], pytest.approx(bench.GATE_LOAD[2])]
    assert [r["pass"] for r in rows] == [True, False]
    assert [r["busy_processes"] for r in rows] == [1, 2] and rows[0]["median_ratio_2_over_1"] == pytest.approx(1.1)
