"""harness/checks/cylinder_entry.py: Campbell & Weynberg's fit as DNV quotes it, the small-s limits of von
Karman and Wagner in reference/data/cylinder_entry_campbell_weynberg.csv, and the windowed measurement of
Cs through the staircase (window means from the impulse)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness import refdata
from harness.checks import cylinder_entry as ce


def test_fit_is_the_quoted_expression():
    # the expression as the source writes it, CS = 5.15*((D/(D+19*S)) + (0.107*S/D)), with dimensions
    for d, s in [(0.2, 0.0), (0.2, 0.01), (0.5, 0.05), (1.0, 0.25), (2.0, 1.0)]:
        assert ce.cs_fit(s / d) == pytest.approx(5.15 * (d / (d + 19 * s) + 0.107 * s / d), rel=1e-14)
    assert ce.cs_fit(0.0) == 5.15
    # about half its initial value at s/D = 0.05 (5.15 (1/1.95 + 0.00535)), 0.766 with the cylinder half under
    assert ce.cs_fit(0.05) == pytest.approx(2.6686, abs=1e-4)
    assert ce.cs_fit(0.5) == pytest.approx(0.7660, abs=1e-4)   # 5.15 (1/10.5 + 0.0535)


def test_reference_file_holds_the_fit_and_the_derived_limits():
    ref = ce.reference()
    assert (ref["fit"]["cs0"], ref["fit"]["b"], ref["fit"]["c"]) == (5.15, 19.0, 0.107)
    assert ref["von_karman"]["cs0"] == pytest.approx(math.pi, rel=1e-9)
    assert ref["wagner"]["cs0"] == pytest.approx(2 * math.pi, rel=1e-9)
    assert ref["von_karman"]["cs0"] < ref["fit"]["cs0"] < ref["wagner"]["cs0"]
    head = " ".join(refdata.header(refdata.DATA / ce.REF))
    for word in ("Campbell", "Weynberg", "DNV-RP-C205", "UNVERIFIED", "von Karman", "Wagner"):
        assert word in head


@pytest.mark.parametrize("row, c2", [("von_karman", lambda s, d: s * (d - s)), ("wagner", lambda s, d: 2 * d * s)])
def test_limits_follow_from_the_added_mass(row, c2):
    # F = d(m V)/dt = V^2 dm/ds with m = rho pi c^2 / 2: Cs = pi d(c^2)/ds / D as s -> 0
    d, rho, v, s, eps = 0.2, 1000.0, 5.0, 1e-7, 1e-9
    dm = rho * math.pi / 2 * (c2(s + eps, d) - c2(s - eps, d)) / (2 * eps)
    assert v**2 * dm / (0.5 * rho * v**2 * d) == pytest.approx(ce.reference()[row]["cs0"], rel=1e-5)


def test_fit_window_mean_is_its_integral():
    for a, b in [(0.0, 0.05), (0.05, 0.1), (0.2, 0.5), (0.0, 0.5)]:
        x = np.linspace(a, b, 200001)   # the trapezoid rule on a fine grid
        y = ce.cs_fit(x)
        assert ce.cs_fit_mean(a, b) == pytest.approx(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)) / (b - a), rel=1e-8)
    assert ce.cs_fit_mean(0.0, 0.05) == pytest.approx(3.63, abs=0.005)   # the number the docstring quotes


def test_window_means_recover_a_force_through_a_staircase():
    # steps of random length; each step's force is the step mean of F(s) = (a + b s/D) * 0.5 rho V^2 D times a
    # factor alternating 0.5 / 1.5 (the staircase's jumps); the impulse-based window means recover the mean
    # of a + b s/D over each window to the alternation's residue over one step
    rng = np.random.default_rng(1)
    dt = rng.uniform(0.5, 1.5, 4000) * 5e-6
    t = np.cumsum(dt)
    t0 = t - dt
    a, b = 3.0, -2.0
    q = 0.5 * ce.RHO * ce.V**2 * ce.D
    s0, s1 = ce.V * t0 / ce.D, ce.V * t / ce.D
    mean = a + b * 0.5 * (s0 + s1)
    force = q * mean * np.where(np.arange(t.size) % 2 == 0, 0.5, 1.5)
    edges = np.array([0.0, 0.05, 0.1, 0.2, 0.5])
    edges = edges[edges <= s1[-1]]
    cs = ce.window_means(t, force, edges)
    exact = a + b * 0.5 * (edges[:-1] + edges[1:])
    np.testing.assert_allclose(cs, exact, rtol=0.02)
    # and without the alternation to round-off and the within-step slope
    np.testing.assert_allclose(ce.window_means(t, q * mean, edges), exact, rtol=1e-4)
