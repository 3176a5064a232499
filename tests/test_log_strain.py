"""Logarithmic strain 1/2 log(F F^T): closed form and LAPACK dsyev against numpy."""

import numpy as np
import pytest

from harness.solver import CpdiError, log_strain


def numpy_log_strain(F):
    out = []
    for f in F:
        Fm = np.array([[f[0], f[2]], [f[1], f[3]]])
        w, V = np.linalg.eigh(Fm @ Fm.T)
        E = 0.5 * V @ np.diag(np.log(w)) @ V.T
        out.append([E[0, 0], E[1, 1], E[0, 1]])
    return np.array(out)


def random_F(rng, n, spread):
    F = []
    while len(F) < n:
        f = np.array([1.0, 0.0, 0.0, 1.0]) + rng.uniform(-spread, spread, 4)
        if f[0] * f[3] - f[1] * f[2] > 0.02:
            F.append(f)
    return np.array(F)


@pytest.mark.parametrize("spread", [1e-6, 1e-3, 0.3, 0.9])
@pytest.mark.parametrize("method", ["closed", "lapack"])
def test_log_strain_matches_numpy(rng, spread, method):
    F = random_F(rng, 500, spread)
    np.testing.assert_allclose(log_strain(F, method), numpy_log_strain(F), rtol=0, atol=1e-12)


def test_closed_form_matches_lapack_at_large_stretch(rng):
    F = random_F(rng, 200, 0.5) * rng.uniform(0.3, 3.0, size=(200, 1))
    np.testing.assert_allclose(log_strain(F, "closed"), log_strain(F, "lapack"), rtol=0, atol=1e-12)


def test_log_strain_known_values():
    # pure stretch: eps = log(lambda); simple shear gamma: eps12 = asinh(gamma/2)/... via numpy
    F = np.array([[2.0, 0.0, 0.0, 0.5], [1.0, 0.0, 0.7, 1.0]])
    e = log_strain(F)
    assert e[0] == pytest.approx([np.log(2.0), np.log(0.5), 0.0], abs=1e-15)
    np.testing.assert_allclose(e[1], numpy_log_strain(F[1:])[0], atol=1e-14)
    assert e[1, 0] + e[1, 1] == pytest.approx(0.0, abs=1e-14), "simple shear is isochoric: tr eps = ln J = 0"


def test_log_strain_refuses_inverted_F():
    with pytest.raises(CpdiError, match="det F <= 0"):
        log_strain(np.array([[1.0, 0.0, 0.0, -1.0]]))
