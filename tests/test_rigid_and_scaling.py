"""Rigid material (prescribed velocity, clamps the grid) and Homel CPDI domain scaling."""

import numpy as np
import pytest

from harness.solver import Simulation
from tests.conftest import block_particles

H = 0.02


def two_bodies(rigid_velocity=(0.0, 0.0), update="musl"):
    slab = block_particles((0.2, 0.2), (0.8, 0.3), H, 2, 2000.0)
    block = block_particles((0.4, 0.34), (0.6, 0.44), H, 2, 1000.0)
    block["mat"][:] = 1
    parts = {k: np.concatenate([slab[k], block[k]]) for k in slab}
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (50, 50), H, ("open",) * 4)
    sim.set_materials([{"model": "rigid", "density": 2000.0, "velocity": rigid_velocity},
                       {"model": "hencky", "density": 1000.0, "youngs_modulus": 2e5, "poisson_ratio": 0.3}])
    sim.set_particles(**parts)
    sim.set_options(shape="cpdi", gravity=(0.0, -9.81), cfl=0.3, update=update)
    return sim, len(slab["x"]), parts


@pytest.mark.parametrize("update", ["musl", "usl"])
def test_rigid_slab_stops_a_falling_block_and_does_not_move(update):
    """The block falls 0.04 m (impact ~0.09 s) and bounces elastically on the slab; free fall
    would have taken its centre 0.78 m lower by t = 0.4 s. (With USL the block's strain rate
    comes from the grid velocity the rigid nodes clamp, on the solver's path for rigid bodies.)"""
    sim, ns, parts = two_bodies(update=update)
    lowest = np.inf
    for t in np.linspace(0.02, 0.4, 20):
        sim.advance(t)
        lowest = min(lowest, sim.state()["x"][ns:, 1].min())
    s = sim.state()
    np.testing.assert_array_equal(s["x"][:ns], parts["x"][:ns])  # rigid particles never move
    assert np.all(s["v"][:ns] == 0.0)
    assert lowest > 0.3 - 0.75 * H, "the block must not sink into the rigid slab"
    assert 0.32 < s["x"][ns:, 1].mean() < 0.40, "the block's centre must stay near its rest height 0.35"
    sim.close()


def test_rigid_body_moves_with_its_prescribed_velocity():
    sim, ns, parts = two_bodies(rigid_velocity=(0.1, 0.0))
    _, t = sim.advance(0.05)
    s = sim.state()
    np.testing.assert_allclose(s["x"][:ns, 0], parts["x"][:ns, 0] + 0.1 * t, rtol=0, atol=1e-12)
    sim.close()


@pytest.mark.parametrize("update", ["musl", "usl"])
def test_rigid_slab_and_the_block_on_it_translate_together_exactly(update):
    """A rigid slab driven at U = (0.1, 0.2) m/s (no gravity) with an elastic block lying on it
    (one continuum, sharing the nodes the slab clamps), the block moving at U too: the whole is a
    rigid translation, which the transfers reproduce exactly: every particle moves U t and keeps
    U (measured: 1e-13 relative, 1e-15 m/s). The slab's nodes get U from its clamp, the block's
    from its own momentum; a wrong clamp in either direction shows at the block's bottom."""
    U = np.array([0.1, 0.2])
    slab = block_particles((0.2, 0.2), (0.8, 0.3), H, 2, 2000.0, v=U)
    block = block_particles((0.4, 0.3), (0.6, 0.4), H, 2, 1000.0, v=U)
    block["mat"][:] = 1
    parts = {k: np.concatenate([slab[k], block[k]]) for k in slab}
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (50, 50), H, ("open",) * 4)
    sim.set_materials([{"model": "rigid", "density": 2000.0, "velocity": list(U)},
                       {"model": "hencky", "density": 1000.0, "youngs_modulus": 2e5, "poisson_ratio": 0.3}])
    sim.set_particles(**parts)
    sim.set_options(shape="cpdi", gravity=(0.0, 0.0), cfl=0.3, update=update)
    _, t = sim.advance(0.2)
    s = sim.state()
    sim.close()
    np.testing.assert_allclose(s["x"], parts["x"] + U * t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s["v"], np.tile(U, (len(s["v"]), 1)), rtol=0, atol=1e-12)


@pytest.mark.parametrize("scaling", [False, True])
def test_homel_domain_scaling_limits_domain_diagonals(scaling):
    parts = block_particles((0.3, 0.3), (0.5, 0.5), H, 1, 1000.0)  # half-width h/2: diagonals start at 0.707 h
    n = len(parts["x"])
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (50, 50), H, ("open",) * 4)
    sim.set_materials([{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    sim.set_particles(**parts)
    sim.set_options(shape="cpdi", gravity=(0.0, 0.0), domain_scaling=scaling, dt=1e-9)
    sim.set_state(np.zeros((n, 2)), np.tile([1.8, 0.0, 0.3, 1.0 / 1.8], (n, 1)), 0.0)
    sim.advance(1e-9)  # one step: domains are rebuilt from F
    r = sim.state()["r"]
    la = np.hypot(r[:, 0] + r[:, 2], r[:, 1] + r[:, 3])
    lb = np.hypot(r[:, 0] - r[:, 2], r[:, 1] - r[:, 3])
    longest = max(la.max(), lb.max())
    if scaling:
        assert longest <= 0.49999 * H * (1 + 1e-12)
        idx, w, gx, gy = sim.shape_functions()  # scaled domains still interpolate exactly
        np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-13)
    else:
        assert longest > 0.9 * H
    sim.close()
