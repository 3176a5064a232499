"""Two-dimensional ideal-flow water entry at constant speed: von Karman, Wagner and the modified
Logvinovich model (MLM), for a wedge, a circle and a parabola (issue 40).

A symmetric rigid body y = f(x) - h(t) (f(0) = 0, f even, increasing in |x|) enters incompressible,
inviscid water at rest (free surface y = 0, no gravity, no surface tension) at constant speed V:
h = V t. Everything here is dimensionless in rho and V: pressures are p / (rho V^2) (so the pressure
coefficient is Cp = 2 p / (rho V^2)), forces per unit length are F / (rho V^2) (both sides of the body).

Models (the force is vertical, F = integral of p dx over the wetted projection, both sides):

- von Karman (1929): the wetted half-width is the body's intersection with the undisturbed surface,
  f(c) = h; F = d/dt(M V), M = rho pi c^2 / 2 the added mass of the flat plate of half-width c:
  F / (rho V^2) = pi c dc/dh. For the circle of diameter D (f = R - sqrt(R^2 - x^2)) this is
  c^2 = s (D - s), Cs = F / (0.5 rho V^2 D) = pi (1 - 2 s/D).
- Wagner (1932): c from Wagner's condition (the free surface meets the body),
      integral_0^{pi/2} f(c sin(theta)) d theta = (pi / 2) h,                                   (W)
  and F / (rho V^2) = pi c dc/dh (the flat-plate added mass with Wagner's c). For f = x^2 / (2 R) (the
  parabola, the circle's small-s form) c^2 = 4 R h = 2 D s, Cs = 2 pi for all s; for the wedge
  f = |x| tan(beta), c = pi h / (2 tan beta), F / (rho V^3 t) = pi (pi / (2 tan beta))^2. Wagner's peak
  pressure (the jet root, from the inner solution) is Cp_max = (dc/dh)^2 = (pi / (2 tan beta))^2.
  (Wagner 1932; Faltinsen 2005, ch. 8; Howison, Ockendon & Wilson 1991, JFM 222.)
- MLM (Korobkin 2004, Eur. J. Appl. Math. 15, 821-838; used in Tassin et al. 2014, Appl. Ocean Res.
  47, 33-41; Hulin et al. 2022, JFM 944): c from (W); the potential on the body is the first two terms
  of the Taylor expansion of the flat-plate (Wagner) potential about y = 0,
      phi(x, f(x) - h, t) = -V [sqrt(c^2 - x^2) + f(x) - h],                                    (L)
  and the pressure is Bernoulli's with the full (quadratic) velocity on the body surface, whose normal
  component is the body's (-V times the normal's y component) and tangential component d phi / ds. For
  constant V this gives (derivation below)
      p / (rho V^2) = c c_h / sqrt(c^2 - x^2) - (1/2) [1 + x^2 / ((c^2 - x^2) (1 + f'(x)^2))],    (P)
  c_h = dc/dh. The pressure is integrated where it is positive (it falls to -infinity at x -> c): the
  force is 2 integral_0^{x*} p dx, p(x*) = 0 (the implementation named below clips the same pressure at
  zero, which is the same integral).
  Derivation of (P): with n the body's normal, |grad phi|^2 = (phi_x^2 + V^2) / (1 + f'^2) (phi_x the
  x-derivative of (L) along the body); the time derivative at a fixed point is the derivative following
  the body point (x fixed, y moving at -V) plus V phi_y, phi_y = (phi_x f' - V) / (1 + f'^2); Bernoulli,
  p = -rho (phi_t + |grad phi|^2 / 2), then simplifies to (P). The same pressure (its 'slamming' and
  'jet' parts) is in the public Python MLM implementation of M. van der Eijk (Deltares) and P. Wellens
  (TU Delft), version 0.2 of 2024-10-24, read in the stored code index (not copied); the equation
  numbers of Korobkin (2004) were not checked here (the paper was not at hand).
  For the wedge (P) is self-similar in xi = x / c, with k = c_h = pi / (2 tan beta) and
  u = 1 / sqrt(1 - xi^2): Cp = 2 k u - 1 - cos^2(beta) (u^2 - 1), the peak Cp_max = k^2 / cos^2(beta)
  - sin^2(beta) at u = k / cos^2(beta), and the force has the closed form `wedge_mlm_closed_form`.

The generalised Wagner model (Zhao, Faltinsen & Aarsnes 1996) solves the body boundary condition on
the exact body with phi = 0 on y = f(c) - h, numerically (a boundary-element solve): not done here.

Validity: all three assume the wetted surface grows monotonically and the flow stays attached. For
the circle (W) reaches the widest point, c = R, at h = R (1 - 2/pi) (s/D = 0.1817, E(1) = 1): beyond
it the models above do not apply (flow separation; Tassin et al. 2014's fictitious body continuation
is not implemented), and `circle` refuses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_GL_X, _GL_W = np.polynomial.legendre.leggauss(400)


def _quad(fun, a: float, b: float) -> float:
    """Gauss-Legendre (400 nodes) of fun over [a, b]; fun takes an array."""
    x = 0.5 * (b - a) * _GL_X + 0.5 * (b + a)
    return float(0.5 * (b - a) * np.sum(_GL_W * fun(x)))


def _bisect(fun, a: float, b: float, tol: float = 1e-14) -> float:
    """A root of fun in [a, b] (fun(a), fun(b) of opposite signs), by bisection."""
    fa = fun(a)
    for _ in range(200):
        m = 0.5 * (a + b)
        fm = fun(m)
        if (fm > 0) == (fa > 0):
            a, fa = m, fm
        else:
            b = m
        if b - a < tol * max(1.0, abs(b)):
            break
    return 0.5 * (a + b)


@dataclass(frozen=True)
class Wedge:
    """f = |x| tan(beta), beta the deadrise angle in radians."""

    beta: float
    x_max: float = math.inf

    def f(self, x):
        return np.abs(x) * math.tan(self.beta)

    def fp(self, x):
        return np.sign(x) * math.tan(self.beta)


@dataclass(frozen=True)
class Circle:
    """f = R - sqrt(R^2 - x^2), |x| < R (the lower half of a circle of radius R)."""

    R: float

    @property
    def x_max(self) -> float:
        return self.R

    def f(self, x):
        return self.R - np.sqrt(np.maximum(self.R**2 - np.asarray(x) ** 2, 0.0))

    def fp(self, x):
        x = np.asarray(x)
        return x / np.sqrt(self.R**2 - x**2)


@dataclass(frozen=True)
class Parabola:
    """f = x^2 / (2 R): the circle's small-penetration form."""

    R: float
    x_max: float = math.inf

    def f(self, x):
        return np.asarray(x) ** 2 / (2.0 * self.R)

    def fp(self, x):
        return np.asarray(x) / self.R


def wagner_c(body, h: float) -> float:
    """Wagner's wetted half-width c(h) from (W), by bisection (Gauss-Legendre in theta)."""
    if h <= 0.0:
        return 0.0
    g = lambda c: _quad(lambda th: body.f(c * np.sin(th)), 0.0, 0.5 * math.pi) - 0.5 * math.pi * h  # noqa: E731
    hi = body.x_max
    if math.isinf(hi):
        hi = max(h, 1e-300)
        while g(hi) < 0.0:
            hi *= 2.0
    elif g(hi) < 0.0:
        raise ValueError(f"Wagner's condition has no root c < {hi} at h = {h}: the wetted surface has passed the "
                         "body's widest point (for a circle at h > R (1 - 2/pi))")
    return _bisect(g, 0.0, hi)


def wagner_c_h(body, c: float) -> float:
    """dc/dh from (W) differentiated: (pi/2) / integral_0^{pi/2} f'(c sin theta) sin theta d theta."""
    return 0.5 * math.pi / _quad(lambda th: body.fp(c * np.sin(th)) * np.sin(th), 0.0, 0.5 * math.pi)


def von_karman_c(body, h: float) -> float:
    """von Karman's half-width: f(c) = h (the undisturbed surface)."""
    hi = body.x_max if not math.isinf(body.x_max) else 1.0
    while math.isinf(body.x_max) and body.f(hi) < h:
        hi *= 2.0
    if body.f(hi) < h:
        raise ValueError(f"f(c) = {h} has no root c <= {hi}")
    return _bisect(lambda c: float(body.f(c)) - h, 0.0, hi)


def added_mass_force(c: float, c_h: float) -> float:
    """F / (rho V^2) = pi c dc/dh: the flat plate's added-mass force at constant speed (von Karman with
    the geometric c, Wagner with (W)'s c)."""
    return math.pi * c * c_h


def mlm_pressure(body, c: float, c_h: float, x):
    """MLM pressure p / (rho V^2) at |x| < c, formula (P) of the module docstring."""
    x = np.asarray(x, dtype=float)
    q = c * c - x * x
    return c * c_h / np.sqrt(q) - 0.5 * (1.0 + x * x / (q * (1.0 + body.fp(x) ** 2)))


def _mlm_p_theta(body, c: float, c_h: float, th):
    """(P) at x = c sin(theta): c_h / cos(theta) - (1/2)(1 + tan^2(theta) / (1 + f'^2))."""
    th = np.asarray(th, dtype=float)
    return c_h / np.cos(th) - 0.5 * (1.0 + np.tan(th) ** 2 / (1.0 + body.fp(c * np.sin(th)) ** 2))


def mlm_force(body, c: float, c_h: float, n_scan: int = 4000) -> tuple[float, float]:
    """MLM force F / (rho V^2) (both sides) and x*/c, the pressure integrated where it is positive.

    With x = c sin(theta), p dx = c [c_h - cos(theta)/2 - sin^2(theta) / (2 cos(theta) (1 + f'^2))] d theta,
    smooth up to the zero of p. The positive intervals are found on a scan of theta (their ends refined by
    bisection); the last one ends at x*, which is returned.
    """
    th = np.linspace(0.0, 0.5 * math.pi, n_scan + 1)[:-1]
    pos = _mlm_p_theta(body, c, c_h, th) > 0.0
    pfun = lambda t: float(_mlm_p_theta(body, c, c_h, t))  # noqa: E731
    integrand = lambda t: c_h - 0.5 * np.cos(t) - 0.5 * np.sin(t) ** 2 / (  # noqa: E731
        np.cos(t) * (1.0 + body.fp(c * np.sin(t)) ** 2))
    total, end = 0.0, 0.0
    i = 0
    while i < len(th):
        if not pos[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(th) and pos[j + 1]:
            j += 1
        a = 0.0 if i == 0 else _bisect(pfun, th[i - 1], th[i])
        b = _bisect(pfun, th[j], th[j + 1] if j + 1 < len(th) else 0.5 * math.pi * (1 - 1e-15))
        total += c * _quad(integrand, a, b)
        end = b
        i = j + 1
    return 2.0 * total, math.sin(end)


def circle(s_over_d: float, model: str = "mlm", D: float = 1.0) -> float:
    """Slamming coefficient Cs = F / (0.5 rho V^2 D) of the circle of diameter D at s/D, s = V t.

    model: 'mlm' (exact circle in (W) and (P)), 'wagner' (exact circle in (W), F = pi c c_h),
    'wagner_parabola' (2 pi), 'von_karman' (pi (1 - 2 s/D)). Raises ValueError past the widest point.
    """
    R, h = 0.5 * D, s_over_d * D
    if model == "von_karman":
        body = Circle(R)
        c = von_karman_c(body, h)
        return added_mass_force(c, (R - h) / c) / (0.5 * D)  # dc/dh from c^2 = 2 R h - h^2
    body = Parabola(R) if model == "wagner_parabola" else Circle(R)
    c = wagner_c(body, h)
    c_h = wagner_c_h(body, c)
    if model in ("wagner", "wagner_parabola"):
        return added_mass_force(c, c_h) / (0.5 * D)
    if model == "mlm":
        return mlm_force(body, c, c_h)[0] / (0.5 * D)
    raise ValueError(f"unknown model {model!r}")


def circle_window_mean(a: float, b: float, model: str = "mlm", n: int = 24) -> float:
    """Mean of Cs over a <= s/D <= b (Gauss-Legendre, n nodes): the impulse over the window / its length,
    as `cylinder_entry` measures it."""
    x, w = np.polynomial.legendre.leggauss(n)
    s = 0.5 * (b - a) * x + 0.5 * (b + a)
    return float(0.5 * np.sum(w * np.array([circle(v, model) for v in s])))


def circle_s_widest(D: float = 1.0) -> float:
    """s/D at which Wagner's c reaches R for the exact circle: (1 - 2/pi) / 2 (E(1) = 1 in (W))."""
    return 0.5 * (1.0 - 2.0 / math.pi)


def wedge(beta_deg: float) -> dict[str, float]:
    """Constant-speed wedge, deadrise beta_deg (self-similar): force coefficients F / (rho V^3 t), peak Cp
    and its height z/(V t) above the keel, for Wagner, von Karman and the MLM (computed with the general
    routines at h = 1, which the tests check against the closed forms)."""
    beta = math.radians(beta_deg)
    body = Wedge(beta)
    k = 0.5 * math.pi / math.tan(beta)
    c = wagner_c(body, 1.0)
    c_h = wagner_c_h(body, c)
    f_mlm, xi_star = mlm_force(body, c, c_h)
    u = max(k / math.cos(beta) ** 2, 1.0)
    xi_peak = math.sqrt(1.0 - 1.0 / u**2)
    return {
        "wagner_force": added_mass_force(c, c_h),
        "von_karman_force": added_mass_force(1.0 / math.tan(beta), 1.0 / math.tan(beta)),
        "mlm_force": f_mlm,
        "mlm_x_star_over_c": xi_star,
        "wagner_cp_max": c_h**2,
        "wagner_z_root": c * math.tan(beta),  # pi/2: the spray root's height z/(V t)
        "mlm_cp_max": 2.0 * float(mlm_pressure(body, c, c_h, xi_peak * c)),
        "mlm_z_peak": xi_peak * c * math.tan(beta),
    }


def wedge_mlm_closed_form(beta_deg: float) -> tuple[float, float]:
    """MLM wedge in closed form: F / (rho V^3 t) and Cp_max (module docstring), for the tests.

    Cp(u) = 2 k u - 1 - cos^2 b (u^2 - 1) = 0 at u*, xi* = sqrt(1 - 1/u*^2); F / (rho V^2 c) =
    2 [k asin xi* - xi*/2 - cos^2 b (atanh xi* - xi*) / 2], c = k V t.
    """
    b = math.radians(beta_deg)
    k = 0.5 * math.pi / math.tan(b)
    c2 = math.cos(b) ** 2
    u = (2.0 * k + math.sqrt(4.0 * k * k + 4.0 * c2 * (c2 - 1.0))) / (2.0 * c2)  # root of c2 u^2 - 2 k u + 1 - c2
    xi = math.sqrt(1.0 - 1.0 / u**2)
    f_over_c = 2.0 * (k * math.asin(xi) - 0.5 * xi - 0.5 * c2 * (math.atanh(xi) - xi))
    return k * f_over_c, k * k / c2 - (1.0 - c2)
