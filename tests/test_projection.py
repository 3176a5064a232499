"""Volumetric projection: reproduction of fields in the lower-order space, conservation,
and 'none' leaving the solver untouched bit for bit."""

import numpy as np
import pytest

from harness.solver import CpdiError
from tests.conftest import block_particles, make_sim

H = 0.1


def sheared_block(rng, shape):
    """Particles in [0.3, 0.9]^2; CPDI domains randomly sheared, many spanning cells."""
    parts = block_particles((0.3, 0.3), (0.9, 0.9), H, 2, 1000.0)
    n = len(parts["x"])
    parts["x"] = parts["x"] + rng.uniform(-0.2, 0.2, size=(n, 2)) * H
    parts["mass"] = parts["mass"] * rng.uniform(0.5, 1.5, n)
    if shape == "cpdi":
        A = np.eye(2)[None] + rng.uniform(-0.4, 0.4, size=(n, 2, 2))
        d = H / 4
        parts["r"] = np.column_stack([A[:, :, 0] * d, A[:, :, 1] * d])
    return parts


@pytest.mark.parametrize("shape", ["mpm", "gimp", "cpdi"])
@pytest.mark.parametrize("mode", ["cell", "nodal"])
def test_projection_conserves_mass_weighted_integral(shape, mode, rng):
    parts = sheared_block(rng, shape)
    sim = make_sim(parts, ncell=(12, 12), h=H, shape=shape)
    theta = rng.normal(size=len(parts["x"]))
    out = sim.project(theta, mode)
    m = parts["mass"]
    assert np.sum(m * out) == pytest.approx(np.sum(m * theta), rel=1e-9, abs=1e-9 * np.sum(m * np.abs(theta)))
    assert np.std(out) < np.std(theta), "a projection must smooth a random field"
    sim.close()


@pytest.mark.parametrize("shape", ["mpm", "gimp", "cpdi"])
@pytest.mark.parametrize("mode", ["cell", "nodal"])
def test_constant_field_is_reproduced(shape, mode, rng):
    parts = sheared_block(rng, shape)
    sim = make_sim(parts, ncell=(12, 12), h=H, shape=shape)
    out = sim.project(np.full(len(parts["x"]), 3.25), mode)
    # cell: diagonal H, exact. nodal: H from point quadrature has near-singular modes; the
    # solve shifts the diagonal by 1e-12 and refines 4 times, leaving ~1e-9 (measured).
    np.testing.assert_allclose(out, 3.25, rtol=1e-13 if mode == "cell" else 1e-8)
    sim.close()


# grids: square, and tall and narrow with the particles high up (every row above the column count:
# an index of one axis bounded by the other's count shows)
GRIDS = {"square": ((12, 12), 0.0), "tall": ((12, 26), 1.4)}


@pytest.mark.parametrize("grid", GRIDS)
def test_cellwise_field_is_reproduced_by_cell_projection(rng, grid):
    """A cell-wise constant field on particles whose domains lie inside one cell."""
    ncell, lift = GRIDS[grid]
    parts = block_particles((0.3, 0.3 + lift), (0.9, 0.9 + lift), H, 2, 1000.0)  # domains are sub-cells
    sim = make_sim(parts, ncell=ncell, h=H, shape="cpdi")
    cell = np.floor(parts["x"] / H + 1e-9).astype(int)
    a = rng.normal(size=ncell)
    field = a[cell[:, 0], cell[:, 1]]
    np.testing.assert_allclose(sim.project(field, "cell"), field, rtol=0, atol=1e-13)
    sim.close()


def last_inside(lo, h, ncell):
    """The largest coordinate the weights place inside the last of ncell cells from lo
    ((x - lo)/h < ncell): the grid's last node line, or the float just below it."""
    x = lo + ncell * h
    while not (x - lo) / h < ncell:
        x = np.nextafter(x, -np.inf)
    return x


def test_cell_projection_uses_the_cells_the_weights_use_up_to_the_grids_edges(rng):
    """The cell projection is the mass-weighted mean over the particles in a cell, and the cell
    of a point is the one its weights are built on, also for points on the padded grid's edge
    lines. A point on the last node line can round to just inside the last cell ((1.2 + 0.2)/0.1
    < 14); the projection must put it there with its neighbours, not in a cell beyond the grid."""
    sim = make_sim(block_particles((0.3, 0.3), (0.5, 0.5), H, 1, 1000.0), ncell=(10, 10), h=H, shape="mpm")
    g = sim.grid_info()
    sim.close()
    ncell = np.array(g.nn) - 1
    hi = [last_inside(g.origin[d], g.h, ncell[d]) for d in range(2)]
    inner = g.origin + (ncell - 0.5) * g.h    # centres of the last cells' row and column
    edges = [[hi[0], 0.5], [inner[0], 0.5], [0.5, hi[1]], [0.5, inner[1]], [hi[0], hi[1]], [inner[0], inner[1]],
             [g.origin[0], 0.5], [g.origin[0] + 0.5 * g.h, 0.5], [0.5, g.origin[1]], [0.5, g.origin[1] + 0.5 * g.h]]
    parts = block_particles((0.3, 0.3), (0.9, 0.9), H, 2, 1000.0)
    n0 = len(parts["x"])
    parts["x"] = np.vstack([parts["x"] + rng.uniform(-0.2, 0.2, (n0, 2)) * H, edges])
    for k in ("v", "mass", "vol", "r", "mat"):
        parts[k] = np.concatenate([parts[k], parts[k][:len(edges)]])
    parts["mass"] = parts["mass"] * rng.uniform(0.5, 1.5, len(parts["mass"]))
    sim = make_sim(parts, ncell=(10, 10), h=H, shape="mpm")
    idx = sim.shape_functions()[0].min(axis=1)            # each point's lowest node: its cell's corner
    ci, cj = idx % g.nn[0], idx // g.nn[0]
    assert ci[n0] == ncell[0] - 1 and cj[n0 + 2] == ncell[1] - 1   # the edge points are in the last cells
    cell = ci + cj * ncell[0]
    field = rng.normal(size=len(cell))
    m = parts["mass"]
    mean = np.bincount(cell, m * field) / np.bincount(cell, m).clip(1e-300)
    np.testing.assert_allclose(sim.project(field, "cell"), mean[cell], rtol=0, atol=1e-13)
    sim.close()


@pytest.mark.parametrize("grid", GRIDS)
def test_nodal_field_is_reproduced_by_nodal_projection(rng, grid):
    """With point quadrature (MPM) a particle field sampled from a bilinear nodal field is in
    the space and must come back unchanged. (With domain quadrature a particle carries one
    value for its whole domain, so a non-constant nodal field is not exactly representable.)"""
    ncell, lift = GRIDS[grid]
    parts = sheared_block(rng, "mpm")
    parts["x"][:, 1] += lift
    sim = make_sim(parts, ncell=ncell, h=H, shape="mpm")
    x = parts["x"]
    field = 1.0 + 2.0 * x[:, 0] - 3.0 * x[:, 1] + 5.0 * x[:, 0] * x[:, 1]  # a global bilinear = nodal field
    out = sim.project(field, "nodal")
    np.testing.assert_allclose(out, field, rtol=0, atol=1e-9 * np.abs(field).max())
    sim.close()


def test_mask_leaves_other_particles_alone(rng):
    parts = sheared_block(rng, "cpdi")
    sim = make_sim(parts, ncell=(12, 12), h=H, shape="cpdi")
    theta = rng.normal(size=len(parts["x"]))
    mask = np.arange(len(theta)) % 2 == 0
    out = sim.project(theta, "cell", mask)
    np.testing.assert_array_equal(out[~mask], theta[~mask])
    assert not np.allclose(out[mask], theta[mask])
    sim.close()


@pytest.mark.parametrize("shape", ["mpm", "gimp", "cpdi"])
@pytest.mark.parametrize("mode", ["cell", "nodal"])
def test_a_particle_outside_the_grid_is_refused_not_projected(shape, mode):
    """A quadrature point beyond the grid has no cell or node to be projected in: `project`
    must say which particle is outside, not answer with the value of the clamped edge cell."""
    parts = block_particles((0.3, 0.3), (0.9, 0.9), H, 2, 1000.0)
    sim = make_sim(parts, ncell=(10, 10), h=H, shape=shape)
    g = sim.grid_info()
    top = g.origin[1] + (g.nn[1] - 1) * g.h
    parts["x"][5] = [0.5, top + 0.25 * H]   # above the padded grid's top node row
    sim.set_particles(**parts)
    with pytest.raises(CpdiError, match="particle 6 at .* lies outside the grid; enlarge") as ei:
        sim.project(np.ones(len(parts["x"])), mode)
    assert ei.value.kind == "outside"
    parts["x"][5] = [0.5, 0.5]   # back inside: the same simulation projects again
    sim.set_particles(**parts)
    out = sim.project(np.full(len(parts["x"]), 2.5), mode)
    np.testing.assert_allclose(out, 2.5, rtol=1e-13 if mode == "cell" else 1e-8)   # as for 3.25 above
    sim.close()


def water_drop(projection, project_water=True):
    parts = block_particles((0.3, 0.3), (0.7, 0.8), 0.05, 2, 1000.0, v=(0.5, -0.5))
    mats = [{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 2e6, "viscosity": 1e-3,
             "projection": project_water}]
    sim = make_sim(parts, ncell=(20, 20), h=0.05, walls=("slip",) * 4, materials=mats, shape="cpdi",
                   projection=projection, gravity=(0.0, -9.81))
    sim.advance(0.15)
    st = sim.state()
    sim.close()
    return st


def test_none_reproduces_the_unprojected_solver_bit_for_bit():
    """'none' and 'cell' with every material opted out run the same arithmetic: identical bits."""
    a = water_drop("none")
    b = water_drop("cell", project_water=False)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    c = water_drop("cell")  # and the projection, when it acts, changes the result
    assert not np.array_equal(a["sigma"], c["sigma"])


def randomly_strained_block(rng, projection):
    """A Hencky block (taking part in the projection) whose particles carry random small
    deformation gradients; the stress of that state refreshed. Returns (sim, sigma)."""
    parts = block_particles((0.3, 0.3), (0.7, 0.5), 0.05, 2, 1000.0)
    n = len(parts["x"])
    mats = [{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3, "projection": True}]
    F = np.column_stack([1 + rng.uniform(-0.05, 0.05, n), rng.uniform(-0.03, 0.03, (n, 2)),
                         1 + rng.uniform(-0.05, 0.05, n)])
    sim = make_sim(parts, ncell=(20, 20), h=0.05, materials=mats, shape="cpdi", projection=projection)
    sim.set_state(np.zeros((n, 2)), F, 0.0)
    sim.stable_dt()
    return sim, sim.state()["sigma"]


def mean_and_deviator(sig):
    m = (sig[:, 0] + sig[:, 1] + sig[:, 3]) / 3
    return m, sig - np.column_stack([m, m, 0 * m, m])


@pytest.mark.parametrize("mode", ["cell", "nodal"])
def test_projection_replaces_the_mean_stress_and_keeps_the_deviator(mode):
    """F-bar-type projection (Mast et al. 2012): the mean stress (sxx + syy + szz)/3 of every
    particle is replaced by the projection of the unprojected mean-stress field, its
    deviatoric part is left as it was (both to rounding, measured 2e-16 and 4e-16)."""
    raw, sig0 = randomly_strained_block(np.random.default_rng(7), "none")
    m0, dev0 = mean_and_deviator(sig0)
    expect = raw.project(m0, mode)
    raw.close()
    sim, sig1 = randomly_strained_block(np.random.default_rng(7), mode)
    sim.close()
    m1, dev1 = mean_and_deviator(sig1)
    scale = np.abs(m0).max()
    assert np.abs(m1 - m0).max() > 0.5 * scale, "the projection must act on this field for the test to mean anything"
    np.testing.assert_allclose(m1, expect, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(dev1, dev0, rtol=0, atol=1e-13 * np.abs(dev0).max())


def wavy_block(projection, beta):
    """An elastic block with a smooth velocity field falling for 0.05 s (125 steps)."""
    parts = block_particles((0.3, 0.3), (0.7, 0.5), 0.05, 2, 1000.0)
    x = parts["x"]
    parts["v"] = 0.3 * np.column_stack([np.sin(8 * x[:, 1]), np.cos(6 * x[:, 0])])
    mats = [{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3, "projection": True}]
    sim = make_sim(parts, ncell=(20, 20), h=0.05, materials=mats, shape="cpdi", projection=projection,
                   projection_stabilization=beta, gravity=(0.0, -9.81))
    sim.advance(0.05)
    st = sim.state()
    sim.close()
    return st


@pytest.mark.parametrize("mode", ["cell", "nodal"])
def test_full_stabilisation_is_no_projection(mode):
    """The stabilised increment is (1 - beta) projected + beta raw: beta = 1 keeps every
    particle's own volumetric strain and mean stress, i.e. the unprojected solver (to rounding:
    J is exp(log(det)) there; measured 7e-13 of the largest stress after 125 steps); beta = 1/2
    is not."""
    ref = wavy_block("none", 0.0)
    full = wavy_block(mode, 1.0)
    for k in ref:
        np.testing.assert_allclose(full[k], ref[k], rtol=0, atol=1e-11 * np.abs(ref[k]).max())
    half = wavy_block(mode, 0.5)
    assert np.abs(half["sigma"] - ref["sigma"]).max() > 0.1 * np.abs(ref["sigma"]).max()


@pytest.mark.parametrize("projection", ["cell", "nodal"])
def test_a_simulation_given_a_new_grid_runs_as_one_built_on_it(projection):
    # the same particles on a finer grid of the same tank, set on a simulation that already ran
    # on the coarse one: the run is the one a fresh simulation on the fine grid makes, bit for bit
    # (the projection's storage follows the grid's node count)
    mats = [{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 2e6, "viscosity": 1e-3}]
    parts = block_particles((0.3, 0.3), (0.7, 0.8), 0.05, 2, 1000.0, v=(0.5, -0.5))
    opts = dict(shape="cpdi", projection=projection, gravity=(0.0, -9.81))
    reused = make_sim(parts, ncell=(10, 10), h=0.1, walls=("slip",) * 4, materials=mats, **opts)
    reused.advance(0.02)
    reused.set_grid((0.0, 0.0), (20, 20), 0.05, ["slip"] * 4)
    reused.set_particles(**parts)
    fresh = make_sim(parts, ncell=(20, 20), h=0.05, walls=("slip",) * 4, materials=mats, **opts)
    for sim in (reused, fresh):
        sim.advance(0.05)
    a, b = reused.state(), fresh.state()
    reused.close()
    fresh.close()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("mode", ["cell", "nodal"])
@pytest.mark.parametrize("material", ["hencky", "water"])
def test_a_uniformly_compressed_confined_body_keeps_its_stress_through_steps(mode, material):
    """Equilibrium: a body filling a tank of slip walls, compressed uniformly (F = 0.99 I), has a
    uniform stress whose internal forces the walls hold, so it stays at rest and keeps that
    stress step after step, with the projection on (a uniform field is its own projection).
    This is the stress the steps project (the step's second use of its operator, after the
    volumetric strain increment), not the one a refresh of the state projects; measured to 1e-15
    (cell) and 1e-11 (nodal: a Cholesky solve) of the stress after 20 steps. (With the stress scatter of a step's second
    projection reading empty strips the mean stress went to 0 in the first step.)"""
    mats = {"hencky": {"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                       "projection": True},
            "water": {"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 2e6, "viscosity": 0.0}}
    parts = block_particles((0.0, 0.0), (1.0, 1.0), H, 2, 1000.0)
    n = len(parts["x"])
    sim = make_sim(parts, ncell=(10, 10), h=H, walls=("slip",) * 4, materials=[mats[material]], shape="cpdi",
                   projection=mode)
    sim.set_state(np.zeros((n, 2)), np.tile([0.99, 0.0, 0.0, 0.99], (n, 1)), 0.0)
    sim.stable_dt()
    sig0 = sim.state()["sigma"]
    assert np.abs(sig0[:, 0]).min() > 1e3, "the body must be stressed for the test to mean anything"
    steps, _ = sim.advance(1.0, max_steps=20)
    st = sim.state()
    sim.close()
    scale = np.abs(sig0).max()
    np.testing.assert_allclose(st["sigma"], sig0, rtol=0, atol=1e-10 * scale)
    assert steps == 20 and np.abs(st["v"]).max() < 1e-12
