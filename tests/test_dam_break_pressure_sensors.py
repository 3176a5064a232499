"""The pure-Python pieces of dam_break_pressure's code-to-code comparison (issue 38): the
references' sensor definition (harness.water.kernel_wall_sensor), the window mean and the
sustained impact time, on synthetic fields and on the 2D reference data whose README quotes
the numbers (reference/data/lobovsky_2d_numerical/README.md)."""

import math

import numpy as np
import pytest

from harness import water
from harness.checks import dam_break_pressure as dbp

WALL = 1.61


def _lattice(dp: float, depth: float = 0.05, top: float = 0.2):
    """Particles on a square lattice of spacing dp left of the wall x = WALL (centres dp/2 from it)."""
    xs = WALL - dp * (np.arange(int(depth / dp)) + 0.5)
    ys = dp * (np.arange(int(top / dp)) + 0.5)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel()])


def test_wendland_c2_is_one_at_the_centre_and_zero_from_the_support_on():
    q = np.array([0.0, 0.5, 1.0, 1.5])
    w = water.wendland_c2(q)
    assert w[0] == 1.0 and w[2] == 0.0 and w[3] == 0.0
    assert w[1] == pytest.approx(0.5**4 * 3.0)


def test_kernel_sensor_reads_a_uniform_pressure_exactly():
    x = _lattice(0.002)
    assert water.kernel_wall_sensor(x, np.full(len(x), 1234.5), None, WALL, 0.08, 0.0042, 0.012) == \
        pytest.approx(1234.5, rel=1e-14)


def test_kernel_sensor_reads_a_hydrostatic_pressure_at_the_sensor_height():
    # p linear in height: a Shepard average over a support symmetric in y (to the lattice's
    # granularity) returns the value at the segment's points, whose mean is the value at z
    dp = 0.0005
    x = _lattice(dp)
    p = 1000.0 * 9.81 * (0.3 - x[:, 1])
    got = water.kernel_wall_sensor(x, p, np.full(len(x), dp * dp), WALL, 0.08, 0.0042, 8 * dp)
    assert got == pytest.approx(1000.0 * 9.81 * (0.3 - 0.08), rel=1e-3)


def test_kernel_sensor_averages_into_the_water_not_at_the_wall():
    # p falls linearly away from the wall: the sensor reads the kernel's mean over the half disc
    # of water, below the wall's value and above the value one support away
    dp = 0.0005
    x = _lattice(dp)
    R = 0.006
    p = 1000.0 * (1.0 - (WALL - x[:, 0]) / 0.05)
    got = water.kernel_wall_sensor(x, p, None, WALL, 0.08, 0.0042, R)
    assert 1000.0 * (1.0 - R / 0.05) < got < 1000.0 * (1.0 - dp / 2 / 0.05)
    # the half-disc mean of the distance, weighted by (1 - q)^4 (1 + 4 q) in 2D: int r^2 w / int r w
    r = np.linspace(0.0, R, 20001)
    w = water.wendland_c2(r / R)
    mean_dist = np.trapezoid(r**2 * w, r) / np.trapezoid(r * w, r) * 2.0 / math.pi
    assert got == pytest.approx(1000.0 * (1.0 - mean_dist / 0.05), rel=2e-3)


def test_kernel_sensor_clips_negative_pressures_and_reads_zero_without_water():
    x = _lattice(0.002)
    assert water.kernel_wall_sensor(x, np.full(len(x), -50.0), None, WALL, 0.08, 0.0042, 0.012) == 0.0
    far = x[x[:, 1] > 0.15]   # nothing within the support of the segment at 80 mm
    assert water.kernel_wall_sensor(far, np.ones(len(far)), None, WALL, 0.08, 0.0042, 0.012) == 0.0
    # half the points have water: a point with no neighbour counts as 0 in the mean
    one = np.array([[WALL - 0.001, 0.08 + 0.0021]])
    got = water.kernel_wall_sensor(one, np.array([10.0]), None, WALL, 0.08, 0.0042, 0.0025)
    ys = 0.08 + 0.0042 * (np.linspace(0.0, 1.0, 10) - 0.5)
    reached = np.hypot(0.001, ys - (0.08 + 0.0021)) < 0.0025
    assert got == pytest.approx(10.0 * reached.mean())


def test_kernel_sensor_weighs_particles_by_their_volume():
    x = np.array([[WALL - 0.001, 0.08], [WALL - 0.002, 0.08]])
    p = np.array([1.0, 3.0])
    same = water.kernel_wall_sensor(x, p, np.array([1.0, 1.0]), WALL, 0.08, 0.0, 0.01)
    heavy = water.kernel_wall_sensor(x, p, np.array([1.0, 100.0]), WALL, 0.08, 0.0, 0.01)
    assert 1.0 < same < heavy < 3.0


def test_window_mean_is_the_trapezoid_average_over_the_samples_span():
    t = np.arange(0.0, 6.001, 0.01)
    assert dbp.window_mean(t, t) == pytest.approx(4.25, abs=1e-12)
    assert dbp.window_mean(t, np.full(t.size, 0.7)) == pytest.approx(0.7, abs=1e-14)
    assert math.isnan(dbp.window_mean(t[:100], t[:100]))


def test_sustained_impact_skips_a_one_sample_spike():
    t = np.round(np.arange(0.0, 4.0, 0.01), 2)
    p = np.zeros(t.size)
    p[t == 2.40] = 0.5                      # the run-up jet's spike
    p[(t >= 2.80) & (t < 2.84)] = 0.2       # held 0.04 < 0.05: not sustained
    p[t >= 2.90] = 0.3
    assert dbp.sustained_impact(t, p) == pytest.approx(2.90)
    assert dbp.sustained_impact(t, np.zeros(t.size)) == math.inf


@pytest.mark.parametrize("name, p3, p4, impact4", [
    ("trixiparticles_edac_400", 0.822, 0.363, 2.82), ("trixiparticles_edac_80", 0.813, 0.357, 2.82),
    ("trixiparticles_wcsph_400", 0.809, 0.359, 2.82), ("trixiparticles_wcsph_40", 0.760, 0.344, 2.71)])
def test_the_2d_references_give_their_readmes_means_and_impact_times(name, p3, p4, impact4):
    r = dbp.reference_2d(f"lobovsky_2d_numerical/{name}.csv")
    assert dbp.window_mean(r["t"], r["3"]) == pytest.approx(p3, abs=5e-4)
    assert dbp.window_mean(r["t"], r["4"]) == pytest.approx(p4, abs=5e-4)
    assert dbp.sustained_impact(r["t"], r["4"]) == pytest.approx(impact4, abs=1e-9)


def test_de_courcy_curves_are_read_per_sensor():
    d = dbp.decourcy()
    assert set(d) == {"3", "4"}
    for t, p in d.values():
        assert t.size == p.size > 100 and np.all(np.diff(t) >= 0)


def test_each_level_is_a_whole_number_of_cells_and_the_fine_ones_use_multigrid():
    from harness import cases
    for n in (*dbp.LEVELS_QUICK, *dbp.LEVELS_FULL):
        c = cases.load(dbp.CASE, dbp.level_settings(n))   # the loader refuses a partial cell
        assert c["grid"]["cell"] == pytest.approx(dbp.H / n, rel=1e-12)
        assert abs(c["grid"]["size"][0] - 1.61) <= c["grid"]["cell"] / 2
        assert c["solver"]["pressure_precond"] == ("multigrid" if n >= dbp.MULTIGRID_FROM else "mic0")
    assert dbp.level_settings(30) == ["grid.cell=0.01"]   # the experiment's run: the check's grid before issue 38
