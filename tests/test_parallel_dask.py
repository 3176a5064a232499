"""harness.parallel on Dask (issue 23, item 5): quick-tier checks on 2 local Dask workers give the
same bits as the serial run; a worker killed during a run has its task re-run, and the verify
report is complete and says so; verify and ``cpdi sweep`` run on an existing cluster given by
``--scheduler ADDRESS``; ``--jobs 1`` starts no cluster."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness import cli, parallel, report, verify
from harness.checks.base import CheckResult, Gate

REPO = Path(__file__).resolve().parent.parent
CASE = str(REPO / "cases" / "water_column.toml")
TINY = ["--set", "solver.t_end=0.02", "--set", "solver.output_every=0.01"]
# the checks whose runs go through pmap, at their cheapest: convergence's 27 small runs and
# elastic_obstacle's two (their snapshots, written by the workers, are read back for figures)
CHECKS = ["convergence", "elastic_obstacle"]
TIMING = ("wall_s", "particle_updates_per_s")  # summary columns that are clock readings


def _same(a: dict, b: dict) -> list[str]:
    """Keys whose values differ in any bit (nan equals nan)."""
    assert a.keys() == b.keys()
    return [k for k in a if json.dumps(a[k]) != json.dumps(b[k])]


@pytest.fixture(scope="module")
def serial_quick(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("serial")
    metrics, _ = verify.verify(True, CHECKS, out, progress=False, jobs=1)
    return metrics


@pytest.fixture(scope="module")
def external_cluster():
    """A cluster started apart from the harness, as a user would (here on this machine)."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=40) as lc:
        yield lc.scheduler_address


def test_serial_run_starts_no_cluster(serial_quick) -> None:
    assert serial_quick["execution"]["mode"] == "serial" and serial_quick["execution"]["scheduler"] is None
    code = ("import sys; from harness import parallel\n"
            "with parallel.cluster(jobs=1) as c:\n"
            "    assert c.serial and parallel.pmap(divmod, [(7, 2), (9, 4)]) == [(3, 1), (2, 1)]\n"
            "assert parallel.pmap(divmod, [(5, 3)]) == [(1, 2)]  # one item: no cluster either\n"
            "assert 'distributed' not in sys.modules, 'the serial path imported distributed'\n")
    subprocess.run([sys.executable, "-c", code], cwd=REPO, check=True)


def test_quick_checks_on_two_dask_workers_match_serial_bit_for_bit(serial_quick, tmp_path) -> None:
    metrics, _ = verify.verify(True, CHECKS, tmp_path, progress=False, jobs=2)
    ex = metrics["execution"]
    # 27 convergence levels + elastic_obstacle's 3 runs (one continuum, contact, incompressible water)
    assert ex["mode"] == "local" and ex["workers"] == 2 and ex["tasks"] == serial_quick["execution"]["tasks"] == 30
    assert ex["tasks_rerun"] == 0 and ex["reruns_uncounted"] == 0
    for check in CHECKS:
        dask_run, serial = metrics["checks"][check], serial_quick["checks"][check]
        assert dask_run["passed"], dask_run["verdict"]
        assert not _same(dask_run["metrics"], serial["metrics"]), f"{check}: metrics differ from the serial run"
        assert dask_run["gates"] == serial["gates"]


# ------------------------------------------------------------------ a worker killed during a run


def _run_then_kill_worker_once(case: str, out: str, marker: str):
    """A real (tiny) run; on the first attempt at the marked item its worker is killed at the end
    of the run, before the result is sent back."""
    from harness import cases, runner

    r = runner.run(cases.load(case, TINY[1::2]), Path(out), progress=False)
    if marker and not Path(marker).exists():
        Path(marker).write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return float(r.series["front_x"][-1]), os.getpid()


NAME = "killed_worker"
REQUIREMENT = "Four tiny runs on the cluster all come back although a worker is killed during one of them."


def run(ctx) -> CheckResult:
    """A verify check (harness.checks protocol) whose second run kills its worker once."""
    marker = ctx.runs_dir / "killed"
    outs = parallel.pmap(_run_then_kill_worker_once, [(CASE, str(ctx.runs_dir / f"r{i}"), str(marker) if i == 1
                                                       else "") for i in range(4)])
    res = CheckResult(NAME, REQUIREMENT)
    for i, out in enumerate(outs):
        assert not isinstance(out, Exception), out
        res.metrics[f"front_x_{i}"] = out[0]
    res.metrics["killed_pid"] = float(marker.read_text())
    res.metrics["rerun_pid"] = float(outs[1][1])
    res.gates.append(Gate.at_most("runs_returned", len(outs), 4))
    return res


def test_worker_killed_during_a_run_is_rerun_and_reported(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, f"harness.checks.{NAME}", sys.modules[__name__])
    monkeypatch.setattr("harness.paths.work_root", lambda: tmp_path)
    t0 = time.perf_counter()
    metrics, _ = verify.verify(True, [NAME], tmp_path / "report", progress=False, jobs=2)
    assert time.perf_counter() - t0 < 60
    check = metrics["checks"][NAME]
    assert check["passed"], check["verdict"]
    m = check["metrics"]
    assert m["rerun_pid"] != m["killed_pid"], "the killed worker's result cannot have come back"
    assert len({m[f"front_x_{i}"] for i in range(4)}) == 1, "the re-run gives the same result as the others"
    ex = metrics["execution"]
    assert ex["tasks"] == 4 and ex["tasks_rerun"] == 1
    assert ex["reruns"] == [{"task": "_run_then_kill_worker_once[1]", "runs": 2, "index": 1, "context": NAME}]
    report_md = (tmp_path / "report" / "report.md").read_text()
    assert ("**1 task re-run after its worker was lost (killed_worker: `_run_then_kill_worker_once[1]` (ran 2 "
            "times))**; the results are complete") in report_md
    assert "**Re-run:** 1 task re-run after its worker was lost (`_run_then_kill_worker_once[1]` (ran 2" in report_md
    stored = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert stored["execution"] == ex
    report.rerender(tmp_path / "report")  # from results.json alone
    assert (tmp_path / "report" / "report.md").read_text() == report_md
    assert json.loads((tmp_path / "report" / "metrics.json").read_text()) == stored


# ------------------------------------------------------------------ --scheduler ADDRESS


def test_verify_on_an_existing_cluster_by_address(external_cluster, serial_quick, tmp_path, capsys) -> None:
    out = tmp_path / "report"
    code = cli.main(["verify", "--quick", "--only", "convergence", "--no-progress", "--out", str(out),
                     "--scheduler", external_cluster])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert f"the Dask scheduler at {external_cluster} (2 workers)" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["execution"]["mode"] == "scheduler" and metrics["execution"]["tasks"] == 27
    assert not _same(metrics["checks"]["convergence"]["metrics"], serial_quick["checks"]["convergence"]["metrics"])


def test_sweep_on_an_existing_cluster_by_address(external_cluster, tmp_path, capsys) -> None:
    tables = {}
    for how in (["--scheduler", external_cluster], ["--jobs", "1"]):
        out = tmp_path / how[0].strip("-")
        code = cli.main(["sweep", CASE, "--set", "grid.cell=0.0146,0.0073", "--set", "solver.cfl=0.3,0.5", *TINY,
                         "--metric", "final.front_x", "--out", str(out), "--no-progress", *how])
        assert code == 0, capsys.readouterr()
        tables[how[0]] = [{k: v for k, v in r.items() if k not in TIMING}
                          for r in csv.DictReader(open(out / "sweep.csv"))]
    assert f"the Dask scheduler at {external_cluster}" in capsys.readouterr().out
    assert len(tables["--scheduler"]) == 4 and all(r["status"] == "completed" for r in tables["--scheduler"])
    assert tables["--scheduler"] == tables["--jobs"], "the cluster's runs are the serial runs, bit for bit"


def test_unreachable_scheduler_is_one_line_and_exit_2(monkeypatch, capsys, tmp_path) -> None:
    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT", "1s")
    assert cli.main(["sweep", CASE, "--set", "solver.cfl=0.3,0.5", *TINY, "--out", str(tmp_path / "s"),
                     "--scheduler", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --scheduler tcp://127.0.0.1:9: no Dask scheduler answers there")


@pytest.mark.parametrize("argv, message", [
    (["--jobs", "0"], "--jobs 0: give at least 1"),
    (["--jobs", "2", "--scheduler", "tcp://127.0.0.1:8786"], "exclude each other"),
])
def test_bad_cluster_arguments_exit_2(argv, message, capsys, tmp_path) -> None:
    for sub in (["verify", "--quick", "--out", str(tmp_path / "v")],
                ["sweep", CASE, "--set", "solver.cfl=0.3,0.5", "--out", str(tmp_path / "s")]):
        assert cli.main([*sub, *argv]) == 2
        assert message in capsys.readouterr().err
    assert not any(tmp_path.iterdir()), "nothing ran"


def test_workers_run_one_solver_thread_and_results_keep_input_order() -> None:
    with parallel.cluster(jobs=2) as c:
        assert c.mode == "local" and c.workers == 2
        outs = parallel.pmap(_threads_after, [(0.4,), (0.0,), (0.2,), ("not a number",)])
    assert [o[0] for o in outs[:3]] == [0.4, 0.0, 0.2]
    assert all(o[1:] == (1, "1") for o in outs[:3]), "each worker runs the solver on one thread"
    assert isinstance(outs[3], TypeError), "an exception inside a task is its value"


def _threads_after(delay):
    from harness import solver

    time.sleep(delay)
    return delay, solver.threads(), os.environ.get("OMP_NUM_THREADS")


# ------------------------------------------------------------------ submit: a long run started early


def _stamped(delay, marker=None):
    t0 = time.time()
    if marker:
        Path(marker).write_text("started")
    time.sleep(delay)
    return os.getpid(), t0, time.time()


def test_submitted_task_runs_beside_the_maps_that_follow_it(tmp_path) -> None:
    """verify starts a check's longest run before the first check (start_early): on two workers it
    must occupy one of them while later maps run on the other, and come back by result()."""
    marker = tmp_path / "started"
    with parallel.cluster(jobs=2) as c:
        early = parallel.submit(_stamped, (3.0, str(marker)))
        deadline = time.time() + 60
        while not marker.exists() and time.time() < deadline:
            time.sleep(0.05)
        outs = parallel.pmap(_stamped, [(0.1,), (0.1,), (0.1,)])
        pid, t0, t1 = early.result()
        failed = parallel.submit(_stamped, ("not a number",)).result()
        assert c.tasks == 5 and not c.reruns
    assert all(o[0] != pid for o in outs), "the maps ran on the other worker"
    assert all(t0 < o[1] and o[2] < t1 for o in outs), "the maps ran while the early task was running"
    assert isinstance(failed, TypeError), "an exception inside the task is its value, as in pmap"


def test_submit_outside_a_cluster_runs_when_asked() -> None:
    p = parallel.submit(_stamped, (0.0,))
    before = time.time()
    assert p.result()[1] >= before, "serially, the task runs at result()"


EARLY_NAME = "early_probe"
_order: list[str] = []


class _EarlyCheck:
    """A check module whose run comes from its start_early."""

    REQUIREMENT = "a check that takes its run from start_early"

    @staticmethod
    def start_early(ctx) -> None:
        _order.append("start_early")
        ctx.early["run"] = parallel.submit(_stamped, (0.0,))

    @staticmethod
    def run(ctx) -> CheckResult:
        _order.append("run")
        res = CheckResult(EARLY_NAME, _EarlyCheck.REQUIREMENT)
        res.metrics["early_pid"] = float(ctx.early["run"].result()[0])
        res.gates.append(Gate.at_most("zero", 0.0, 0.0))
        return res


def test_verify_starts_every_early_run_before_the_first_check(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, f"harness.checks.{EARLY_NAME}", _EarlyCheck)
    monkeypatch.setitem(sys.modules, f"harness.checks.{NAME}_first", _FirstCheck)
    monkeypatch.setattr("harness.paths.work_root", lambda: tmp_path)
    _order.clear()
    metrics, _ = verify.verify(True, [f"{NAME}_first", EARLY_NAME], tmp_path / "report", progress=False, jobs=1)
    assert _order == ["start_early", "first", "run"]
    assert metrics["checks"][EARLY_NAME]["passed"]


class _FirstCheck:
    """A check module without start_early, run before early_probe."""

    REQUIREMENT = "runs first"

    @staticmethod
    def run(ctx) -> CheckResult:
        _order.append("first")
        res = CheckResult(f"{NAME}_first", "runs first")
        res.gates.append(Gate.at_most("zero", 0.0, 0.0))
        return res
