"""Interpolation identities for MPM, uGIMP and CPDI1 at random particles and domains.

For every particle p: sum_i S_ip = 1, sum_i grad S_ip = 0, sum_i S_ip x_i = x_p and
sum_i x_i (x) grad S_ip = I. CPDI domains are randomly sheared and stretched, including
domains larger than a cell that straddle several cells.
"""

import numpy as np
import pytest

from tests.conftest import make_sim

H = 0.1
NCELL = (12, 12)


def random_particles(rng, n, shape):
    x = rng.uniform(0.3, 0.9, size=(n, 2))
    if shape == "cpdi":
        # random linear map of a square domain: stretch up to 3 cells, shear, rotation
        r = np.empty((n, 4))
        for p in range(n):
            A = np.eye(2) + rng.uniform(-0.8, 0.8, size=(2, 2))
            while np.linalg.det(A) < 0.2:
                A = np.eye(2) + rng.uniform(-0.8, 0.8, size=(2, 2))
            half = rng.uniform(0.05, 1.5) * H
            r1, r2 = A @ [half, 0.0], A @ [0.0, half]
            r[p] = [*r1, *r2]
    elif shape == "gimp":
        half = rng.uniform(0.05, 0.5, size=(n, 2)) * H
        r = np.column_stack([half[:, 0], np.zeros(n), np.zeros(n), half[:, 1]])
    else:
        r = np.tile([H / 4, 0.0, 0.0, H / 4], (n, 1))
    vol = 4.0 * np.abs(r[:, 0] * r[:, 3] - r[:, 1] * r[:, 2])
    return dict(x=x, v=np.zeros((n, 2)), mass=1000 * vol, vol=vol, r=r, mat=np.zeros(n, dtype=np.int32))


@pytest.mark.parametrize("ncell, lift", [(NCELL, 0.0), ((14, 11), 0.0), ((12, 30), 1.8)],
                         ids=["square", "wide", "tall"])
@pytest.mark.parametrize("shape", ["mpm", "gimp", "cpdi"])
def test_partition_of_unity_and_linear_reproduction(shape, ncell, lift, rng):
    """(A wide grid as well: with a square one, node numbering by the wrong axis's count,
    i + (j - 1) nn(2) for i + (j - 1) nn(1), gives the same nodes; make mutate had it survive.
    And a tall one with the particles lifted above row nn(1), where only a tall grid tells the
    axes' counts apart. The fast path's row clamped by the column count, make mutate's
    shape:327, still passes here: those particles take the general path, same weights.)"""
    parts = random_particles(rng, 400, shape)
    parts["x"][:, 1] += lift
    sim = make_sim(parts, ncell=ncell, h=H, shape=shape)
    idx, w, gx, gy = sim.shape_functions()
    xi = sim.grid_info().node_xy(idx)  # (n, slots, 2)
    x = parts["x"]
    assert np.all(w >= -1e-15), "weights must be non-negative"
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=0, atol=1e-13)
    np.testing.assert_allclose(gx.sum(axis=1), 0.0, rtol=0, atol=1e-11 / H)
    np.testing.assert_allclose(gy.sum(axis=1), 0.0, rtol=0, atol=1e-11 / H)
    np.testing.assert_allclose(np.einsum("ps,psk->pk", w, xi), x, rtol=0, atol=1e-13)
    grad_x = np.stack([np.einsum("ps,ps->p", xi[..., a], g) for a in range(2) for g in (gx, gy)], axis=1)
    np.testing.assert_allclose(grad_x, np.tile([1.0, 0.0, 0.0, 1.0], (len(x), 1)), rtol=0, atol=1e-11)
    sim.close()


def test_cpdi_domains_really_straddle_cells(rng):
    """The random CPDI set-up above must exercise multi-cell domains (guards the test itself)."""
    parts = random_particles(rng, 400, "cpdi")
    sim = make_sim(parts, ncell=NCELL, h=H, shape="cpdi")
    idx, w, _, _ = sim.shape_functions()
    distinct = np.array([len(set(row[wr > 0])) for row, wr in zip(idx, w, strict=True)])
    assert distinct.max() >= 12, "some CPDI domain should touch many nodes"
    assert np.mean(distinct > 4) > 0.5
    sim.close()


def test_gimp_reduces_to_mpm_weights_away_from_particle_edges():
    """uGIMP with a tiny half-width approaches linear MPM (consistency of the two kernels)."""
    x = np.array([[0.537, 0.612]])
    out = {}
    for shape, half in (("mpm", H / 4), ("gimp", 1e-6 * H)):
        r = np.array([[half, 0.0, 0.0, half]])
        parts = dict(x=x, v=np.zeros((1, 2)), mass=np.ones(1), vol=np.full(1, 4 * half * half), r=r,
                     mat=np.zeros(1, dtype=np.int32))
        sim = make_sim(parts, ncell=NCELL, h=H, shape=shape)
        idx, w, _, _ = sim.shape_functions()
        out[shape] = {int(i): float(v) for i, v in zip(idx[0], w[0], strict=True) if v > 0}
        sim.close()
    assert out["mpm"].keys() == out["gimp"].keys()
    for k, v in out["mpm"].items():
        assert abs(out["gimp"][k] - v) < 1e-5


def test_cpdi_domains_are_carried_by_the_deformation(rng):
    """CPDI's domain vectors are material lines: a state of deformation gradient F carries each
    particle's reference vectors r0_k to r_k = F r0_k (tilted, sheared reference domains and
    general F, so that no term of the product vanishes), and the domain areas scale by det F."""
    parts = random_particles(rng, 50, "cpdi")
    n = len(parts["x"])
    sim = make_sim(parts, ncell=NCELL, h=H, shape="cpdi")
    F = np.column_stack([rng.uniform(0.8, 1.2, n), rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(0.8, 1.2, n)])
    sim.set_state(np.zeros((n, 2)), F, 0.0)
    r = sim.state()["r"]
    sim.close()
    Fm = np.stack([F[:, [0, 2]], F[:, [1, 3]]], axis=1)   # (n, 2, 2) from [F11, F21, F12, F22]
    r0 = parts["r"]
    expect = np.column_stack([np.einsum("pij,pj->pi", Fm, r0[:, :2]), np.einsum("pij,pj->pi", Fm, r0[:, 2:])])
    np.testing.assert_allclose(r, expect, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r[:, 0] * r[:, 3] - r[:, 1] * r[:, 2],
                               np.linalg.det(Fm) * (r0[:, 0] * r0[:, 3] - r0[:, 1] * r0[:, 2]), rtol=1e-12)
