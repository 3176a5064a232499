"""Two solver processes stepped in turns: a comparison that a shared machine's slow spells cannot tip.

make bench's loaded gate compares a 2-thread run with a 1-thread run beside the same busy
processes. Run one after the other, the two met different machines in some pairs: the host has
stretches of seconds in which a process beside a busy loop runs markedly slower, and a 2-thread
run that ran the very same 1-thread steps as its partner (its team choice had settled on one
thread) read far slower (the figures: docs/notes/threads.md). Here both processes are built and warmed up first, then
step CHUNK steps each in turns (the first to go alternates), so a spell of the machine falls on
both runs alike. Only one process steps at a time; the other waits on a pipe, its threads asleep.
Each process is a fresh one, as a user's run is: the 2-thread run chooses its team and probes the
other as it would alone.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CHUNK = 10   # steps a process takes in one turn (a fraction of a second at 32k CPDI on one thread)
WARM = 10    # untimed steps of each process before the turns (first touch, team choice)


def serve(size: str, shape: str) -> None:
    """The child: build the bench's dam break, then obey stdin line by line: `warm N` and `step N`
    (advance N steps, the second timed) answer `ok`; `end` prints the totals as JSON and returns."""
    from harness import cases, runner, solver
    from harness.seeding import seed
    from tools import bench

    case = cases.from_dict(bench.dam_break_case(bench.SIZES[size], shape))
    sim, parts = runner.build(case, seed(case))
    print("ready", flush=True)
    wall, steps, chunks = 0.0, 0, []
    while True:
        cmd, _, n = sys.stdin.readline().strip().partition(" ")
        if cmd == "warm":
            sim.advance(10.0, max_steps=int(n))
        elif cmd == "step":
            t0 = time.perf_counter()
            done, _ = sim.advance(10.0, max_steps=int(n))
            chunks.append(time.perf_counter() - t0)
            wall += chunks[-1]
            steps += done
        else:
            break
        print("ok", flush=True)
    print(json.dumps({"wall_s": wall, "steps": steps, "particles": parts.n, "threads": solver.threads(),
                      "chunk_s": chunks}), flush=True)
    sim.close()


def _child(size: str, shape: str, threads: int, repo: Path) -> list[str]:
    return [sys.executable, "-c", f"from tools.bench_interleave import serve; serve({size!r}, {shape!r})"]


class _Proc:
    """One child with its pipes; its stderr goes to a temporary file (read when it fails)."""

    def __init__(self, cmd: list[str], threads: int, repo: Path):
        self.err = tempfile.TemporaryFile(mode="w+")
        env = dict(os.environ, OMP_NUM_THREADS=str(threads), PYTHONPATH=str(repo))
        self.p = subprocess.Popen(cmd, cwd=repo, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=self.err, text=True)
        self.what = f"{threads}-thread run"

    def ask(self, line: str | None, want: str | None) -> str:
        if line is not None:
            self.p.stdin.write(line + "\n")
            self.p.stdin.flush()
        got = self.p.stdout.readline().strip()
        if want is not None and got != want:
            self._fail(f"stopped answering ({got!r} instead of {want!r})")
        return got

    def result(self) -> dict:
        line = self.ask("end", None)
        try:
            return json.loads(line)
        except json.JSONDecodeError:
            self._fail(f"ended without its totals ({line!r})")

    def _fail(self, what: str) -> None:
        """Stop the child (if it still runs) and raise with what it wrote to stderr."""
        self.close(keep_err=True)
        self.err.seek(0)
        raise RuntimeError(f"benchmark {self.what} (interleaved) {what}:\n{self.err.read().strip()[-3000:]}")

    def close(self, keep_err: bool = False) -> None:
        if self.p.poll() is None:
            self.p.kill()
        self.p.wait()
        if not keep_err:
            self.err.close()


def pair(size: str, shape: str, steps: int, threads: tuple[int, int] = (1, 2), chunk: int = CHUNK,
         warm: int = WARM, repo: Path = REPO, command=_child) -> dict:
    """Run `threads[0]` and `threads[1]` threads on the same case in two fresh processes, in turns
    of `chunk` steps until each has taken `steps`; returns both timed walls, their ratio
    (second over first) and every turn's seconds."""
    procs = [_Proc(command(size, shape, t, repo), t, repo) for t in threads]
    try:
        for p in procs:
            p.ask(None, "ready")
        for p in procs:   # warm up one after the other, so neither chooses its team beside the other
            p.ask(f"warm {warm}", "ok")
        turns = (steps + chunk - 1) // chunk
        for k in range(turns):
            n = min(chunk, steps - k * chunk)
            for p in (procs if k % 2 == 0 else procs[::-1]):
                p.ask(f"step {n}", "ok")
        res = [p.result() for p in procs]
    finally:
        for p in procs:
            p.close()
    a, b = res
    return {f"wall_{threads[0]}": a["wall_s"], f"wall_{threads[1]}": b["wall_s"], "ratio": b["wall_s"] / a["wall_s"],
            "steps": [a["steps"], b["steps"]], "chunk": chunk, f"chunk_s_{threads[0]}": a["chunk_s"],
            f"chunk_s_{threads[1]}": b["chunk_s"], "runs": res}
