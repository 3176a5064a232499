"""``python -m tools.mutation`` (make mutate): the command line of the mutation tool."""

from __future__ import annotations

import argparse
import sys

from tools.mutation.main import main


def parser() -> argparse.ArgumentParser:
    mu = argparse.ArgumentParser(prog="python -m tools.mutation",
                                 description="mutation testing of the Fortran core (make mutate)")
    mu.add_argument("--sample", type=int, default=220, help="about this many mutants, stratified over the files")
    mu.add_argument("--jobs", type=int, help="parallel scratch builds (default: the cores this process may use)")
    mu.add_argument("--seed", type=int, default=20, help="sampling seed (same commit + seed = same mutants)")
    mu.add_argument("--fast-only", action="store_true", help="no full make test for the fast tier's survivors")
    mu.add_argument("--resume", metavar="DIR", help="continue an interrupted run in its report directory")
    mu.add_argument("--only", nargs="+", metavar="FILE", help="mutate only these files (fortran/src/x.f90)")
    mu.add_argument("--ids", nargs="+", metavar="ID",
                    help="run exactly these mutants (ids as in a report's mutants.json, e.g. cpdi_fsi:126:3d364ae9); "
                         "with --only FILE, only those files are scanned; the report goes to <date>-<sha>-ids/. "
                         "With --resume DIR: only these of DIR's sample run (say, one survivor through --verify), "
                         "and DIR's report still covers the whole sample")
    mu.add_argument("--report-only", action="store_true", help="with --resume: summarise the journal, run nothing")
    mu.add_argument("--fast-timeout", type=float, default=120.0, metavar="S",
                    help="time limit per mutant for the fast tier, at least 3x the unmutated tree's (a hang counts "
                         "as killed, and the report says so)")
    mu.add_argument("--full-timeout", type=float, default=1200.0, metavar="S",
                    help="time limit per mutant for the full make test (raise it on a loaded machine: a slow run "
                         "must not count as a hang)")
    mu.add_argument("--verify", action="store_true",
                    help="also run make verify (a whole verify each: long) on every survivor of make test, "
                         "those in a resumed journal included: the kill rate with make verify")
    mu.add_argument("--verify-timeout", type=float, default=7200.0, metavar="S",
                    help="time limit per mutant for make verify")
    return mu


def cmd_mutate(args) -> int:
    return main(sample=args.sample, jobs=args.jobs, seed=args.seed, full=not args.fast_only,
                         resume=args.resume, only=args.only, report_only=args.report_only,
                         ids=args.ids, fast_timeout=args.fast_timeout, full_timeout=args.full_timeout,
                         verify_timeout=args.verify_timeout if args.verify else None)


if __name__ == "__main__":
    sys.exit(cmd_mutate(parser().parse_args()))
