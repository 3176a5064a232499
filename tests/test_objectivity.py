"""Objectivity: rigid rotation of an elastic body produces no stress."""

import numpy as np
import pytest

from harness.solver import CpdiError
from tests.conftest import block_particles, make_sim

E = 1.0e6


def rotation(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([c, s, -s, c])  # [F11, F21, F12, F22]


@pytest.mark.parametrize("model", ["hencky", "neo_hookean"])
def test_stress_of_rotated_state_is_zero(model, rng):
    parts = block_particles((0.4, 0.4), (0.6, 0.6), 0.05, 2, 1000.0)
    mat = [{"model": model, "density": 1000.0, "youngs_modulus": E, "poisson_ratio": 0.3}]
    sim = make_sim(parts, ncell=(20, 20), h=0.05, materials=mat)
    n = len(parts["x"])
    F = np.array([rotation(t) for t in rng.uniform(-np.pi, np.pi, n)])
    sim.set_state(np.zeros((n, 2)), F, 0.0)
    sim.stable_dt()  # refreshes the stress of the imposed state
    assert np.abs(sim.state()["sigma"]).max() < 1e-9 * E
    # and a stretched state is not stress free (the check can fail)
    sim.set_state(np.zeros((n, 2)), np.tile([1.01, 0.0, 0.0, 1.0], (n, 1)), 0.0)
    sim.stable_dt()
    assert np.abs(sim.state()["sigma"]).max() > 1e-3 * E
    sim.close()


def spin(kinematics, update="musl"):
    """A stiff block spun at omega = 1 rad/s for 30 degrees; returns max |sigma| / E."""
    h = 0.02
    parts = block_particles((0.4, 0.4), (0.6, 0.6), h, 2, 1000.0)
    c = np.array([0.5, 0.5])
    rel = parts["x"] - c
    parts["v"] = np.column_stack([-rel[:, 1], rel[:, 0]])  # omega = 1
    sim = make_sim(parts, ncell=(50, 50), h=h, gravity=(0.0, 0.0), cfl=0.3, kinematics=kinematics, update=update,
                   materials=[{"model": "hencky", "density": 1000.0, "youngs_modulus": E, "poisson_ratio": 0.3}])
    try:
        sim.advance(np.pi / 6)
    except CpdiError:
        return float("inf")  # the body tore itself apart: as non-objective as it gets
    smax = np.abs(sim.state()["sigma"][:, :3]).max() / E
    sim.close()
    return smax


@pytest.mark.parametrize("update", ["musl", "usl"])
def test_spinning_block_stays_stress_free_with_log_strain(update):
    """A non-objective law sees eps = sym(R) - I = (cos 30deg - 1) I, i.e. |sigma| ~ 0.13 E.

    With log strain the physical (centrifugal) stress is rho omega^2 R^2 ~ 1e-5 E; what
    remains is discretisation: measured 1.5e-3 E (MUSL, CPDI) at the block's corners,
    2.4e-4 E median, from MUSL's smoothing remap of the rotating velocity field; 3.2e-4 E with
    USL (the velocity gradient from the grid velocity itself).
    """
    finite = spin("log", update)
    small = spin("small", update)
    print(f"max |sigma|/E after 30 deg: log strain {finite:.2e}, small strain {small:.2e}")
    assert finite < 3e-3
    assert small > 40 * finite, "small-strain kinematics is not objective and must show it"
