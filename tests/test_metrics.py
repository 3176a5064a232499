"""Unit tests for harness.metrics on synthetic data with known order."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness import metrics as m

H = np.array([0.1, 0.05, 0.025, 0.0125, 0.00625])


# --------------------------------------------------------------------------- norms


def test_l2_unweighted_is_rms() -> None:
    assert m.l2_norm([3.0, -4.0]) == pytest.approx(math.sqrt(12.5), rel=1e-15)


def test_l2_weighted_by_hand() -> None:
    e = np.array([1.0, 2.0, -3.0])
    w = np.array([1.0, 0.0, 3.0])
    assert m.l2_norm(e, w) == pytest.approx(math.sqrt((1.0 + 27.0) / 4.0), rel=1e-15)


def test_l2_weights_scale_invariant_and_uniform_equals_rms() -> None:
    rng = np.random.default_rng(1)
    e = rng.normal(size=50)
    w = rng.uniform(0.1, 2.0, size=50)
    assert m.l2_norm(e, w) == pytest.approx(m.l2_norm(e, 7.3 * w), rel=1e-14)
    assert m.l2_norm(e, np.full(50, 2.5)) == pytest.approx(m.l2_norm(e), rel=1e-14)


def test_vector_norms_use_euclidean_magnitude() -> None:
    e = np.array([[3.0, 4.0], [0.0, 1.0]])  # magnitudes 5 and 1
    assert m.l2_norm(e) == pytest.approx(math.sqrt(13.0), rel=1e-15)
    assert m.l2_norm(e, [3.0, 1.0]) == pytest.approx(math.sqrt((3 * 25 + 1) / 4), rel=1e-15)
    assert m.linf_norm(e) == pytest.approx(5.0, rel=1e-15)


def test_linf_scalar() -> None:
    assert m.linf_norm([0.5, -2.0, 1.5]) == 2.0


def test_norm_input_validation() -> None:
    with pytest.raises(ValueError):
        m.l2_norm([1.0, 2.0], [1.0])
    with pytest.raises(ValueError):
        m.l2_norm([1.0, 2.0], [1.0, -1.0])
    with pytest.raises(ValueError):
        m.l2_norm(np.zeros((2, 2, 2)))


# --------------------------------------------------------------------------- observed order


@pytest.mark.parametrize("p", [1.0, 2.0, 1.5])
def test_observed_orders_pure_power_law(p: float) -> None:
    e = 3.7 * H**p
    np.testing.assert_allclose(m.observed_orders(H, e), p, rtol=0, atol=1e-12)


def test_observed_orders_with_higher_order_term_approach_p() -> None:
    e = H**2 + 5.0 * H**3
    orders = m.observed_orders(H, e)
    assert orders.shape == (4,)
    assert np.all(np.diff(np.abs(orders - 2.0)) < 0)  # monotonically approaching 2
    # exact value for the finest pair
    expected = math.log(e[-2] / e[-1]) / math.log(2.0)
    assert orders[-1] == pytest.approx(expected, rel=1e-14)
    assert 0.04 < orders[-1] - 2.0 < 0.045  # = log2(1.0625 / 1.03125)


def test_observed_orders_non_uniform_ratio() -> None:
    h = np.array([0.3, 0.1, 0.08])
    np.testing.assert_allclose(m.observed_orders(h, 2.0 * h**1.7), 1.7, atol=1e-12)


def test_observed_orders_nan_for_zero_or_negative() -> None:
    orders = m.observed_orders([0.4, 0.2, 0.1, 0.05], [1.0, 0.0, 0.25, -1.0])
    assert np.isnan(orders).all()
    orders = m.observed_orders([0.4, 0.2, 0.1], [1.0, 0.25, 0.0625])
    np.testing.assert_allclose(orders, [2.0, 2.0], atol=1e-12)


# --------------------------------------------------------------------------- Richardson


def test_richardson_recovers_exact_limit() -> None:
    f0, c, p, r = 1.2345, 0.8, 2.0, 2.0
    f = {hv: f0 + c * hv**p for hv in (0.4, 0.2, 0.1)}
    res = m.richardson(f_coarse=f[0.4], f_medium=f[0.2], f_fine=f[0.1], r=r)
    assert res.convergence == "monotone"
    assert res.converging
    assert res.p == pytest.approx(p, abs=1e-10)
    assert res.f_extrapolated == pytest.approx(f0, abs=1e-13)
    assert res.ratio == pytest.approx(1 / r**p, rel=1e-10)


def test_richardson_ratio_three_and_negative_coefficient() -> None:
    f0, c, p, r = -2.0, -5.0, 1.3, 3.0
    f = [f0 + c * (0.9 / r**k) ** p for k in range(3)]  # coarse, medium, fine
    res = m.richardson(f_coarse=f[0], f_medium=f[1], f_fine=f[2], r=r)
    assert res.p == pytest.approx(p, abs=1e-10)
    assert res.f_extrapolated == pytest.approx(f0, abs=1e-12)


def test_richardson_is_keyword_only() -> None:
    with pytest.raises(TypeError):
        m.richardson(1.0, 0.5, 0.25, 2.0)  # type: ignore[misc]


def test_richardson_oscillatory() -> None:
    res = m.richardson(f_coarse=1.2, f_medium=0.9, f_fine=1.05, r=2.0)
    assert res.convergence == "oscillatory"
    assert res.converging  # |R| = 0.5 < 1: oscillatory convergence
    assert math.isnan(res.p) and math.isnan(res.f_extrapolated)


def test_richardson_divergent() -> None:
    res = m.richardson(f_coarse=1.0, f_medium=1.1, f_fine=1.3, r=2.0)  # differences growing
    assert res.convergence == "divergent"
    assert not res.converging
    assert res.p == pytest.approx(math.log(0.1 / 0.2) / math.log(2.0), abs=1e-12)
    assert math.isnan(res.f_extrapolated)
    osc = m.richardson(f_coarse=1.0, f_medium=1.1, f_fine=0.8, r=2.0)  # oscillating, growing
    assert osc.convergence == "divergent" and math.isnan(osc.p)


def test_richardson_rejects_bad_ratio() -> None:
    with pytest.raises(ValueError):
        m.richardson(f_coarse=1.0, f_medium=0.5, f_fine=0.25, r=1.0)


# --------------------------------------------------------------------------- GCI


def test_gci_exact_power_law_values() -> None:
    f0, c, p, r, fs = 10.0, 2.0, 2.0, 2.0, 1.25
    f3, f2, f1 = (f0 + c * hv**p for hv in (0.4, 0.2, 0.1))
    g = m.gci(f1=f1, f2=f2, f3=f3, r=r, fs=fs)
    assert g.convergence == "monotone"
    assert g.p == pytest.approx(2.0, abs=1e-10)
    assert g.f_extrapolated == pytest.approx(f0, abs=1e-12)
    assert g.gci12 == pytest.approx(fs * abs((f1 - f2) / f1) / (r**p - 1), rel=1e-12)
    # With exact p the fine-grid GCI is fs * |f1 - f0| / |f1|.
    assert g.gci12 == pytest.approx(fs * abs(f1 - f0) / abs(f1), rel=1e-9)
    assert g.gci23 == pytest.approx(fs * abs(f2 - f0) / abs(f2), rel=1e-9)
    # Roache's asymptotic ratio reduces to |f1| / |f2| for an exact power law.
    assert g.asymptotic_ratio == pytest.approx(abs(f1) / abs(f2), rel=1e-12)
    assert g.asymptotic_ratio == pytest.approx(1.0, abs=0.01)


def test_gci_asymptotic_ratio_near_one_in_asymptotic_range() -> None:
    h = np.array([0.02, 0.01, 0.005])
    f = 1.0 + 0.3 * h**2 + 0.4 * h**3
    g = m.gci(f1=f[2], f2=f[1], f3=f[0], r=2.0)
    assert g.p == pytest.approx(2.0, abs=0.025)
    assert g.f_extrapolated == pytest.approx(1.0, abs=1e-7)
    assert g.asymptotic_ratio == pytest.approx(1.0, abs=1e-4)
    # Pre-asymptotic: p is off, and the ratio (identically |f1/f2| for constant r) drifts from one.
    h = np.array([0.8, 0.4, 0.2])
    f = 1.0 + 0.3 * h**2 + 0.4 * h**3
    g = m.gci(f1=f[2], f2=f[1], f3=f[0], r=2.0)
    assert g.p > 2.4
    assert g.asymptotic_ratio == pytest.approx(f[2] / f[1], rel=1e-12)
    assert abs(g.asymptotic_ratio - 1.0) > 0.05


def test_gci_nan_for_oscillatory_and_divergent() -> None:
    g = m.gci(f1=1.05, f2=0.9, f3=1.2, r=2.0)
    assert g.convergence == "oscillatory"
    assert all(math.isnan(x) for x in (g.p, g.gci12, g.gci23, g.asymptotic_ratio))
    g = m.gci(f1=1.3, f2=1.1, f3=1.0, r=2.0)
    assert g.convergence == "divergent" and not g.converging
    assert math.isnan(g.gci12)


# --------------------------------------------------------------------------- GCI from errors


def test_gci_from_errors_pure_power_law() -> None:
    e = 0.5 * H**2
    res = m.gci_from_errors(H, e, fs=1.25)
    assert res.p == pytest.approx(2.0, abs=1e-12)
    assert res.p_medium == pytest.approx(2.0, abs=1e-12)
    assert res.p_lsq == pytest.approx(2.0, abs=1e-12)
    assert res.p_three_level == pytest.approx(2.0, abs=1e-10)
    assert res.e_fine == e[-1]
    assert res.gci_fine == pytest.approx(1.25 * e[-1], rel=1e-12)
    assert res.gci_medium == pytest.approx(1.25 * e[-2], rel=1e-12)
    assert res.asymptotic_ratio == pytest.approx(1.0, abs=1e-12)
    assert abs(res.e_limit) < 1e-12 * e[-1] * 1e3
    assert res.convergence == "monotone"


def test_gci_from_errors_detects_error_floor() -> None:
    floor = 1e-3
    e = floor + 0.5 * H**2
    res = m.gci_from_errors(H, e)
    assert res.p_three_level == pytest.approx(2.0, abs=1e-9)
    assert res.e_limit == pytest.approx(floor, rel=1e-9)
    assert res.p < 1.0  # apparent order collapses towards the floor
    assert abs(res.asymptotic_ratio - 1.0) > 0.2


def test_gci_from_errors_pre_asymptotic_ratio_departs_from_one() -> None:
    e = H**2 + 40.0 * H**3
    res = m.gci_from_errors(H[:3], e[:3])
    assert abs(res.asymptotic_ratio - 1.0) > 0.1
    res_fine = m.gci_from_errors(H, H**2 + 0.4 * H**3)
    assert res_fine.asymptotic_ratio == pytest.approx(1.0, abs=0.01)


def test_gci_from_errors_non_constant_ratio_uses_celik_iteration() -> None:
    h = np.array([0.3, 0.2, 0.13])
    floor = 0.01
    e = floor + 2.0 * h**1.5
    res = m.gci_from_errors(h, e)
    assert res.p_three_level == pytest.approx(1.5, abs=1e-8)
    assert res.e_limit == pytest.approx(floor, rel=1e-7)


def test_gci_from_errors_flags() -> None:
    h = [0.4, 0.2, 0.1]
    assert m.gci_from_errors(h, [1.0, 0.9, 0.5]).convergence == "divergent"
    osc = m.gci_from_errors(h, [1.0, 0.2, 0.4])
    assert osc.convergence == "oscillatory" and math.isnan(osc.e_limit)
    with pytest.raises(ValueError):
        m.gci_from_errors([0.2, 0.1], [1.0, 0.5])


# --------------------------------------------------------------------------- table


def test_convergence_table() -> None:
    table = m.convergence_table([0.1, 0.05, 0.025], [4e-2, 1e-2, 2.5e-3], norm_name="Linf")
    lines = table.strip().splitlines()
    assert lines[0] == "| h | Linf error | rate |"
    assert lines[1].startswith("| -")
    assert lines[2] == "| 0.1 | 4.000e-02 |  |"
    assert lines[3] == "| 0.05 | 1.000e-02 | 2.00 |"
    assert lines[4] == "| 0.025 | 2.500e-03 | 2.00 |"
    assert len(lines) == 5


# --------------------------------------------------------------------------- occupied water volume


def _water_layer(width: float, depth: float, d: float):
    xs, ys = np.meshgrid(np.arange(d / 2, width, d), np.arange(d / 2, depth, d))
    x = np.column_stack([xs.ravel(), ys.ravel()])
    r = np.tile([d / 2, 0.0, 0.0, d / 2], (len(x), 1))
    return x, r, np.full(len(x), d * d)


def test_water_volume_loss_is_zero_for_a_tiling_layer_and_sees_a_collapse() -> None:
    from harness.checks.sinking_block import water_volume_loss
    x, r, vol = _water_layer(1.0, 0.4, 0.025)
    water, block = np.ones(len(x), bool), np.zeros(len(x), bool)
    assert water_volume_loss(x, r, vol, water, block, 0.05, 0.0, 1.0) == pytest.approx(0.0, abs=1e-12)
    # positions packed 10 % closer vertically, volumes kept: the surface drops, 10 % is lost
    xc = x * [1.0, 0.9]
    rc = r * [1.0, 0.9, 1.0, 0.9]
    assert water_volume_loss(xc, rc, vol, water, block, 0.05, 0.0, 1.0) == pytest.approx(0.1, abs=2e-3)
    # a block on the floor of one column lifts that column's water by its height; its area is
    # not water, so nothing is lost
    col = (x[:, 0] / 0.025).astype(int) == 20
    xb = np.vstack([x + np.where(col, 0.025, 0.0)[:, None] * [0.0, 1.0], [[20.5 * 0.025, 0.0125]]])
    rb = np.vstack([r, [[0.0125, 0.0, 0.0, 0.0125]]])
    vb = np.append(vol, 0.025**2)
    wb = np.append(water, False)
    assert water_volume_loss(xb, rb, vb, wb, ~wb, 0.025, 0.0, 1.0) == pytest.approx(0.0, abs=1e-12)
    # with the block left out, its column counts as water: a gain
    assert water_volume_loss(xb[:-1], rb[:-1], vb[:-1], wb[:-1], ~wb[:-1], 0.025, 0.0, 1.0) < -1e-3
    # the columns follow the grid's origin: the same layer shifted with it loses nothing
    assert water_volume_loss(x + [3.0, 0.0], r, vol, water, block, 0.05, 3.0, 1.0) == pytest.approx(0.0, abs=1e-12)
    # a block above the water is not subtracted
    xa = np.vstack([x, [[0.5, 0.6]]])
    assert water_volume_loss(xa, rb, vb, wb, ~wb, 0.025, 0.0, 1.0) == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------- sharper cases
# (make mutate-harness: with r = 2 and p = 2, r**p == r*p and such mutants survived; these use
# non-integer orders and ratios, and check the messages a user sees)


@pytest.mark.parametrize("p", [1.5, 2.5])
def test_gci_from_errors_non_uniform_ratio_by_hand(p: float) -> None:
    h = np.array([0.3, 0.2, 0.13])
    e = 2.0 * h**p
    e3, e2, e1 = e
    r21, r32 = h[1] / h[2], h[0] / h[1]
    res = m.gci_from_errors(h, e, fs=1.25)
    assert res.p == pytest.approx(p, abs=1e-12) and res.p_medium == pytest.approx(p, abs=1e-12)
    assert res.gci_fine == pytest.approx(1.25 * abs(e1 - e2) / (r21**p - 1.0), rel=1e-12)
    assert res.gci_fine == pytest.approx(1.25 * e1, rel=1e-12)
    assert res.gci_medium == pytest.approx(1.25 * abs(e2 - e3) / (r32**p - 1.0), rel=1e-12)
    assert res.asymptotic_ratio == pytest.approx(1.0, abs=1e-12)
    assert abs(res.e_limit) < 1e-9 * e1
    slope = np.sum((np.log(h) - np.log(h).mean()) * (np.log(e) - np.log(e).mean())) / np.sum(
        (np.log(h) - np.log(h).mean()) ** 2)
    assert res.p_lsq == pytest.approx(slope, abs=1e-12)


def test_lsq_slope_of_noisy_levels_is_the_least_squares_fit() -> None:
    h = np.array([0.4, 0.2, 0.1])
    e = np.array([1.1, 0.24, 0.065])
    lh, le = np.log(h), np.log(e)
    slope = np.sum((lh - lh.mean()) * (le - le.mean())) / np.sum((lh - lh.mean()) ** 2)
    assert m.gci_from_errors(h, e).p_lsq == pytest.approx(slope, rel=1e-12)
    assert math.isnan(m.gci_from_errors(h, [1.0, 0.0, 0.1]).p_lsq)


def test_gci_roache_at_non_integer_ratio_and_order() -> None:
    f0, c, p, r, fs = 3.0, -1.5, 1.7, 1.5, 1.25
    f3, f2, f1 = (f0 + c * hv**p for hv in (0.45, 0.3, 0.2))
    g = m.gci(f1=f1, f2=f2, f3=f3, r=r, fs=fs)
    assert g.p == pytest.approx(p, abs=1e-10) and g.f_extrapolated == pytest.approx(f0, abs=1e-10)
    assert g.gci12 == pytest.approx(fs * abs((f1 - f2) / f1) / (r**p - 1.0), rel=1e-10)
    assert g.gci23 == pytest.approx(fs * abs((f2 - f3) / f2) / (r**p - 1.0), rel=1e-10)
    assert g.asymptotic_ratio == pytest.approx(g.gci23 / (r**p * g.gci12), rel=1e-12)


def test_three_finest_levels_must_be_decreasing_and_positive() -> None:
    for h in ([0.2, 0.2, 0.1], [0.4, 0.1, 0.1], [0.4, 0.2, 0.0]):
        with pytest.raises(ValueError, match="positive and decreasing"):
            m.gci_from_errors(h, [1.0, 0.5, 0.25])
    with pytest.raises(ValueError, match="at least three levels"):
        m.gci_from_errors([0.2, 0.1], [1.0, 0.5])


def test_norm_messages_name_the_problem() -> None:
    with pytest.raises(ValueError, match="does not match error count"):
        m.l2_norm([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="weights must be non-negative"):
        m.l2_norm([1.0, 2.0], [1.0, -1.0])
    assert math.isnan(m.l2_norm([]))
    assert m.l2_norm([2.0]) == 2.0


def test_convergence_table_rates_per_row_and_undefined_rate() -> None:
    table = m.convergence_table([0.4, 0.2, 0.1, 0.05], [1.0, 0.5, 0.125, 0.0], norm_name="L2")
    rows = table.strip().splitlines()[2:]
    assert [r.split("|")[3].strip() for r in rows] == ["", "1.00", "2.00", "n/a"]
