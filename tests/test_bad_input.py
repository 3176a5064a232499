"""Bad input at the API raises CpdiError naming the problem; the interpreter carries on."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from harness.solver import CpdiError, Simulation
from tests.conftest import block_particles, make_sim

REPO = Path(__file__).resolve().parent.parent


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


@pytest.mark.parametrize("projection", ["cell", "nodal"])
def test_particle_outside_grid_with_projection_is_refused_before_the_first_step(projection):
    """The volumetric projection sets up its operator when the run is prepared, before any step
    checks the particles: a particle outside the grid is refused there, by name."""
    parts = good_parts()
    parts["x"][3] = [5.0, 5.0]
    sim = make_sim(parts, ncell=(10, 10), h=0.1, projection=projection)
    with pytest.raises(CpdiError, match="particle 4 at .* lies outside the grid; enlarge") as ei:
        sim.advance(0.01)
    assert ei.value.kind == "outside"
    np.testing.assert_array_equal(sim.state()["x"], parts["x"])   # no step was taken
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
    sim.set_grid((0, 0), (10, 10), 0.1)   # a grid alone, then without particles: still refused
    with pytest.raises(CpdiError, match="before stepping"):
        sim.advance(1.0)
    sim.set_materials([{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    with pytest.raises(CpdiError, match="before stepping"):
        sim.advance(1.0)
    h = sim._handle
    sim.close()
    from harness.solver import _call

    with pytest.raises(CpdiError, match="freed"):
        _call("cpdi_advance", h, 1.0, 10)


@pytest.mark.parametrize("indices, named", [((3,), "particle 1 has material 4 but only 1"),
                                             ((-1,), "particle 1 has material 0 but only 1"),
                                             ((0, -1, 3), "particle 2 has material 0 but only 1")])
def test_unknown_material_index(indices, named):
    """Material indices beyond the list, below it, and both in one particle set (each check
    alone must see its own; the first bad particle is named)."""
    parts = good_parts()
    parts["mat"][:] = 0
    parts["mat"][:len(indices)] = indices
    sim = make_sim(parts, ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match=named):
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
    ({"cfl": 0.0}, "cfl"), ({"cfl": 1.0 + 1e-9}, "cfl"),
    ({"lcrit": 1.0 + 1e-9}, "lcrit"), ({"lcrit": 0.0}, "lcrit"), ({"flip": 1.0 + 1e-9}, "flip"),
    ({"damping": 1.0}, "damping"), ({"projection_stabilization": 1.0 + 1e-9}, "projection_stabilization"),
])
def test_option_bounds_are_refused(options, message):
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match=message):
        sim.set_options(**options)
    edge = {k: (1.0 if k != "damping" else 0.999) for k in options}  # the bound itself is allowed
    if next(iter(options.values())) > 0:   # (the upper bound; at a lower bound of 0, 0 is the refused value)
        sim.set_options(**edge)
    sim.close()


@pytest.mark.parametrize("fullness", [-1e-9, 1.0 + 1e-9, -np.inf, np.inf, np.nan])
def test_contact_fullness_outside_a_cell_is_refused(fullness):
    # the fraction of a cell that supports a body must lie in [0, 1]; both bounds are allowed
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    body = np.ones(len(good_parts()["x"]), dtype=np.int32)
    with pytest.raises(CpdiError, match="fullness"):
        sim.set_bodies(body, contact=True, fullness=fullness)
    sim.set_bodies(body, contact=True, fullness=0.0)
    sim.set_bodies(body, contact=True, fullness=1.0)
    sim.close()


def test_friction_must_be_finite():
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    n = len(good_parts()["x"])
    with pytest.raises(CpdiError, match="friction"):
        sim.set_bodies(np.ones(n, dtype=np.int32), contact=True, friction=np.inf)
    sim.set_bodies(np.ones(n, dtype=np.int32), contact=True, friction=1e300)
    sim.close()


@pytest.mark.parametrize("gravity", [(-np.inf, 0.0), (0.0, np.inf)])
def test_infinite_option_is_refused(gravity):
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match="NaN or Inf"):
        sim.set_options(gravity=gravity)
    sim.close()


def test_gimp_half_width_beyond_half_a_cell_is_refused():
    """uGIMP needs 0 < half-width <= h/2 along each axis; a tilted domain's half-width along y
    is |r1y| + |r2y| (here 0.04 + 0.02 > 0.05), though r2 alone stays within."""
    parts = good_parts()
    parts["r"] = parts["r"].copy()
    parts["r"][4] = [0.02, 0.04, 0.0, 0.02]
    sim = make_sim(parts, ncell=(10, 10), h=0.1, shape="gimp")
    with pytest.raises(CpdiError, match="particle 5 has GIMP half-widths"):
        sim.advance(0.01)
    sim.close()


@pytest.mark.parametrize("over, refused", [(0.0, False), (1, False), (1e-9, True)])
def test_gimp_half_width_of_half_a_cell_is_allowed_up_to_rounding(over, refused):
    """One particle per cell has half-width h/2 exactly in theory; computed (0.3/6 against
    0.1/2) it may be an ulp or so above. The bound allows a relative 1e-12 of rounding: h/2 and
    the next double above it run, h/2 (1 + 1e-9) is refused."""
    h = 0.1
    lp = h / 2 if over == 0.0 else (np.nextafter(h / 2, 1.0) if over == 1 else h / 2 * (1 + over))
    parts = block_particles((0.4, 0.4), (0.6, 0.6), h, 1, 1000.0)
    parts["r"] = np.tile([lp, 0.0, 0.0, lp], (len(parts["x"]), 1))
    sim = make_sim(parts, ncell=(10, 10), h=h, shape="gimp")
    if refused:
        with pytest.raises(CpdiError, match="GIMP half-widths"):
            sim.advance(0.001)
    else:
        sim.advance(0.001)
    sim.close()


def test_stress_that_overflows_is_reported_naming_the_particle():
    """A finite, valid state whose stress is not finite: neo-Hookean F = diag(1e160, 1e-160)
    (det F = 1) has b11 = 1e320 = Inf. Refreshing the stress reports it with the particle."""
    parts = good_parts()
    n = len(parts["x"])
    sim = make_sim(parts, ncell=(10, 10), h=0.1, materials=[{"model": "neo_hookean", "density": 1000.0,
                                                             "youngs_modulus": 1e6, "poisson_ratio": 0.3}])
    F = np.tile([1.0, 0.0, 0.0, 1.0], (n, 1))
    F[6] = [1e160, 0.0, 0.0, 1e-160]
    sim.set_state(np.zeros((n, 2)), F, 0.0)
    with pytest.raises(CpdiError, match="NaN or Inf in the stress or velocity of particle 7") as ei:
        sim.stable_dt()
    assert ei.value.kind == "nan"
    sim.close()


def test_speed_that_overflows_is_reported_naming_the_particle():
    """A finite velocity whose magnitude overflows (1e200 m/s: |v|^2 = Inf) is a non-finite
    signal speed: reported as such, not taken as a zero time step."""
    parts = good_parts()
    n = len(parts["x"])
    sim = make_sim(parts, ncell=(10, 10), h=0.1)
    v = np.zeros((n, 2))
    v[6] = [1e200, 0.0]
    sim.set_state(v, np.tile([1.0, 0.0, 0.0, 1.0], (n, 1)), 0.0)
    with pytest.raises(CpdiError, match="NaN or Inf in the stress or velocity of particle 7"):
        sim.stable_dt()
    sim.close()


def test_full_state_with_every_dimension_wrong_is_refused():
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    full = sim.get_full_state()
    with pytest.raises(CpdiError, match="rows per particle"):
        sim.set_full_state(full["particles"][:-1], full["scalars"][:-1])
    sim.close()


def test_incompressible_queries_refuse_bad_calls():
    """The raw API: face velocities or cell pressures for (nx, ny) that are not the grid's (both
    wrong), and the face-lattice transfer of a freed simulation, are errors, not reads out of
    bounds."""
    from harness.solver import _call

    water = block_particles((0.0, 0.0), (0.4, 0.3), 0.05, 2, 1000.0)
    sim = make_sim(water, ncell=(10, 10), h=0.05, walls=("slip", "slip", "slip", "open"), fluid="incompressible",
                   materials=[{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 1.0, "viscosity": 0.0}],
                   gravity=(0.0, -9.81))
    sim.advance(0.01)
    for query in ("cpdi_face_velocity", "cpdi_grid_pressure"):
        with pytest.raises(CpdiError, match="cell counts"):
            _call(query, sim._handle, 11, 12)
    handle = sim._handle
    sim.close()
    with pytest.raises(CpdiError, match="freed"):
        _call("cpdi_transfer_cycle", handle)


@pytest.mark.parametrize("ncell", [(1, 33333330), (33333330, 1)])
def test_grid_beyond_2e8_nodes_is_refused_before_any_allocation(ncell):
    """(1 + 1 + 4) x (33333330 + 1 + 4) = 2.0000001e8 nodes (padding included): refused as input.
    Run in a child process limited to 8 GB of address space, so that a check that let it pass
    fails to allocate (20 GB) instead of filling the machine's memory."""
    code = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))\n"
        "from harness.solver import CpdiError, Simulation\n"
        "sim = Simulation()\n"
        "try:\n"
        f"    sim.set_grid((0.0, 0.0), {ncell!r}, 1.0)\n"
        "except CpdiError as e:\n"
        "    print(e.kind, e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("input ") and "more than 2e8 nodes" in out.stdout, out.stdout


@pytest.mark.parametrize("name", ["domain_scaling", "fixed_dt"])
@pytest.mark.parametrize("value", [2.0, -1.0, 0.5])
def test_option_flags_are_zero_or_one(name, value):
    """domain_scaling and fixed_dt reach the Fortran API as numbers; a caller other than
    Simulation.set_options (which passes bools) can give anything: 2, -1 and 0.5 are refused."""
    from harness.solver import _call

    sim = Simulation()
    with pytest.raises(CpdiError, match=f"{name} is a flag: 0 or 1"):
        _call("cpdi_set_option", sim._handle, name, [value])
    _call("cpdi_set_option", sim._handle, name, [1.0])
    sim.close()


@pytest.mark.parametrize("name, values, message", [
    ("shape", [3.0], "shape must be one of 0 (mpm), 1 (gimp), 2 (cpdi), got 3"),
    ("shape", [1.5], "shape must be one of"),
    ("cfl", [0.0], "cfl = 0 must lie in (0, 1]"),
    ("cg_max_iterations", [2.5], "cg_max_iterations must be a whole number, got 2.5"),
    ("cg_max_iterations", [1.0e9], "cg_max_iterations = 1000000000 must lie in [0, 1000000000)"),
    ("gravity", [0.0], "gravity takes 2 value(s), got 1"),
    ("cfll", [0.3], "unknown solver option 'cfll'; use one of: shape, update"),
])
def test_the_option_table_refuses_in_one_place(name, values, message):
    """cpdi_set_option checks every option against its row of the Fortran table (kind, components,
    range), naming the option and what it accepts; the refused value is not stored."""
    from harness.solver import _call

    sim = Simulation()
    with pytest.raises(CpdiError) as ei:
        _call("cpdi_set_option", sim._handle, name, values)
    assert message in str(ei.value), str(ei.value)
    sim.close()


@pytest.mark.parametrize("options, message", [
    ({"transfer": "apic"}, "transfer = 'apic' is available with fluid = 'incompressible' only"),
    ({"dt": 0.0}, "a fixed time step dt must be positive"),
])
def test_rules_between_options_are_refused(options, message):
    """The rules between two rows of the table (cpdi_check_options): Simulation.set_options
    runs them, and so does cpdi_advance for a caller that sets options one by one."""
    from harness.solver import _call

    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1)
    with pytest.raises(CpdiError, match=message):
        sim.set_options(**options)
    sim.set_options()
    _call("cpdi_set_option", sim._handle, "transfer", [1.0])   # apic, the water weakly compressible
    with pytest.raises(CpdiError, match="apic"):
        sim.advance(1e-4)
    sim.close()


def test_unknown_set_options_keyword_is_refused():
    sim = Simulation()
    with pytest.raises(CpdiError, match="unknown solver option 'cfll'"):
        sim.set_options(cfll=0.3)
    with pytest.raises(CpdiError, match="unknown solver option 'fixed_dt'"):
        sim.set_options(fixed_dt=True)   # set by giving dt
    sim.close()


def test_a_step_that_underflows_to_zero_is_refused():
    """cfl may be any number in (0, 1]; the smallest positive double makes cfl h / c round to
    0 s. Such a step must be refused with the fix named, not taken: steps of 0 s never reach
    t_end (the run would only stop at max_steps, having done nothing)."""
    sim = make_sim(good_parts(), ncell=(10, 10), h=0.1, cfl=5e-324)
    with pytest.raises(CpdiError, match="time step is zero"):
        sim.advance(0.01, max_steps=5)
    sim.close()
