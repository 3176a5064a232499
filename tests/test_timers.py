"""The phase timers (Simulation.timers): wall-clock seconds spent in each phase of the steps,
accumulated over the run. They are measurements, so the tests hold what every measurement must
satisfy: each is non-negative, the steps' phases took some time, and together they took no
longer than the advance that ran them."""

import time

import numpy as np
import pytest

from harness.solver import TIMER_NAMES
from tests.conftest import block_particles, make_sim


@pytest.mark.parametrize("fluid", ["weakly_compressible", "incompressible"])
def test_phase_timers_add_up_to_at_most_the_wall_time(fluid):
    if fluid == "incompressible":
        parts = block_particles((0.0, 0.0), (0.4, 0.3), 0.05, 2, 1000.0)
        mats = [{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 1.0, "viscosity": 0.0}]
    else:
        parts = block_particles((0.3, 0.3), (0.6, 0.5), 0.05, 2, 1000.0)
        mats = None
    sim = make_sim(parts, ncell=(20, 20), h=0.05, walls=("slip", "slip", "slip", "open"), materials=mats,
                   fluid=fluid, gravity=(0.0, -9.81), projection="none")
    sim.stable_dt()   # preparation is not a step
    before = sim.timers()
    t0 = time.perf_counter()
    steps, _ = sim.advance(0.2)
    wall = time.perf_counter() - t0
    after = sim.timers()
    sim.close()
    values = np.array([after[k] - before[k] for k in TIMER_NAMES])
    assert steps >= 5
    assert np.all(values >= 0.0)
    assert values.sum() > 0.0
    assert values.sum() <= wall + 1e-3   # (the clocks' resolution)
