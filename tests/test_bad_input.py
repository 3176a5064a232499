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


# Boundary values of the particle and option checks (make mutate: `>` turned into `>=`, or an
# index into its neighbour, survived where only values far from the bound were tried).
@pytest.mark.parametrize("field, value, message", [
    ("mass", 0.0, "particle 3 has mass"), ("mass", np.inf, "particle 3 has mass"),
    ("vol", 0.0, "particle 3 has volume"), ("vol", np.inf, "particle 3 has volume"),
])
def test_particle_bounds_are_refused_naming_the_particle(field, value, message):
    parts = good_parts()
    parts[field] = parts[field].copy()
    parts[field][2] = value
    sim = Simulation()
    sim.set_grid((0, 0), (10, 10), 0.1)
    sim.set_materials([{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    with pytest.raises(CpdiError, match=message):
        sim.set_particles(**parts)
    sim.close()


@pytest.mark.parametrize("r", [[0.05, 0.0, 0.0, 0.0], [0.05, 0.02, 0.05, 0.02], [0.0, 0.05, 0.05, 0.0],
                               [0.05, 0.01, 0.01, 0.002]])
def test_degenerate_or_inverted_domain_is_refused_naming_the_particle(r):
    """r1 x r2 = r11 r22 - r21 r12 <= 0: zero area (a line), or clockwise (inverted)."""
    parts = good_parts()
    parts["r"] = parts["r"].copy()
    parts["r"][4] = r   # [r1x, r1y, r2x, r2y]
    sim = Simulation()
    sim.set_grid((0, 0), (10, 10), 0.1)
    sim.set_materials([{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    with pytest.raises(CpdiError, match="particle 5 has a degenerate or inverted domain"):
        sim.set_particles(**parts)
    ok = parts["r"][4].copy()
    parts["r"][4] = [0.05, 0.01, -0.01, 0.05]   # rotated, positive area: accepted
    sim.set_particles(**parts)
    parts["r"][4] = ok
    sim.close()


@pytest.mark.parametrize("options, message", [
    ({"lcrit": 1.0 + 1e-9}, "lcrit"), ({"lcrit": 0.0}, "lcrit"), ({"flip": 1.0 + 1e-9}, "flip"),
    ({"damping": 1.0}, "damping"), ({"projection_stabilization": 1.0 + 1e-9}, "stabilisation"),
])
def test_option_bounds_are_refused(options, message):
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match=message):
        sim.set_options(**options)
    edge = {k: (1.0 if k != "damping" else 0.999) for k in options}  # the bound itself is allowed
    if "lcrit" not in options or options["lcrit"] > 0:
        sim.set_options(**edge)
    sim.close()


def test_friction_must_be_finite():
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    n = len(good_parts()["x"])
    with pytest.raises(CpdiError, match="friction"):
        sim.set_bodies(np.ones(n, dtype=np.int32), contact=True, friction=np.inf)
    sim.set_bodies(np.ones(n, dtype=np.int32), contact=True, friction=1e300)
    sim.close()
