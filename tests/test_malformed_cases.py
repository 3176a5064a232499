"""Every file in tests/malformed/ is a case with one defect; its first line names the expected
message (`# expect: ...`). Each must be refused with that message, naming the key."""

from pathlib import Path

import pytest

from harness import cases
from harness.cases import CaseError

FILES = sorted((Path(__file__).parent / "malformed").glob("*.toml"))


def test_there_are_at_least_25_kinds_of_rejection():
    assert len(FILES) >= 25


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_malformed_case_is_refused_with_its_message(path):
    expect = path.read_text().splitlines()[0].removeprefix("# expect:").strip()
    with pytest.raises(CaseError) as ei:
        cases.load(path)
    assert expect in str(ei.value), f"message was: {ei.value}"
    assert str(path) in str(ei.value), "the message names the file"


NEW_KEYS = [p for p in FILES if int(p.stem.split("_")[0]) >= 36]   # issue 40: geometry, fill, omega, tables


def test_the_new_keys_have_their_malformed_cases():
    # polygon, disc, angle, a key of another shape, fill, subtract, omega, velocity_table
    assert len(NEW_KEYS) >= 19


def test_cli_refuses_each_new_key_with_one_line_and_status_2():
    """`python -m harness run` on each malformed case of the new keys: exit status 2, the message
    on one line of stderr, no traceback. One interpreter runs them all, each through cli.main as
    the command does (its exit status is main's return value)."""
    import json
    import subprocess
    import sys

    script = ("import json, sys, io, contextlib\nfrom harness import cli\nout = []\n"
              "for f in sys.argv[1:]:\n"
              "    err = io.StringIO()\n"
              "    with contextlib.redirect_stderr(err):\n"
              "        code = cli.main(['run', f, '--no-progress', '--out', '/nonexistent/never'])\n"
              "    out.append((code, err.getvalue()))\n"
              "print(json.dumps(out))\n")
    p = subprocess.run([sys.executable, "-c", script, *map(str, NEW_KEYS)], capture_output=True, text=True,
                       timeout=300, cwd=Path(__file__).resolve().parent.parent)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    for path, (code, err) in zip(NEW_KEYS, json.loads(p.stdout.splitlines()[-1]), strict=True):
        expect = path.read_text().splitlines()[0].removeprefix("# expect:").strip()
        assert code == 2, (path.name, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and expect in lines[0], (path.name, err)


def _outside(opt):
    """Values just outside each finite bound of an option's range, and the bounds that are allowed."""
    import math

    bad, good = [], []
    for bound, is_open, away in ((opt.lo, opt.lo_open, -math.inf), (opt.hi, opt.hi_open, math.inf)):
        if bound is None:
            continue
        beyond = math.nextafter(bound, away)
        bad.append(bound if is_open else beyond)
        if not is_open:
            good.append(bound)
    if opt.kind == "int":
        bad = [math.floor(b) if b < (opt.lo if opt.lo is not None else 0) + 0.5 else math.ceil(b) for b in bad]
        good = [int(g) for g in good]
    return bad, good


def _bounded_options():
    from harness.solver import CASE_NO, OPTIONS

    return [o for o in OPTIONS.values() if o.in_case != CASE_NO and o.ncomp == 1 and (o.lo, o.hi) != (None, None)]


@pytest.mark.parametrize("opt", _bounded_options(), ids=lambda o: o.name)
def test_every_bounded_option_is_refused_at_load_as_the_core_refuses_it(opt):
    """The case schema's range of each [solver] option and the Fortran table's check are the same
    range: just outside a bound is refused by both (at load, naming the key; by cpdi_set_option),
    a closed bound is accepted by both (issue 39 item 1)."""
    from harness.solver import CpdiError, Simulation

    path = Path(__file__).parent.parent / "cases" / "water_column.toml"
    bad, good = _outside(opt)
    assert bad, f"{opt.name}: a bounded option needs a value outside its range"
    for value in bad:
        with pytest.raises(CaseError, match=rf"solver\.{opt.name} = "):
            cases.load(path, [f"solver.{opt.name}={value!r}"])
        sim = Simulation()
        with pytest.raises(CpdiError, match=opt.name):
            sim.set_options(**{opt.name: value})
        sim.close()
    for value in good:
        if opt.name == "dt" and value == 0.0:
            continue   # dt = 0 is inside the row's range; the rule fixed dt > 0 refuses it (70_fixed_dt_zero)
        cases.load(path, [f"solver.{opt.name}={value!r}"])
