"""Issue 40 item 4: the wedge_entry check's time averages (harness/checks/wedge_entry.py window,
window_weights). A prescribed body is a staircase of cells, so the pressure it meets is periodic with
the period h / V of its moving one cell, and the solver's steps are shorter where the pressure spikes.
The check's profile and force at a time are averages over whole such cycles, each step weighted by its
dt: on a synthetic run whose every step carries a self-similar profile times a periodic spike of zero
time mean, they give the self-similar profile itself, which a plain mean over the steps does not."""

import numpy as np
import pytest

from harness.checks import wedge_entry as W

H = 0.005
PERIOD = H / W.V


def spike(t):
    """Zero time mean over a period: +9 in its first tenth, -1 in the rest."""
    phase = np.mod(t / PERIOD, 1.0)
    return np.where(phase < 0.1, 9.0, -1.0)


def synthetic_run(t_end=0.0171):
    """Steps of dt = PERIOD/100 in each spike (the short steps after a cell joins), 0.9 PERIOD/8 in the rest,
    each step's value that of its interval (t[i-1], t[i]]: Cp = g(z / V t) (1 + 0.5 spike), F = C rho V^3 t
    (1 + 0.5 spike)."""
    per = np.concatenate([np.arange(1, 11) * PERIOD / 100, 0.1 * PERIOD + np.arange(1, 9) * 0.9 * PERIOD / 8])
    ts = [k * PERIOD + per for k in range(int(np.ceil(t_end / PERIOD)))]
    ts = np.concatenate(ts)
    mid = ts - 0.5 * np.diff(np.concatenate([[0.0], ts]))   # the interval's middle carries its value
    z0 = np.linspace(0.0, 0.17, 60)

    def g(zeta):
        return 1.0 + zeta

    factor = 1.0 + 0.5 * spike(mid)
    cp = np.array([g(z0 / (W.V * ti)) * f for ti, f in zip(ts, factor, strict=True)])
    force = 16.0 * W.RHO * W.V**3 * ts * factor
    return {"h": H, "t": ts, "cp": cp, "z0": z0, "force": force}, g


def test_the_window_spans_whole_staircase_cycles_centred_on_its_time():
    o, _ = synthetic_run()
    for depth in W.DEPTHS:
        tk = depth / W.V
        w, lo, hi = W.window_weights(o["t"], tk, H)
        cycles = (hi - lo) / PERIOD
        assert abs(cycles - round(cycles)) < 1e-9 and round(cycles) == max(1, round(2 * W.WINDOW * depth / H))
        assert abs(0.5 * (lo + hi) - tk) < 1e-15
        assert abs(w.sum() - (hi - lo)) < 1e-12 and np.all(w >= 0.0)


def test_time_averages_over_whole_cycles_remove_the_staircase_spike():
    o, g = synthetic_run()
    for depth in W.DEPTHS:
        p = W.window(o, depth)
        np.testing.assert_allclose(p["force_coef"], 16.0, rtol=1e-9)
        inner = p["zeta"] <= 0.17 / (W.V * (depth / W.V + 0.5 * p["cycles"] * PERIOD))   # every step covers it
        np.testing.assert_allclose(p["cp"][inner], g(p["zeta"][inner]), rtol=1e-9)


def test_a_plain_mean_over_the_steps_is_biased_by_the_short_spike_steps():
    """The reason for the weights: the spike's steps, ten times as many per unit time, dominate a
    plain mean (so the test above can fail)."""
    o, _ = synthetic_run()
    tk = W.DEPTHS[0] / W.V
    sel = (o["t"] >= (1 - W.WINDOW) * tk) & (o["t"] <= (1 + W.WINDOW) * tk)
    plain = np.mean(o["force"][sel] / (W.RHO * W.V**3 * o["t"][sel]))
    assert plain > 1.2 * 16.0


def test_a_window_past_the_end_of_the_run_is_refused():
    o, _ = synthetic_run(t_end=0.0150)
    with pytest.raises(ValueError, match="does not cover"):
        W.window(o, W.DEPTHS[-1])


def test_the_root_is_where_the_profile_past_its_peak_falls_to_half():
    zeta = np.linspace(0.0, 2.0, 201)
    cp = np.interp(zeta, [0.0, 1.4, 1.5, 1.7, 2.0], [2.0, 7.0, 6.0, 0.0, 0.0])   # 3.5 at 1.5 + 2.5/30
    assert abs(W.half_peak_root(zeta, cp) - (1.5 + 2.5 / 30.0)) < 1e-12
    assert np.isnan(W.half_peak_root(zeta, np.linspace(1.0, 2.0, 201)))   # no fall past the peak
