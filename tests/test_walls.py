"""Wall conditions after one explicit step: what each kind does to the velocity next to it.

A stress-free, weightless block touching one side of the grid moves into that wall and along
it. After one PIC step (flip = 0) every particle's velocity is the interpolation of nodal
velocities; the wall's nodes have:
- slip: zero normal velocity, the tangential velocity kept;
- noslip: zero velocity;
- open: nothing imposed.
By partition of unity a component the wall leaves alone is kept exactly by every particle;
a component it removes is reduced for the particles next to the wall and kept exactly for
those whose stencil does not reach it.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import block_particles, make_sim

H = 0.1
N = 10  # cells per side
SIDES = {"left": (0, -1.0), "right": (0, 1.0), "bottom": (1, -1.0), "top": (1, 1.0)}  # normal axis, direction


def one_step(side: str, kind: str):
    axis, sign = SIDES[side]
    lo, hi = [0.3, 0.3], [0.7, 0.7]
    lo[axis], hi[axis] = (0.0, 0.3) if sign < 0 else (0.7, 1.0)   # the block touches the wall
    v = np.zeros(2)
    v[axis] = sign * 1.0          # into the wall
    v[1 - axis] = 0.5             # along it
    parts = block_particles(tuple(lo), tuple(hi), H, 2, 1000.0, v=tuple(v))
    walls = ["open"] * 4
    walls[["left", "right", "bottom", "top"].index(side)] = kind
    sim = make_sim(parts, ncell=(N, N), h=H, walls=walls, gravity=(0.0, 0.0), flip=0.0, shape="mpm",
                   update="usl", materials=[{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 1e3,
                                             "viscosity": 0.0}], dt=1e-4)
    x0 = parts["x"]
    sim.advance(1e-4)
    vel = sim.state()["v"]
    sim.close()
    dist = np.abs(x0[:, axis] - (0.0 if sign < 0 else 1.0))  # distance to the wall
    return vel, v, axis, dist


@pytest.mark.parametrize("side", SIDES)
def test_slip_wall_removes_the_normal_velocity_and_keeps_the_tangential(side):
    vel, v, axis, dist = one_step(side, "slip")
    np.testing.assert_allclose(vel[:, 1 - axis], v[1 - axis], rtol=0, atol=1e-12)
    near, far = dist < H, dist > 2 * H
    assert np.all(np.abs(vel[near, axis]) < 0.9 * abs(v[axis]))      # held back next to the wall
    np.testing.assert_allclose(vel[far, axis], v[axis], rtol=0, atol=1e-9)


@pytest.mark.parametrize("side", SIDES)
def test_noslip_wall_removes_both_components(side):
    vel, v, axis, dist = one_step(side, "noslip")
    near, far = dist < H, dist > 2 * H
    for c in (0, 1):
        assert np.all(np.abs(vel[near, c]) < 0.9 * abs(v[c]))
        np.testing.assert_allclose(vel[far, c], v[c], rtol=0, atol=1e-9)


@pytest.mark.parametrize("side", SIDES)
def test_open_side_imposes_nothing(side):
    vel, v, _, _ = one_step(side, "open")
    np.testing.assert_allclose(vel, np.tile(v, (len(vel), 1)), rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", ["slip", "noslip", "open"])
@pytest.mark.parametrize("side", SIDES)
def test_particles_beyond_a_closed_wall_are_held_on_it_and_counted(side, kind):
    """Impenetrability: a particle found beyond a closed wall (here the outer row of a block
    placed 0.01 m past it, inside the grid's padding) is put back on the wall by the next step,
    and the wall_clamps diagnostic counts the particles held in that step (8, then 0 once
    they sit on the wall). An open side holds nothing."""
    axis, sign = SIDES[side]
    parts = block_particles((0.3, 0.3), (0.7, 0.7), H, 2, 1000.0)
    parts["x"][:, axis] += sign * 0.335     # the outer row's centres 0.01 m past the wall
    wall = 1.0 if sign > 0 else 0.0
    beyond = sign * (parts["x"][:, axis] - wall) > 0
    walls = ["open"] * 4
    walls[list(SIDES).index(side)] = kind
    sim = make_sim(parts, ncell=(N, N), h=H, walls=walls, gravity=(0.0, 0.0), shape="mpm", dt=1e-4,
                   materials=[{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 1e3, "viscosity": 0.0}])
    sim.advance(1e-4)
    x, first = sim.state()["x"], sim.diagnostics()["wall_clamps"]
    sim.advance(2e-4)
    second = sim.diagnostics()["wall_clamps"]
    sim.close()
    assert beyond.sum() == 8   # the outer row
    if kind == "open":
        assert first == 0 and np.all(sign * (x[beyond, axis] - wall) > 0)
    else:
        np.testing.assert_array_equal(x[beyond, axis], wall)
        assert np.all(sign * (x[:, axis] - wall) <= 0)
        assert (first, second) == (beyond.sum(), 0)
