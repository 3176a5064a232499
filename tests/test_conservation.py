"""Momentum balance of the explicit step."""

import numpy as np
import pytest

from tests.conftest import block_particles, make_sim

H = 0.05


@pytest.mark.parametrize("shape", ["mpm", "gimp", "cpdi"])
@pytest.mark.parametrize("update", ["usl", "musl"])
def test_free_flying_block_conserves_momentum(shape, update, rng):
    """No gravity, no walls: internal forces sum to zero, so total momentum is constant.

    USL with linear MPM goes unstable when a lone particle of a stressed body enters an
    empty cell (tiny nodal mass, O(1/h) gradient: the textbook USL cell-crossing
    instability); that combination is tested without bulk drift so no particle crosses.
    """
    drift = (0.0, 0.0) if (shape, update) == ("mpm", "usl") else (0.3, -0.2)
    parts = block_particles((0.4, 0.4), (0.7, 0.6), H, 2, 1000.0, v=drift)
    # smooth internal velocity field so the block deforms (white noise would excite USL null modes)
    x = parts["x"]
    parts["v"] = parts["v"] + 0.05 * np.column_stack([np.sin(20 * x[:, 1]), np.cos(15 * x[:, 0])])
    sim = make_sim(parts, ncell=(22, 20), h=H, shape=shape, update=update, gravity=(0.0, 0.0), cfl=0.3)
    p0 = (parts["mass"][:, None] * parts["v"]).sum(axis=0)
    steps, _ = sim.advance(0.05)
    d = sim.diagnostics()
    scale = parts["mass"].sum() * 0.4
    assert steps > 50
    assert abs(d["momentum_x"] - p0[0]) < 1e-13 * scale * steps
    assert abs(d["momentum_y"] - p0[1]) < 1e-13 * scale * steps
    s = sim.state()
    assert np.abs(s["sigma"]).max() > 10.0, "the block must actually deform for the test to mean anything"
    sim.close()


@pytest.mark.parametrize("grid", [((20, 20), (0.3, 0.6), (0.6, 0.9)), ((8, 36), (0.1, 1.4), (0.35, 1.7))],
                         ids=["square", "tall"])
@pytest.mark.parametrize("shape", ["mpm", "gimp", "cpdi"])
def test_momentum_grows_as_m_g_t_under_gravity(shape, grid):
    """(Also on a tall, narrow grid with the block high up, where a node count taken from the
    narrow axis alone would be too small.)"""
    ncell, lo, hi = grid
    parts = block_particles(lo, hi, H, 2, 1000.0)
    g = -9.81
    sim = make_sim(parts, ncell=ncell, h=H, shape=shape, gravity=(0.0, g))
    _, t = sim.advance(0.1)
    d = sim.diagnostics()
    M = parts["mass"].sum()
    assert d["mass"] == pytest.approx(M, rel=1e-15)
    assert d["momentum_y"] == pytest.approx(M * g * t, rel=1e-12)
    assert abs(d["momentum_x"]) < 1e-12 * abs(M * g * t)
    sim.close()


@pytest.mark.parametrize("update", ["usl", "musl"])
@pytest.mark.parametrize("rigid", [False, True], ids=["one_field", "with_a_rigid_body"])
def test_work_of_gravity_and_body_force_is_their_potential_released(update, rigid):
    """Each step the particles move by dx = dt v, so the gravity_work and body_force_work
    diagnostics are sum m g . (x - x0) and sum m b . (x - x0) over the run (the sums over the
    steps telescope), to rounding (measured 1e-15). A block thrown with a smooth internal velocity
    field under gravity and a body force varying along x; with a rigid body at rest elsewhere the
    solver's other grid-to-particle path does the bookkeeping."""
    parts = block_particles((0.3, 0.5), (0.6, 0.7), H, 2, 1000.0, v=(0.2, 0.3))
    x = parts["x"]
    parts["v"] = parts["v"] + 0.05 * np.column_stack([np.sin(20 * x[:, 1]), np.cos(15 * x[:, 0])])
    materials = None
    if rigid:
        slab = block_particles((0.2, 0.1), (0.8, 0.2), H, 2, 2000.0)
        slab["mat"][:] = 1
        parts = {k: np.concatenate([parts[k], slab[k]]) for k in parts}
        materials = [{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3},
                     {"model": "rigid", "density": 2000.0, "velocity": [0.0, 0.0]}]
    x, m, g = parts["x"], parts["mass"], np.array([0.0, -9.81])
    sim = make_sim(parts, ncell=(20, 20), h=H, gravity=tuple(g), update=update, materials=materials)
    b = np.column_stack([np.full(len(x), 2.0), 1.0 + x[:, 0]])
    sim.set_body_force(b)
    v0 = parts["v"].copy()
    steps, t = sim.advance(0.1)
    st, d = sim.state(), sim.diagnostics()
    dx = st["x"] - x
    sim.close()
    assert steps > 100 and np.abs(dx).max() > 0.02
    assert d["gravity_work"] == pytest.approx((m[:, None] * g * dx).sum(), rel=1e-12)
    assert d["body_force_work"] == pytest.approx((m[:, None] * b * dx).sum(), rel=1e-12)
    # and the forces that did the work are these: the free block's momentum grows by
    # t sum m (g + b) (internal forces cancel; the rigid slab, apart from it, is held)
    blk = parts["mat"] == 0
    dp = (m[blk, None] * (st["v"][blk] - v0[blk])).sum(axis=0)
    np.testing.assert_allclose(dp, t * (m[blk, None] * (g + b[blk])).sum(axis=0), rtol=1e-10)


@pytest.mark.parametrize(("gravity", "v0"), [((0.0, -9.81), (0.0, -1.0)), ((0.0, -9.81), (0.0, 3.0)),
                                             ((-9.81, 0.0), (-1.0, 0.0)), ((-9.81, 0.0), (3.0, 0.0))],
                         ids=["falling", "thrown_up", "falling_along_x", "thrown_against_x"])
def test_local_damping_opposes_the_motion_by_alpha_times_the_force(gravity, v0):
    """Cundall's local damping, f - alpha |f| sign(v) on every node: a free block in uniform motion
    under gravity alone (no stress, no walls) feels f = m g at each node, so it accelerates at
    g (1 - alpha) while it moves along g and decelerates at g (1 + alpha) while it moves against
    it, in either axis: v = v0 + (g - alpha |g| sign(v0)) t for every particle."""
    alpha = 0.1
    parts = block_particles((0.4, 0.4), (0.6, 0.6), H, 2, 1000.0, v=v0)
    sim = make_sim(parts, ncell=(40, 40), h=H, origin=(-0.5, -0.5), gravity=gravity, damping=alpha, cfl=0.3)
    _, t = sim.advance(0.1)
    v = sim.state()["v"]
    sim.close()
    g, v0 = np.asarray(gravity), np.asarray(v0)
    expected = v0 + (g - alpha * np.abs(g) * np.sign(v0)) * t
    np.testing.assert_allclose(v, np.tile(expected, (len(v), 1)), rtol=0, atol=1e-9 * np.abs(expected).max())
