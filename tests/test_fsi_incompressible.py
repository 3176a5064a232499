"""Solids coupled two-way with the incompressible water (cpdi_fsi; docs/fsi_incompressible.md).
coupling = "batty" (the default): the pressure lives in the water's cells, the solid enters each
cell's constraint through its boundary flux (cpdi_coupling; the operator's own tests, exact
Archimedes for a hydrostatic pressure among them, are fortran/tests/test_coupling.f90).
coupling = "mixture": the solid's mass joins the water's on the MAC faces and the projection runs
over water and solid cells with the mixture's face densities. Rigid bodies bound the water with
their velocity in both.

Small tanks (1 m x 0.5 m of water, h = 0.05 m, 2 x 2 particles per cell) stepped through
Simulation.advance."""

import numpy as np
import pytest

from harness.solver import CpdiError, Simulation

H_CELL, WIDTH, DEPTH, RHO, G = 0.05, 1.0, 0.5, 1000.0, 9.81


def tank_with_block(rho_s, block, *, rigid_velocity=None, E=1.0e6, h=H_CELL, coupling="batty"):
    """Water DEPTH deep in a WIDTH-wide tank (slip walls, open top), a block ((x0, y0), (x1, y1))
    of Hencky material of density rho_s (or rigid, moving with rigid_velocity) replacing the
    water it covers. Returns the prepared simulation and the number of water particles."""
    d = h / 2
    xs, ys = np.arange(d / 2, WIDTH, d), np.arange(d / 2, DEPTH, d)
    xx, yy = np.meshgrid(xs, ys, indexing="xy")
    xw = np.column_stack([xx.ravel(), yy.ravel()])
    (x0, y0), (x1, y1) = block
    xw = xw[~((xw[:, 0] > x0) & (xw[:, 0] < x1) & (xw[:, 1] > y0) & (xw[:, 1] < y1))]
    bx, by = np.meshgrid(np.arange(x0 + d / 2, x1, d), np.arange(y0 + d / 2, y1, d), indexing="xy")
    xb = np.column_stack([bx.ravel(), by.ravel()])
    x = np.vstack([xw, xb])
    n, nw = len(x), len(xw)
    vol = np.full(n, d * d)
    mat = np.r_[np.zeros(nw, int), np.ones(n - nw, int)]
    v = np.zeros((n, 2))
    if rigid_velocity is None:
        solid = {"model": "hencky", "density": rho_s, "youngs_modulus": E, "poisson_ratio": 0.3}
    else:
        solid = {"model": "rigid", "density": rho_s, "velocity": list(rigid_velocity)}
        v[nw:] = rigid_velocity
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (round(WIDTH / h), round(1.0 / h)), h,
                 {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0}, solid])
    sim.set_particles(x, v, np.where(mat == 0, RHO, rho_s) * vol, vol, np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)),
                      mat)
    sim.set_bodies(mat)
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99, coupling=coupling)
    return sim, nw


def hydrostatic_cells(h=H_CELL):
    ny = round(1.0 / h)
    yc = (np.arange(ny) + 0.5) * h
    return RHO * G * (DEPTH - yc)


def test_mixture_submerged_solid_at_rest_feels_exactly_the_buoyancy():
    # coupling = "mixture": a neutrally buoyant block (the one density at which a free solid in
    # resting water is at rest): the water's force on it is rho_w g V, the state stays at rest,
    # and the pressure is hydrostatic in every cell, the solid's included (the face densities are
    # the mixture's: the projection holds the solid's volume, and its pressure carries its weight)
    block = ((0.4, 0.1), (0.6, 0.3))
    vol = 0.2 * 0.2
    sim, nw = tank_with_block(RHO, block, coupling="mixture")
    sim.advance(1.0, max_steps=1)
    f1 = sim.solid_force()
    steps, t = sim.advance(0.5)
    f, st, grid = sim.solid_force(), sim.state(), sim.grid_pressure()
    sim.close()
    buoyancy = RHO * G * vol
    # measured 2e-10 after one step and 8e-12 after 0.5 s
    assert abs(f1[1] - buoyancy) <= 1e-6 * buoyancy and abs(f1[0]) <= 1e-6 * buoyancy
    assert abs(f[1] - buoyancy) <= 1e-6 * buoyancy and abs(f[0]) <= 1e-6 * buoyancy
    assert np.abs(st["v"]).max() <= 1e-6 * G * t / steps   # measured 3e-10 m/s
    occupied = grid["water"] == 1
    assert occupied.sum() == 20 * 10
    exact = np.tile(hydrostatic_cells(), (20, 1))
    np.testing.assert_allclose(grid["pressure"][occupied], exact[occupied], rtol=1e-6)


def test_batty_neutral_block_released_unstressed_feels_the_buoyancy_on_average():
    # coupling = "batty": the pressure acts on the solid's boundary only, so an elastic block
    # released without stress in resting water is not in equilibrium: the water's load
    # compresses it (its breathing mode, undamped, moves the whole water column) and its first
    # step feels 0.30 of rho_w g V. Neutrally buoyant, it must feel rho_w g V on average and stay
    # where it is. (That a hydrostatic pressure gives exactly rho_w g V, to 1e-15, is
    # fortran/tests/test_coupling.f90.) Measured over 0.5 s: mean force 1 + 9.8e-4, centre of mass
    # 1.5 mm down at 4.8e-3 m/s, strain energy 0.23 J.
    block = ((0.4, 0.1), (0.6, 0.3))
    buoyancy = RHO * G * 0.2 * 0.2
    sim, nw = tank_with_block(RHO, block)
    t, impulse = 0.0, 0.0
    while t < 0.5:
        t_old = t
        _, t = sim.advance(1.0, max_steps=1)
        impulse += sim.solid_force()[1] * (t - t_old)
    st = sim.state()
    sim.close()
    assert impulse / t == pytest.approx(buoyancy, rel=0.01)
    assert abs(st["x"][nw:, 1].mean() - 0.2) <= 0.01 * 0.2      # 1 % of the block's size
    assert abs(st["v"][nw:, 1].mean()) <= 0.01 * G * t          # 1 % of free fall's velocity


def test_batty_heavy_block_sinks_with_its_added_mass_and_lands():
    # coupling = "batty": a block of density 1500 released at rest 0.1 m under the surface
    # accelerates at g (rho_s - rho_w) / (rho_s + C rho_w), C = 1.19 the added mass of a square
    # per rho_w b^2 in unbounded water (1.51 rho_w pi b^2 / 4): 1.82 m/s^2 (measured over the first
    # 0.1 s: 1.80); it lands on the floor (its bottom within half a cell, measured 0.002 m) and
    # stays; the energy, with the volume correction's lift, is not created (measured: at most
    # +0.06 J, against the 39 J the sink releases). coupling = "mixture" parks the block 0.045 m
    # up and its correction lifts the water by 97 J.
    rho_s, b = 1500.0, 0.2
    sim, nw = tank_with_block(rho_s, ((0.4, 0.2), (0.6, 0.4)))
    released = (rho_s - RHO) * G * b * b * 0.2
    _, t = sim.advance(0.1, land=False)
    v01 = sim.state()["v"][nw:, 1].mean()
    a_expected = G * (rho_s - RHO) / (rho_s + 1.19 * RHO)
    assert -v01 / t == pytest.approx(a_expected, rel=0.15)
    excess, bottoms = [], []
    for k in range(2, 13):
        sim.advance(0.1 * k, land=False)
        st, d = sim.state(), sim.diagnostics()
        excess.append(d["kinetic_energy"] + d["strain_energy"] - d["gravity_work"] - d["correction_work"])
        bottoms.append(st["x"][nw:, 1].min() - H_CELL / 4)   # the bottom row's domains reach h/4 down
    sim.close()
    assert max(excess) <= 0.01 * released
    assert max(abs(y) for y in bottoms[-5:]) <= H_CELL / 2


@pytest.mark.parametrize("coupling", ["batty", "mixture"])
def test_no_pressure_spike_next_to_a_floating_solid(coupling):
    # a block of density 500 floating at Archimedes' draft (0.1 m of its 0.2 m): after it has
    # settled, the pressure of the water cells touching it (below and beside) is the far
    # field's hydrostatic pressure at their depth: no spike on the first fluid layer
    block = ((0.3, 0.4), (0.7, 0.6))
    sim, nw = tank_with_block(500.0, block, coupling=coupling)
    sim.advance(2.0)
    grid, f = sim.grid_pressure(), sim.solid_force()
    sim.close()
    p = grid["pressure"]
    exact = hydrostatic_cells()
    below = p[6:14, 7]                       # cells (6..13, 7): centres 0.025 m under the block
    beside = np.r_[p[5, 8:10], p[14, 8:10]]  # the water cells left and right of its wet part
    scale = RHO * G * 0.1
    # measured at 2 s: below within 0.23 % (batty 0.017 %) of rho g d, beside within 0.41 % (batty 0.23 %)
    assert np.abs(below - exact[7]).max() <= 0.02 * scale
    assert np.abs(beside - np.tile(exact[8:10], 2)).max() <= 0.02 * scale
    # and the water carries the block: the force on it is its weight (measured 1 + 2.6e-4, batty 1 + 7e-4)
    assert f[1] == pytest.approx(500.0 * G * 0.4 * 0.2, rel=0.01)


def test_moving_rigid_body_imposes_its_normal_velocity_on_the_water():
    # a rigid block moving at U through the water: every water face on its boundary carries U's
    # normal component, exactly (the body's cells bound the pressure equation like a wall)
    U = (0.1, -0.05)
    sim, nw = tank_with_block(2000.0, ((0.4, 0.1), (0.6, 0.3)), rigid_velocity=U)
    sim.advance(1.0, max_steps=3)
    u, v = sim.face_velocity()
    st = sim.state()
    sim.close()
    # the block covers cells 8..11 x 2..5 at the start and has moved 3 dt < h/2
    assert np.all(u[8, 2:6] == U[0]) and np.all(u[12, 2:6] == U[0])
    assert np.all(v[8:12, 2] == U[1]) and np.all(v[8:12, 6] == U[1])
    np.testing.assert_array_equal(st["v"][nw:], np.tile(U, (len(st["v"]) - nw, 1)))


def test_solids_with_incompressible_water_need_a_water_and_no_contact():
    sim, nw = tank_with_block(500.0, ((0.3, 0.4), (0.7, 0.6)))
    sim.set_bodies(np.r_[np.zeros(nw, int), np.ones(sim.n - nw, int)], contact=True)
    with pytest.raises(CpdiError, match="contact is not available"):
        sim.advance(0.01)
    sim.close()
