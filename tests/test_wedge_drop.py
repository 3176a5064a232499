"""harness/checks/wedge_drop.py: the record it reads, the error measure and the seeded density, on cases
whose answers are known by hand (no simulation)."""

from __future__ import annotations

import numpy as np
import pytest

from harness import cases
from harness.checks import wedge_drop as w


def test_the_record_starts_at_the_impact_speed_and_decelerates_within_the_window():
    t, v = w.record()
    assert t[0] == pytest.approx(0.30081e-3, rel=1e-4) and v[0] == pytest.approx(5.0536, abs=1e-3)
    assert np.all(np.diff(t) > 0) and t[-1] < w.WINDOW
    assert v[-1] == pytest.approx(1.77677, abs=1e-4)  # the last point, 39.93 ms
    assert v.max() < 5.06 and v.min() > 1.7


def test_velocity_errors_are_relative_at_the_record_times_inside_the_window():
    t_run = np.linspace(0.0, 0.05, 101)
    v_run = 5.0 - 50.0 * t_run                    # linear: interpolation is exact
    t_exp = np.array([-0.001, 0.0, 0.01, 0.02, 0.041])
    v_exp = np.array([9.0, 5.0, 4.0, 5.0, 1.0])   # first and last outside [0, 40 ms]
    tk, err = w.velocity_errors(t_run, v_run, t_exp, v_exp)
    np.testing.assert_array_equal(tk, [0.0, 0.01, 0.02])
    np.testing.assert_allclose(err, [0.0, 0.125, 0.2], rtol=1e-12)   # (4.5-4)/4, |4-5|/5


def test_velocity_errors_drop_points_beyond_the_run():
    tk, err = w.velocity_errors([0.0, 0.01], [5.0, 4.0], [0.005, 0.02], [4.5, 3.0])
    np.testing.assert_array_equal(tk, [0.005])
    np.testing.assert_allclose(err, [0.0], atol=1e-15)


def test_seeded_density_gives_the_wedge_94_kg_per_metre():
    h = 0.02
    case = cases.load(w.CASE, [f"grid.cell={h}"])
    rho = w.seeded_density(case)
    polygon = 0.6 * 0.6 * np.tan(np.radians(25.0))          # 0.167874 m^2
    assert rho == pytest.approx(w.MASS / polygon, rel=0.01)  # the staircase: 0.3 % at h = 0.02
    from harness import seeding
    parts = seeding.seed(cases.load(w.CASE, [f"grid.cell={h}", f"materials.1.density={rho!r}"]))
    assert parts.mass[parts.mat == 1].sum() == pytest.approx(w.MASS, rel=1e-12)


def test_the_case_is_the_experiment():
    case = cases.load(w.CASE)
    body = next(b for b in case["bodies"] if b["name"] == "wedge")
    v = np.asarray(body["geometry"]["vertices"])
    keel, right, left = v
    deadrise = np.degrees(np.arctan2(right[1] - keel[1], right[0] - keel[0]))
    assert deadrise == pytest.approx(25.0, abs=1e-4)
    assert right[0] - left[0] == pytest.approx(1.2) and right[1] == pytest.approx(left[1])
    assert body["velocity"] == [0.0, -5.05]
    water = next(b for b in case["bodies"] if b["name"] == "water")
    assert keel[1] == pytest.approx(water["geometry"]["max"][1])   # keel on the surface at t = 0
    assert case["materials"][1]["model"] == "rigid_body" and case["solver"]["t_end"] >= w.WINDOW


def test_the_known_limitation_evidence_the_2d_bem_misses_the_record_by_9_percent():
    """The evidence behind the record gate's known-limitation mark (LIMITATION): the 2-D potential-flow BEM,
    the same model as ours, lies 9.1 % above the record at 19.8 ms, more than the 5 % gate; and it starts at
    the impact speed and ends within 2 % of the record, so it is the same experiment's case."""
    te, ve = w.record()
    tb, vb = w.record(w.BEM)
    tk, err = w.velocity_errors(tb, vb, te, ve)
    assert len(tk) == len(te)                      # the BEM covers every record point in the window
    assert err.max() == pytest.approx(0.0914, abs=5e-4) and tk[np.argmax(err)] == pytest.approx(19.80e-3, abs=1e-5)
    assert err.max() > w.GATE and "9.1 %" in w.LIMITATION
    assert vb[0] == pytest.approx(5.05, abs=0.01) and abs(vb[-1] / ve[-1] - 1.0) < 0.02
