"""Checkpoint and restart (issue 8, part 3): the full state round-trips bit for bit, a
restarted run equals an uninterrupted one bit for bit, SIGINT/SIGTERM stop a run cleanly
with a resumable checkpoint, and a missing, damaged or foreign checkpoint is refused with
one clear line."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from harness import checkpoint, cli, runner
from harness.cases import load
from harness.output import read_series
from harness.solver import FULL_STATE_ROWS, FULL_STATE_SCALARS, CpdiError
from tests.conftest import named

REPO = Path(__file__).resolve().parent.parent
WATER = REPO / "cases" / "water_column.toml"
OBSTACLE = REPO / "cases" / "elastic_obstacle.toml"
SINKING = REPO / "cases" / "sinking_block.toml"
RIGID_BODY = ["materials.1.model=rigid_body", "solver.t_end=2.0"]   # the block as a free rigid body
SMALL = ["grid.cell=0.0146", "solver.t_end=0.1"]  # 800 particles (incompressible water: ~30 steps)
# the case's weakly compressible comparison (explicit: ~800 steps for SMALL)
WEAKLY = ['solver.fluid="weakly_compressible"', 'solver.transfer="flip"']
# long enough (several thousand explicit steps) to be signalled mid-way from a test
SLOW = ["grid.cell=0.0146", "solver.cfl=0.1", "solver.t_end=0.15", *WEAKLY]
TINY = ["grid.cell=0.0146", "solver.t_end=0.02", "solver.output_every=0.01"]
# summary entries that depend on the wall clock or on where the outputs live
WALL = {"wall_s", "particle_updates_per_s", "timers", "checkpoint", "restarted_from"}



def assert_same_bits(a, b, what=""):
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(np.asarray(a[k]), np.asarray(b[k]), equal_nan=True), f"{what}{k} differs"


def datasets(group, prefix="") -> dict:
    """Every dataset below an HDF5 group (sub-groups such as a snapshot's pressure grid included)."""
    out = {}
    for k, item in group.items():
        if isinstance(item, h5py.Group):
            out.update(datasets(item, f"{prefix}{k}/"))
        else:
            out[prefix + k] = item[()]
    return out


def assert_same_run(ref: Path, other: Path):
    """Two run directories hold bit-identical results."""
    assert (ref / "series.csv").read_text() == (other / "series.csv").read_text()
    s_ref, s_other = (json.loads((d / "summary.json").read_text()) for d in (ref, other))
    assert {k: v for k, v in s_ref.items() if k not in WALL} == {k: v for k, v in s_other.items() if k not in WALL}
    with h5py.File(ref / "snapshots.h5") as fa, h5py.File(other / "snapshots.h5") as fb:
        assert sorted(fa["snapshots"]) == sorted(fb["snapshots"])
        for g in fa["snapshots"]:
            ga, gb = fa["snapshots"][g], fb["snapshots"][g]
            assert ga.attrs["time"] == gb.attrs["time"]
            assert_same_bits(datasets(ga), datasets(gb), f"snapshot {g}: ")
    assert (ref / "snapshots.xdmf").read_text() == (other / "snapshots.xdmf").read_text()


# ---------------------------------------------------------------- the API
@pytest.mark.parametrize("path, sets, t1, t2", [
    (WATER, SMALL, 0.03, 0.06),
    (WATER, SMALL + WEAKLY, 0.03, 0.06),
    # frictional contact of water with an elastic plate on a rigid anchor (moved close to the
    # column so they touch before t1), nodal projection
    (OBSTACLE, ["grid.cell=0.0146", "contact.enabled=true", "contact.friction=0.3", 'solver.projection="nodal"',
                "bodies.1.geometry.min=[0.16, 0.004]", "bodies.1.geometry.max=[0.172, 0.08]",
                "bodies.2.geometry.min=[0.16, 0.0]", "bodies.2.geometry.max=[0.172, 0.004]"], 0.045, 0.07),
    # a free rigid body sinking through the water, and resting on the floor (the walls hold it in the
    # pressure solve, decided from the water's force of the step before: p%aw, full state rows 26-27)
    (SINKING, RIGID_BODY, 0.4, 0.5),
    (SINKING, RIGID_BODY, 1.7, 1.8),
    # the Hencky block subcycled inside the water's step (solid_substeps): the substeps'
    # simulation is rebuilt from the full state
    (SINKING, ['solver.solid_substeps="explicit"'], 0.4, 0.5),
    # ... and with its volumetric stress in the projection (the substeps' pressure path is rebuilt
    # from the stress and the step's own projection)
    (SINKING, ['solver.solid_substeps="implicit"'], 0.4, 0.5),
    # the elastic plate clamped by its prescribed rigid anchor, both in the substeps' simulation
    # (the substeps move the anchor's particles), struck by the incompressible water
    (OBSTACLE, ["grid.cell=0.008", 'solver.fluid="incompressible"', 'solver.projection="none"',
                'solver.solid_substeps="implicit"'], 0.15, 0.2),
])
def test_full_state_restores_bit_for_bit(path, sets, t1, t2):
    case = load(path, sets)
    a, _ = runner.build(case)
    a.advance(t1)
    if case["contact"]["enabled"]:
        assert a.diagnostics()["friction_work"] > 0, "the bodies should be in frictional contact at the restart"
    full = a.get_full_state()
    b, _ = runner.build(case)
    b.set_full_state(full["particles"], full["scalars"])
    assert_same_bits(named(b.get_full_state()), named(full), "round trip: ")
    a.advance(t2)
    b.advance(t2)
    end_a, end_b = named(a.get_full_state()), named(b.get_full_state())
    assert end_a["t"] == pytest.approx(t2, rel=1e-12) and end_a["steps"] > full["scalars"][1]
    assert_same_bits(end_b, end_a, "after restart: ")
    assert_same_bits(b.diagnostics(), a.diagnostics())
    a.close()
    b.close()


@pytest.mark.parametrize("field, sets", [("sigma", WEAKLY), ("smax", WEAKLY), ("L", [])])
def test_the_comparison_sees_one_ulp_of_restored_state(field, sets):
    """The bitwise comparisons above can fail: one ulp more in the restored stress (sxx of
    every particle), or a few ulps more in the signal speed, changes the continued explicit
    run; one ulp more in the affine matrix (L11 of every particle) changes the continued
    incompressible (APIC) run, whose stress is an output only and whose steps land on the
    target time in equal parts. (The explicit step is cfl h / smax rounded: one ulp of smax is
    absorbed by that rounding for some states, so the signal speed is moved by 8 ulps.)"""
    case = load(WATER, SMALL + sets)
    a, _ = runner.build(case)
    a.advance(0.03)
    full = a.get_full_state()
    p, s = full["particles"].copy(), full["scalars"].copy()
    if field in ("sigma", "L"):
        row = sum(w for _, w in FULL_STATE_ROWS[:FULL_STATE_ROWS.index((field, 4))])
        p[row] = np.nextafter(p[row], np.inf)
    else:
        i = FULL_STATE_SCALARS.index("smax")
        for _ in range(8):
            s[i] = np.nextafter(s[i], np.inf)
    b, _ = runner.build(case)
    b.set_full_state(p, s)
    a.advance(0.04)
    b.advance(0.04)
    assert not np.array_equal(a.state()["x"], b.state()["x"])


def test_set_full_state_refuses_bad_input():
    case = load(WATER, SMALL)
    sim, _ = runner.build(case)
    full = sim.get_full_state()
    p, s = full["particles"], full["scalars"]
    bad = p.copy()
    bad[0, 3] = np.nan
    with pytest.raises(CpdiError, match="NaN or Inf"):
        sim.set_full_state(bad, s)
    bad_s = s.copy()
    bad_s[0] = np.inf   # the time
    with pytest.raises(CpdiError, match="NaN or Inf"):
        sim.set_full_state(p, bad_s)
    with pytest.raises(CpdiError, match="NaN or Inf"):   # damaged both ways at once
        sim.set_full_state(bad, bad_s)
    with pytest.raises(CpdiError, match="particles but the simulation has"):
        sim.set_full_state(p[:, :-1], s)
    with pytest.raises(CpdiError, match="rows per particle"):
        sim.set_full_state(p[:-1], s)
    neg = s.copy()
    neg[1] = 2.5  # steps not a whole number
    with pytest.raises(CpdiError, match="whole number"):
        sim.set_full_state(p, neg)
    inverted = p.copy()
    inverted[4:8, 7] = [1.0, 0.0, 0.0, -1.0]  # det F < 0
    with pytest.raises(CpdiError, match="particle 8 has det F"):
        sim.set_full_state(inverted, s)
    sim.close()


# ---------------------------------------------------------------- the runner
def test_restart_from_a_periodic_checkpoint_equals_the_uninterrupted_run(tmp_path):
    case = load(WATER, SMALL)
    ref = runner.run(case, tmp_path / "ref", progress=False)
    ckpt = runner.run(case, tmp_path / "ck", progress=False, checkpoint_every=0.06)
    with h5py.File(tmp_path / "ck" / "checkpoint.h5") as f:
        t_ck = float(f.attrs["t"])
    assert 0.06 <= t_ck < 0.1
    assert ckpt.summary["checkpoint"]["t"] == t_ck
    assert_same_run(tmp_path / "ref", tmp_path / "ck")  # checkpointing itself changes nothing
    res = runner.run(case, tmp_path / "re", progress=False, restart=tmp_path / "ck")
    assert res.summary["restarted_from"]["t"] == t_ck
    assert_same_bits(res.final, ref.final, "final ")
    assert_same_bits(res.series, ref.series, "series ")
    assert res.snapshots == ref.snapshots
    assert_same_run(tmp_path / "ref", tmp_path / "re")


def test_stop_on_signal_catches_and_restores_handlers():
    before = signal.getsignal(signal.SIGTERM)
    with runner.StopOnSignal() as stop:
        assert stop() is None
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.01)
        assert stop() == "SIGTERM" and stop.exit_code == 143
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.fixture(scope="module")
def slow_reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("slow") / "ref"
    return out, runner.run(load(WATER, SLOW), out, progress=False)


def rows_written(path: Path) -> int:
    try:
        return len(path.read_text().splitlines()) - 1
    except FileNotFoundError:
        return 0


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_stops_cleanly_and_the_restart_matches(tmp_path, slow_reference, sig, code):
    out = tmp_path / "run"
    sets = [a for kv in SLOW for a in ("--set", kv)]
    proc = subprocess.Popen([sys.executable, "-m", "harness", "run", str(WATER), "--out", str(out), *sets],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while rows_written(out / "series.csv") < 3 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)  # stepping has begun (t >= 0.01 of 0.15)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert "Traceback" not in err and "resume with:" in err and f"--restart {out}" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and signal.Signals(sig).name in summary["reason"]
    t_stop = summary["simulated_time"]
    assert 0.01 <= t_stop < 0.15 and summary["checkpoint"]["t"] == t_stop
    case = load(WATER, SLOW)
    ck = checkpoint.load(out, case, runner.build(case)[1])
    assert ck.scalars[0] == t_stop
    # the partial outputs are valid: every row written so far, snapshots readable
    assert read_series(out / "series.csv")["t"][-1] <= t_stop
    with h5py.File(out / "snapshots.h5") as f:
        assert len(f["snapshots"]) == summary["snapshots"] >= 1
    res = runner.run(case, out, progress=False, restart=out)
    ref_dir, ref = slow_reference
    assert_same_bits(res.final, ref.final, "final ")
    assert_same_bits(res.series, ref.series, "series ")
    assert_same_run(ref_dir, out)


# ---------------------------------------------------------------- refusals
@pytest.fixture
def checkpointed(tmp_path):
    out = tmp_path / "ck"
    runner.run(load(WATER, TINY), out, progress=False, checkpoint_every=0.01)
    return out


def restart_cli(capsys, run_dir, *sets):
    """Run the CLI in-process; returns (exit status, stderr). An exception fails the test."""
    before = (run_dir / "series.csv").read_text()
    argv = ["run", str(WATER), "--restart", str(run_dir), "--no-progress",
            *(a for kv in [*TINY, *sets] for a in ("--set", kv))]
    code = cli.main(argv)
    err = capsys.readouterr().err
    if code != 0:
        assert (run_dir / "series.csv").read_text() == before, "a refused restart must not touch the outputs"
    return code, err


def one_line_error(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def test_missing_checkpoint_is_refused(tmp_path, capsys, checkpointed):
    (checkpointed / "checkpoint.h5").unlink()
    code, err = restart_cli(capsys, checkpointed)
    assert code == 2
    assert "no checkpoint at" in one_line_error(err) and "--checkpoint-every" in err


def test_truncated_checkpoint_is_refused(capsys, checkpointed):
    path = checkpointed / "checkpoint.h5"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    code, err = restart_cli(capsys, checkpointed)
    assert code == 2 and "is damaged or truncated" in one_line_error(err)


def test_altered_checkpoint_contents_are_refused(capsys, checkpointed):
    with h5py.File(checkpointed / "checkpoint.h5", "r+") as f:
        f["particles"][0, 0] += 1e-9
    code, err = restart_cli(capsys, checkpointed)
    assert code == 2 and "do not match their SHA-256" in one_line_error(err)


def test_checkpoint_of_another_case_is_refused(capsys, checkpointed):
    code, err = restart_cli(capsys, checkpointed, "solver.cfl=0.3", "materials.0.viscosity=0.002")
    line = one_line_error(err)
    assert code == 2 and "belongs to a different case" in line
    assert "solver.cfl is 0.4 in the checkpoint but 0.3 now" in line
    assert "materials.0.viscosity is 0.001 in the checkpoint but 0.002 now" in line


def test_missing_snapshots_are_refused(capsys, checkpointed):
    (checkpointed / "snapshots.h5").unlink()
    code, err = restart_cli(capsys, checkpointed)
    assert code == 2 and "cannot continue the snapshots" in one_line_error(err)


def test_restart_of_a_good_checkpoint_via_the_cli_completes(capsys, checkpointed):
    code, err = restart_cli(capsys, checkpointed)
    assert code == 0, err
    assert json.loads((checkpointed / "summary.json").read_text())["status"] == "completed"


def test_bad_checkpoint_interval_is_refused(tmp_path, capsys):
    code = cli.main(["run", str(WATER), "--out", str(tmp_path), "--checkpoint-every", "nan", "--no-progress",
                     *(a for kv in SMALL for a in ("--set", kv))])
    assert code == 2 and "must be a positive number" in one_line_error(capsys.readouterr().err)
