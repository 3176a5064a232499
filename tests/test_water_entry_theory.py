"""harness/problems/water_entry_theory.py: the 2D constant-speed water-entry models (von Karman, Wagner,
modified Logvinovich) against their closed forms and limits (issue 40; docs/notes/cylinder_entry.md).

No published MLM or fully nonlinear number was found to check against (the notes say what was searched);
the tests check the formulas against independent derivations: Wagner's closed forms (Wagner 1932;
Faltinsen 2005 ch. 8, as reference/data/wedge_entry_wagner_similarity.csv holds them), the circle's Wagner
condition against the complete elliptic integral E computed by the arithmetic-geometric mean, the MLM
pressure against Bernoulli's equation evaluated by finite differences of the MLM potential, and the MLM
wedge force against its closed-form integral.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness import refdata
from harness.problems import water_entry_theory as w

TWO_PI = 2.0 * math.pi


def ellipe(k: float) -> float:
    """Complete elliptic integral of the second kind E(k) (modulus k) by the AGM (Abramowitz & Stegun 17.6)."""
    a, b, c = 1.0, math.sqrt(1.0 - k * k), k
    s, p = 0.5 * c * c, 0.5
    for _ in range(40):
        a, b, c = 0.5 * (a + b), math.sqrt(a * b), 0.5 * (a - b)
        p *= 2.0
        s += p * c * c
        if c < 1e-16:
            break
    return 0.5 * math.pi / a * (1.0 - s)


@pytest.mark.parametrize("beta_deg", [10.0, 20.0, 30.0])
def test_wedge_wagner_matches_reference_file(beta_deg):
    """Wagner's c/(Vt), Cp_max and F/(rho V^3 t), and von Karman's force, from the general routines (Wagner's
    condition solved by quadrature and bisection) equal the closed forms in the wedge reference file."""
    ref = refdata.read("wedge_entry_wagner_similarity.csv")
    i = int(np.flatnonzero(ref["beta_deg"] == beta_deg)[0])
    got = w.wedge(beta_deg)
    c = w.wagner_c(w.Wedge(math.radians(beta_deg)), 1.0)
    assert c == pytest.approx(ref["wagner_c_over_Vt"][i], rel=2e-5)
    assert got["wagner_cp_max"] == pytest.approx(ref["wagner_cp_max"][i], rel=2e-5)
    assert got["wagner_force"] == pytest.approx(ref["wagner_force_coef"][i], rel=2e-5)
    assert got["von_karman_force"] == pytest.approx(ref["von_karman_force_coef"][i], rel=2e-5)
    assert got["wagner_z_root"] == pytest.approx(0.5 * math.pi, rel=1e-12)


def test_circle_wagner_condition_is_the_elliptic_integral():
    """For the exact circle Wagner's condition is h = R (1 - (2/pi) E(c/R)); the quadrature solution obeys it,
    tends to the parabola's c^2 = 4 R h for small h, and the wetted surface reaches the widest point at
    h = R (1 - 2/pi), past which the routine refuses."""
    R = 0.5
    body = w.Circle(R)
    for h in (1e-4, 0.01, 0.05, 0.1, 0.15):
        c = w.wagner_c(body, h)
        assert R * (1.0 - 2.0 / math.pi * ellipe(c / R)) == pytest.approx(h, rel=1e-9)
    assert w.wagner_c(body, 1e-6) == pytest.approx(math.sqrt(4 * R * 1e-6), rel=1e-5)
    h_w = R * (1.0 - 2.0 / math.pi)
    assert w.circle_s_widest() == pytest.approx(h_w / (2 * R))
    assert w.wagner_c(body, h_w * (1 - 1e-6)) > 0.999 * R
    with pytest.raises(ValueError):
        w.wagner_c(body, h_w * (1 + 1e-6))


def test_wagner_c_h_is_the_derivative_of_c():
    """dc/dh from the differentiated condition equals the finite difference of c(h) (circle and wedge)."""
    for body, h in ((w.Circle(0.5), 0.07), (w.Circle(0.5), 0.15), (w.Wedge(math.radians(25)), 0.3)):
        dh = 1e-6 * h
        fd = (w.wagner_c(body, h + dh) - w.wagner_c(body, h - dh)) / (2 * dh)
        assert w.wagner_c_h(body, w.wagner_c(body, h)) == pytest.approx(fd, rel=1e-6)


def test_circle_limits():
    """Von Karman's Cs = pi (1 - 2 s/D); Wagner's 2 pi for the parabola; the exact circle's Wagner force and
    the MLM's tend to 2 pi as s -> 0 (the MLM slowly: its nonlinear terms vanish like c log c), from below,
    and the MLM lies below Wagner's."""
    for s in (0.01, 0.1, 0.3):
        assert w.circle(s, "von_karman") == pytest.approx(math.pi * (1 - 2 * s), rel=1e-9)
    for s in (1e-4, 0.05, 0.3):
        assert w.circle(s, "wagner_parabola") == pytest.approx(TWO_PI, rel=1e-9)
    errs = [1.0 - w.circle(s, "mlm") / TWO_PI for s in (1e-2, 1e-4, 1e-6)]
    assert all(e > 0 for e in errs) and errs[0] > errs[1] > errs[2]
    assert errs[2] < 0.005
    assert 1.0 - w.circle(1e-6, "wagner") / TWO_PI < 1e-5
    for s in (0.01, 0.05, 0.1):
        assert w.circle(s, "mlm") < w.circle(s, "wagner") < TWO_PI


def _bernoulli_pressure(body, h: float, x: float) -> float:
    """p / (rho V^2), V = 1, at the body point (x, f(x) - h) from the MLM potential on the body,
    phi_b(x, h) = -[sqrt(c(h)^2 - x^2) + f(x) - h], by finite differences, without the simplification:
    |grad phi|^2 = (phi_x^2 + 1)/(1 + f'^2) (tangential d phi/ds and the body's normal velocity), and
    phi_t at a fixed point = (d phi_b/dt following the body point, x fixed) + phi_y, with
    phi_y = (phi_x f' - 1)/(1 + f'^2); p = -(phi_t + |grad phi|^2 / 2)."""
    def phi_b(xx, hh):
        c = w.wagner_c(body, hh)
        return -(math.sqrt(c * c - xx * xx) + float(body.f(xx)) - hh)

    dh, dx = 1e-6 * h, 1e-6 * max(x, 1e-3)
    phi_t_body = (phi_b(x, h + dh) - phi_b(x, h - dh)) / (2 * dh)
    phi_x = (phi_b(x + dx, h) - phi_b(x - dx, h)) / (2 * dx)
    fp = float(body.fp(x))
    phi_y = (phi_x * fp - 1.0) / (1.0 + fp * fp)
    grad2 = (phi_x**2 + 1.0) / (1.0 + fp * fp)
    return -(phi_t_body + phi_y + 0.5 * grad2)


@pytest.mark.parametrize("body,h", [(w.Wedge(math.radians(30)), 0.2), (w.Wedge(math.radians(10)), 0.05),
                                    (w.Circle(0.5), 0.05), (w.Circle(0.5), 0.12)])
def test_mlm_pressure_is_bernoulli_of_the_mlm_potential(body, h):
    """Formula (P) equals Bernoulli's pressure of the potential (L) computed without the algebra."""
    c = w.wagner_c(body, h)
    c_h = w.wagner_c_h(body, c)
    for xi in (0.0, 0.3, 0.7, 0.95):
        x = xi * c
        assert float(w.mlm_pressure(body, c, c_h, x)) == pytest.approx(_bernoulli_pressure(body, h, x),
                                                                       rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("beta_deg", [10.0, 20.0, 30.0, 45.0])
def test_wedge_mlm_force_closed_form_and_similarity(beta_deg):
    """The MLM wedge force from the general quadrature equals its closed form, grows linearly in t (the flow
    is self-similar), lies between von Karman's and Wagner's, and the peak Cp equals k^2/cos^2 b - sin^2 b."""
    f_closed, cp_closed = w.wedge_mlm_closed_form(beta_deg)
    got = w.wedge(beta_deg)
    assert got["mlm_force"] == pytest.approx(f_closed, rel=1e-9)
    assert got["mlm_cp_max"] == pytest.approx(cp_closed, rel=1e-9)
    body = w.Wedge(math.radians(beta_deg))
    for h in (0.013, 0.37):
        c = w.wagner_c(body, h)
        assert w.mlm_force(body, c, w.wagner_c_h(body, c))[0] / h == pytest.approx(f_closed, rel=1e-9)
    assert got["von_karman_force"] < got["mlm_force"] < got["wagner_force"]


def test_mlm_30_degree_values():
    """The numbers the notes quote (docs/notes/wedge_entry.md, cylinder_entry.md), so that a change to the
    module that moves them fails here: MLM F/(rho V^3 t) = 15.09 at 30 degrees (0.649 of Wagner's 23.25),
    and the circle's window means 4.38, 2.97, 1.94 over s/D 0-0.05, 0.05-0.1, 0.1-0.15."""
    assert w.wedge(30.0)["mlm_force"] == pytest.approx(15.0857, abs=1e-3)
    means = [w.circle_window_mean(a, b) for a, b in ((0.0, 0.05), (0.05, 0.1), (0.1, 0.15))]
    assert means == pytest.approx([4.3756, 2.9701, 1.9375], abs=2e-3)
