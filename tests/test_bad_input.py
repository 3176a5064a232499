"""Bad input at the API raises CpdiError naming the problem; the interpreter carries on."""

import numpy as np
import pytest

from harness.solver import CpdiError, Simulation
from tests.conftest import block_particles, make_sim


def good_parts():
    return block_particles((0.4, 0.4), (0.6, 0.6), 0.1, 2, 1000.0)


def test_negative_density():
    sim = Simulation()
    with pytest.raises(CpdiError, match="density") as ei:
        sim.set_materials([{"model": "hencky", "density": -5.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    assert ei.value.kind == "input"
    sim.set_materials([{"model": "hencky", "density": 5.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    sim.close()


def test_zero_cell_size():
    sim = Simulation()
    with pytest.raises(CpdiError, match="cell size"):
        sim.set_grid((0, 0), (10, 10), 0.0)
    sim.set_grid((0, 0), (10, 10), 0.1)
    sim.close()


def test_particle_outside_grid():
    parts = good_parts()
    parts["x"][3] = [5.0, 5.0]
    sim = make_sim(parts, ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match="left the grid") as ei:
        sim.advance(0.01)
    assert ei.value.kind == "outside"
    assert "particle 4" in str(ei.value)
    sim.close()


@pytest.mark.parametrize("field", ["x", "v", "vol", "mass"])
def test_nan_in_particle_data(field):
    parts = good_parts()
    parts[field] = parts[field].astype(float)
    parts[field].flat[0] = np.nan
    sim = Simulation()
    sim.set_grid((0, 0), (10, 10), 0.1)
    sim.set_materials([{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    with pytest.raises(CpdiError, match="NaN|positive and finite"):
        sim.set_particles(**parts)
    sim.close()


def test_nan_option_and_unstable_fixed_dt():
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match="NaN"):
        sim.set_options(gravity=(np.nan, 0.0))
    sim.set_options(dt=1.0)  # far above h / c
    with pytest.raises(CpdiError, match="exceeds the stable limit") as ei:
        sim.advance(1.0)
    assert ei.value.kind == "cfl"
    sim.close()


def test_wrong_shapes_are_refused():
    sim = Simulation()
    sim.set_grid((0, 0), (10, 10), 0.1)
    sim.set_materials([{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    parts = good_parts()
    parts["vol"] = parts["vol"][:-1]
    with pytest.raises(CpdiError, match="shape"):
        sim.set_particles(**parts)
    sim.close()


def test_freed_handle_and_state_errors():
    sim = Simulation()
    with pytest.raises(CpdiError, match="before stepping"):
        sim.advance(1.0)
    h = sim._handle
    sim.close()
    from harness.solver import _call

    with pytest.raises(CpdiError, match="freed"):
        _call("cpdi_advance", h, 1.0, 10)


def test_unknown_material_index():
    parts = good_parts()
    parts["mat"][:] = 3
    sim = make_sim(parts, ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match="material 4 but only 1"):
        sim.advance(0.01)
    sim.close()
