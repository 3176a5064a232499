"""Command line: ``cpdi`` (installed by pip) or ``python -m harness``: run, verify, report, sweep, gate.

The developer tools have their own entry points in a checkout: ``python -m tools.bench`` (make bench)
and ``python -m tools.mutation`` (make mutate).

Errors print one line naming the problem and the fix, and exit non-zero:
1 = a run or check failed, 2 = bad input (case file, arguments, checkpoint), 130 = interrupted
(``run``: 128 + the signal, i.e. 130 for SIGINT and 143 for SIGTERM, after a clean stop).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path

from harness import paths
from harness.cases import CaseError
from harness.parallel import SchedulerUnreachable


def _err(msg: str) -> None:
    print(f"error: {msg}", file=sys.stderr)


def cmd_run(args) -> int:
    from harness import cases, runner
    from harness.checkpoint import CheckpointError, locate

    case = cases.load(args.case, args.set)
    every = args.checkpoint_every
    if every is not None and not (math.isfinite(every) and every > 0):
        _err(f"--checkpoint-every {every} must be a positive number of simulated seconds")
        return 2
    if args.out:
        out = Path(args.out)
    else:
        out = locate(args.restart).parent if args.restart else paths.work_root() / "runs" / case.name
    try:
        with runner.StopOnSignal() as stop:
            res = runner.run(case, out, progress=not args.no_progress, checkpoint_every=every,
                             restart=args.restart, stop=stop)
    except CheckpointError as exc:
        _err(str(exc))
        return 2
    except runner.RunFailed as exc:
        _err(f"{exc}\n       partial outputs kept in {out}/ (summary.json has status 'failed')")
        return 1
    except runner.RunInterrupted as exc:
        again = shlex.join(["python", "-m", "harness", "run", args.case,
                            *(a for kv in args.set for a in ("--set", kv)), "--restart", str(out)])
        print(f"{exc}\n  partial outputs kept in {out}/ (summary.json has status 'interrupted'), "
              f"checkpoint {exc.summary['checkpoint']['path']}\n  resume with: {again}", file=sys.stderr)
        return exc.exit_code
    s = res.summary
    print(f"{case.name}: completed t = {s['simulated_time']:.4g} s in {s['steps']} steps, "
          f"{s['wall_s']:.2f} s wall, {s['particles']} particles, "
          f"{s['particle_updates_per_s'] / 1e6:.2f} M particle-updates/s -> {out}/")
    return 0


def _cluster_args(args) -> bool:
    """--jobs and --scheduler: True if they are usable, else one error line."""
    if args.jobs is not None and args.jobs < 1:
        _err(f"--jobs {args.jobs}: give at least 1 (1 runs everything in this process, no cluster)")
        return False
    if args.jobs is not None and args.scheduler:
        _err("--jobs and --scheduler exclude each other: an existing cluster has its own workers")
        return False
    return True


def cmd_verify(args) -> int:
    from harness import verify

    if not _cluster_args(args):
        return 2
    return verify.main(quick=args.quick, only=args.only, out=Path(args.out) if args.out else None,
                       progress=not args.no_progress, regen_gold=args.regen_gold, jobs=args.jobs,
                       scheduler=args.scheduler)


def cmd_report(args) -> int:
    from harness import report

    d = Path(args.dir)
    if not (d / "results.json").is_file():
        _err(f"{d} holds no results.json; give a directory written by `python -m harness verify`")
        return 2
    report.rerender(d)
    print(f"re-rendered {d}/index.html and {d}/report.md")
    return 0


def cmd_gate(args) -> int:
    import json

    from harness import gate

    path = Path(args.metrics)
    if not path.is_file():
        _err(f"{path} does not exist; give a metrics.json written by `python -m harness verify`")
        return 2
    metrics = json.loads(path.read_text())
    tier = "quick" if metrics.get("quick") else "full"
    rows = gate.compare(metrics, gate.load_gold(), tier)
    if not rows:
        _err(f"no gold baseline for the {tier} tier in reference/gold/metrics.json; run make regen-gold")
        return 2
    for line in gate.summary_lines(rows):
        print(line)
    bad = [r for r in rows if r["status"] == "regressed"]
    print(f"gate ({tier}): {len(rows)} metrics, {len(bad)} regressed")
    return 1 if bad else 0


def cmd_sweep(args) -> int:
    from harness import sweep

    if not Path(args.case).is_file():
        _err(f"case file {args.case} does not exist")
        return 2
    if not _cluster_args(args):
        return 2
    out = Path(args.out) if args.out else paths.work_root() / "runs" / "sweep" / Path(args.case).stem
    return sweep.main(args.case, args.set, out, metric=args.metric, progress=not args.no_progress,
                      jobs=args.jobs, scheduler=args.scheduler)


def _add_cluster_args(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--jobs", type=int, metavar="N",
                   help=f"run {what} on a local Dask cluster of N single-threaded worker processes (default: the "
                        "cores this process may use); --jobs 1 runs them one after another in this process")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help=f"send {what} to the existing Dask cluster whose scheduler is at ADDRESS (e.g. "
                        "tcp://login1:8786, a dask-jobqueue SLURMCluster: see docs/running.md); its workers "
                        "must import this harness and share this file system")


def parser() -> argparse.ArgumentParser:
    prog = "cpdi" if Path(sys.argv[0]).name == "cpdi" else "python -m harness"
    p = argparse.ArgumentParser(prog=prog, description="cpdi-verify harness")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run one case")
    r.add_argument("case", help="case file (TOML)")
    r.add_argument("--out", help="output directory (default runs/<case name>)")
    r.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a case value, e.g. --set solver.cfl=0.2 (repeatable)")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.add_argument("--checkpoint-every", type=float, metavar="T",
                   help="write OUT/checkpoint.h5 (atomically) at the first step at or after every T simulated "
                        "seconds; SIGINT/SIGTERM always stop cleanly and write one")
    r.add_argument("--restart", metavar="DIR",
                   help="continue bit for bit from DIR/checkpoint.h5 (same case and --set overrides); "
                        "outputs go to DIR unless --out is given")
    r.set_defaults(func=cmd_run)
    v = sub.add_parser("verify", help="run the verification checks and write a report")
    v.add_argument("--quick", action="store_true", help="CI resolution")
    v.add_argument("--only", nargs="+", action="extend", metavar="NAME",
                   help="run only these checks (the flag may be repeated)")
    v.add_argument("--out", help="report directory (default reports/<UTC stamp>)")
    v.add_argument("--no-progress", action="store_true")
    v.add_argument("--regen-gold", action="store_true",
                   help="run the full and quick tiers and rewrite reference/gold/metrics.json (never in CI)")
    _add_cluster_args(v, "the checks' independent runs")
    v.set_defaults(func=cmd_verify)
    rep = sub.add_parser("report", help="re-render a report from stored data")
    rep.add_argument("dir", help="report directory")
    rep.set_defaults(func=cmd_report)
    gt = sub.add_parser("gate", help="compare a metrics.json with the gold baselines")
    gt.add_argument("metrics", help="metrics.json of a verify run")
    gt.set_defaults(func=cmd_gate)
    sw = sub.add_parser("sweep", help="parameter study: run the cartesian product of case overrides",
                        description="Run CASE once per combination of the --set values (side by side on a Dask "
                                    "cluster: --jobs, --scheduler) and write one table (sweep.csv, sweep.md) and "
                                    "one plot of --metric (sweep.png) in OUT.")
    sw.add_argument("case", help="case file (TOML)")
    sw.add_argument("--set", action="append", default=[], required=True, metavar="SECTION.KEY=V1,V2,...",
                    help="values of one case key, comma-separated, e.g. --set solver.cfl=0.3,0.5 (repeatable; "
                         "the runs are the cartesian product)")
    sw.add_argument("--metric", default="wall_s",
                    help="the table column to plot (default wall_s; e.g. steps, final.front_x)")
    sw.add_argument("--out", help="output directory (default runs/sweep/<case file stem>)")
    sw.add_argument("--no-progress", action="store_true", help="no progress bars")
    _add_cluster_args(sw, "the runs")
    sw.set_defaults(func=cmd_sweep)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except (CaseError, SchedulerUnreachable) as exc:
        _err(str(exc))
        return 2
    except KeyboardInterrupt:
        _err("interrupted")
        return 130
    except ImportError as exc:
        _err(str(exc))
        return 2
