"""Solids coupled two-way with the incompressible water (cpdi_fsi; docs/fsi_incompressible.md).
The coupling is chosen by what the solids are. Deformable and prescribed solids: the solid's mass
joins the water's on the MAC faces and the projection runs over water and solid cells with the
mixture's face densities; a prescribed rigid body bounds the water with its velocity. Free rigid
bodies (`rigid_body`; tests/test_rigid_body.py): the pressure lives in the water's cells, the body
enters each cell's constraint through its boundary flux (cpdi_coupling; the operator's own tests,
exact Archimedes for a hydrostatic pressure among them, are fortran/tests/test_coupling.f90).

Small tanks (1 m x 0.5 m of water, h = 0.05 m, 2 x 2 particles per cell) stepped through
Simulation.advance."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from harness.solver import FULL_STATE_ROWS, CpdiError, Simulation

H_CELL, WIDTH, DEPTH, RHO, G = 0.05, 1.0, 0.5, 1000.0, 9.81


def tank_with_block(rho_s, block, *, rigid_velocity=None, E=1.0e6, h=H_CELL, depth=DEPTH,
                    solid_substeps="off", free_body=False):
    """Water depth deep in a WIDTH-wide tank 1 m high (slip walls, open top), a block ((x0, y0),
    (x1, y1)) of Hencky material of density rho_s (or rigid, moving with rigid_velocity; or with
    free_body a free rigid body) replacing the water it covers. Returns the prepared simulation
    and the number of water particles."""
    d = h / 2
    xs, ys = np.arange(d / 2, WIDTH, d), np.arange(d / 2, depth, d)
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
    if free_body:
        solid = {"model": "rigid_body", "density": rho_s}
    elif rigid_velocity is None:
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
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99,
                    solid_substeps=solid_substeps)
    return sim, nw


def lattice(lo, hi, d):
    """Particle centres at spacing d filling the rectangle lo-hi."""
    xx, yy = np.meshgrid(np.arange(lo[0] + d / 2, hi[0], d), np.arange(lo[1] + d / 2, hi[1], d), indexing="xy")
    return np.column_stack([xx.ravel(), yy.ravel()])


def water_and_solid(xw, xs, solid, **options):
    """A prepared simulation of water particles at xw and solid particles at xs (material `solid`,
    a dict with its density), at rest, in a 20 x 20 cell tank (slip walls, open top)."""
    d = H_CELL / 2
    x = np.vstack([xw, xs])
    n, nw = len(x), len(xw)
    mat = np.r_[np.zeros(nw, int), np.ones(n - nw, int)]
    vol = np.full(n, d * d)
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 20), H_CELL, {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0}, solid])
    sim.set_particles(x, np.zeros((n, 2)), np.where(mat == 0, RHO, solid["density"]) * vol, vol,
                      np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)), mat)
    sim.set_bodies(mat)
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99, **options)
    return sim


def pool_and_block(U=(0.0, 0.0), omega=0.0, unit=1.0, rho_s=500.0, E=1.0e6, water_v=(0.0, 0.0), sides="slip"):
    """A Hencky block 0.3 m x 0.15 m (rho_s, E) in the air above a 0.2 m pool (the coupling
    needs a water) moving at water_v, the block thrown with velocity U and spin omega about its
    centre; masses, densities and moduli in units of `unit` kg; left and right walls `sides`.
    Returns the prepared simulation, the number of water particles and the initial positions."""
    d = H_CELL / 2
    xw, xb = lattice((0.0, 0.0), (1.0, 0.2), d), lattice((0.3, 0.6), (0.6, 0.75), d)
    x = np.vstack([xw, xb])
    n, nw = len(x), len(xw)
    vol = np.full(n, d * d)
    mat = np.r_[np.zeros(nw, int), np.ones(n - nw, int)]
    rel = xb - xb.mean(axis=0)
    v = np.zeros((n, 2))
    v[:nw] = water_v
    v[nw:] = np.asarray(U) + omega * np.column_stack([-rel[:, 1], rel[:, 0]])
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 20), H_CELL, {"left": sides, "right": sides, "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": RHO * unit, "bulk_modulus": 1.0, "viscosity": 0.0},
                       {"model": "hencky", "density": rho_s * unit, "youngs_modulus": E * unit,
                        "poisson_ratio": 0.3}])
    sim.set_particles(x, v, np.where(mat == 0, RHO, rho_s) * unit * vol, vol, np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)),
                      mat)
    sim.set_bodies(mat)
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99)
    return sim, nw, x


def block_in_flight(U, omega, t_end, unit=1.0, rho_s=500.0):
    """pool_and_block with the block thrown, run to t_end. Returns (state, number of water
    particles, steps, t, initial positions, diagnostics, cell pressures)."""
    sim, nw, x = pool_and_block(U, omega, unit, rho_s)
    steps, t = sim.advance(t_end)
    out = sim.state(), nw, steps, t, x, sim.diagnostics(), sim.grid_pressure()["pressure"]
    sim.close()
    return out


def test_thrown_solid_flies_with_gravity_along_minus_y():
    """A solid thrown through the air (U = (0.3, 0.1) m/s) is in free fall: every particle's
    velocity is U + g t (to rounding), and its position that of semi-implicit Euler with the run's
    equal steps dt, x0 + U t + g (t^2 + t dt) / 2 (the solid's nodal step: its gravity, its
    two velocity components, its FLIP update and its wall clamp)."""
    U = np.array([0.3, 0.1])
    st, nw, steps, t, x0, _, _ = block_in_flight(U, 0.0, 0.02)
    dt = t / steps
    g = np.array([0.0, -G])
    np.testing.assert_allclose(st["v"][nw:], np.tile(U + g * t, (len(st["v"]) - nw, 1)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(st["x"][nw:], x0[nw:] + U * t + g * (t * t + t * dt) / 2, rtol=0, atol=1e-12)


def test_spinning_solid_in_flight_keeps_its_volume_and_shape():
    """A solid spinning at 2 rad/s in free flight: its velocity gradient is a pure spin, so
    after 0.02 s (2.3 degrees) F is a rotation: J = 1 and F^T F = I up to the discretisation
    (measured 3.0e-4 and 1.5e-3; the volume 3e-5). A velocity gradient with a component taken
    from the wrong velocity or the wrong derivative strains the block by ~omega t = 0.04."""
    st, nw, _, _, _, _, _ = block_in_flight((0.3, 0.1), 2.0, 0.02)
    F = st["F"][nw:]
    J = F[:, 0] * F[:, 3] - F[:, 1] * F[:, 2]
    C = np.column_stack([F[:, 0] ** 2 + F[:, 1] ** 2 - 1, F[:, 2] ** 2 + F[:, 3] ** 2 - 1,
                         F[:, 0] * F[:, 2] + F[:, 1] * F[:, 3]])
    assert np.abs(J - 1).max() < 2e-3
    assert np.abs(C).max() < 1e-2
    assert abs(st["vol"][nw:].sum() / (0.3 * 0.15) - 1) < 1e-3


def test_coupled_step_does_not_depend_on_the_mass_unit():
    """Dimensional analysis: the same run with every mass, density and modulus in units of
    2^-20 kg moves identically (positions, velocities, F: bit for bit, power-of-two scaling
    commutes with rounding), and its stresses and pressures are the same numbers in the new
    unit. A tolerance or threshold in absolute mass units breaks it."""
    unit = 2.0 ** -20
    a = block_in_flight((0.3, 0.1), 0.0, 0.05)
    b = block_in_flight((0.3, 0.1), 0.0, 0.05, unit=unit)
    for k in ("x", "v", "F", "vol", "r"):
        np.testing.assert_array_equal(b[0][k], a[0][k])
    np.testing.assert_array_equal(b[0]["sigma"], a[0]["sigma"] * unit)
    np.testing.assert_array_equal(b[6], a[6] * unit)
    assert np.abs(a[6]).max() > 0.1 * RHO * G * 0.2, "the pool's pressure must be part of the comparison"


def swapped_runs(xw, xb, vb, model="hencky", t_end=0.05):
    """Water particles at xw (a swirl 0.05 (sin 9y, cos 7x) m/s) and a block of density 600
    (Hencky, or model "rigid_body": a free rigid body) at xb moving with vb, in a 16 x 16 grid
    with slip walls left and bottom (open right and top), without gravity, run to t_end as given
    and with x and y exchanged (the walls map onto each other). Returns both (state, cell
    pressures), the second mapped back."""
    x = np.vstack([xw, xb])
    n, nw = len(x), len(xw)
    v = np.zeros((n, 2))
    v[:nw] = 0.05 * np.column_stack([np.sin(9 * xw[:, 1]), np.cos(7 * xw[:, 0])])
    v[nw:] = vb
    mat = np.r_[np.zeros(nw, int), np.ones(n - nw, int)]
    vol = np.full(n, (H_CELL / 2) ** 2)
    runs = []
    for p in ([0, 1], [1, 0]):
        sim = Simulation()
        sim.set_grid((0.0, 0.0), (16, 16), H_CELL, {"left": "slip", "bottom": "slip", "right": "open", "top": "open"})
        sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0},
                           {"model": "hencky", "density": 600.0, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3}
                           if model == "hencky" else {"model": model, "density": 600.0}])
        sim.set_particles(x[:, p], v[:, p], np.where(mat == 0, RHO, 600.0) * vol, vol,
                          np.tile([H_CELL / 4, 0.0, 0.0, H_CELL / 4], (n, 1)), mat)
        sim.set_bodies(mat)
        sim.set_options(shape="cpdi", gravity=(0.0, 0.0), fluid="incompressible", cfl=0.5, flip=0.99,
                        cg_tolerance=1e-13)
        sim.advance(t_end)
        st, pres = sim.state(), sim.grid_pressure()["pressure"]
        sim.close()
        if p == [1, 0]:
            st = {"x": st["x"][:, p], "v": st["v"][:, p], "F": st["F"][:, [3, 2, 1, 0]],
                  "sigma": st["sigma"][:, [1, 0, 2, 3]]}
            pres = pres.T
        runs.append((st, pres))
    return runs


def assert_swap_symmetric(runs):
    (a, pa), (b, pb) = runs
    for k in ("x", "v", "F", "sigma"):
        np.testing.assert_allclose(b[k], a[k], rtol=0, atol=1e-9 * np.abs(a[k]).max(), err_msg=k)
    np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-9 * np.abs(pa).max(), err_msg="cell pressure")


def test_coupled_flow_is_symmetric_under_exchanging_x_and_y():
    """Without gravity, a water square in the corner of slip walls left and bottom (open right
    and top) with a Hencky block thrown through it at (0.4, 0.1) m/s: exchanging x and y
    exchanges the solution (the walls map onto each other). The block hands most of its
    momentum to the water in 0.05 s (96 steps); measured 2e-15 relative in positions and F,
    1e-13 in velocities, 1e-11 in stresses and pressures (CG tolerance 1e-13)."""
    d = H_CELL / 2
    lo, hi = (0.1, 0.15), (0.25, 0.3)
    xw = lattice((0.0, 0.0), (0.5, 0.45), d)
    xw = xw[~((xw[:, 0] > lo[0]) & (xw[:, 0] < hi[0]) & (xw[:, 1] > lo[1]) & (xw[:, 1] < hi[1]))]
    runs = swapped_runs(xw, lattice(lo, hi, d), (0.4, 0.1))
    assert_swap_symmetric(runs)
    assert np.abs(runs[0][0]["v"][len(xw):, 0]).mean() < 0.2, \
        "the block must have pushed the water for the test to mean anything"


def test_boundary_flux_coupling_is_symmetric_under_exchanging_x_and_y_at_the_walls():
    """The same symmetry with a free rigid body, whose boundary-flux coupling's cell classification
    reads each cell's solid fraction: a block on the floor slides at 0.4 m/s into a sparse sheet of water
    (one particle row, fill ~1/3) beside a column of water; exchanged, it lies against the left
    wall. Measured 4e-16 relative in positions, 1e-13 in velocities, 2e-12 in stresses, 1e-13
    in pressures. (With the bottom row's solid fractions left at 0 the sheet's cells there turned
    water: 0.6 % in positions, 56 % in velocities.)"""
    d = H_CELL / 2
    lo, hi = (0.1, 0.0), (0.25, 0.15)
    sheet = lattice((0.25, 0.0), (0.5, d), d)
    sheet[:, 0] = 0.25 + 1.5 * (sheet[:, 0] - 0.25)     # spaced 1.5 d: a sheet filling its cells to ~1/3
    xw = np.vstack([lattice((0.0, 0.0), (0.1, 0.3), d), sheet[sheet[:, 0] < 0.5]])
    runs = swapped_runs(xw, lattice(lo, hi, d), (0.4, 0.05), "rigid_body")
    assert_swap_symmetric(runs)
    assert np.abs(runs[0][1]).max() > 100.0, "the water must have been pushed for the test to mean anything"


def test_volume_correction_lifts_over_packed_water_beside_a_solid():
    """Water packed 10 % too close (fill 1.21) in a 0.3 m pool with a floating block: the volume
    correction moves the particles apart at the water's rate, so in 0.3 s the surface rises
    most of the way to the 0.363 m of the unpacked volume (measured 0.348 m, 99th percentile;
    0.300 m without the correction)."""
    d = H_CELL / 2
    xw, xb = lattice((0.0, 0.0), (1.0, 0.3), d / 1.1), lattice((0.4, 0.3), (0.6, 0.4), d)
    x = np.vstack([xw, xb])
    n, nw = len(x), len(xw)
    vol = np.full(n, d * d)
    mat = np.r_[np.zeros(nw, int), np.ones(n - nw, int)]
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 12), H_CELL, {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0},
                       {"model": "hencky", "density": 500.0, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3}])
    sim.set_particles(x, np.zeros((n, 2)), np.where(mat == 0, RHO, 500.0) * vol, vol,
                      np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)), mat)
    sim.set_bodies(mat)
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, volume_correction=0.5)
    sim.advance(0.3)
    top = np.percentile(sim.state()["x"][:nw, 1], 99)
    sim.close()
    assert top > 0.33


def rigid_block_in_sparse_water(U, patch=False, **options):
    """A rigid block 0.2 m square moving at U through water whose particle volumes are 0.9 of
    their spacing's (no cell over-filled), with patch=True a patch packed to 1.3 in the far
    top-right corner. Returns the prepared simulation, the initial positions and the number of
    water particles."""
    d = H_CELL / 2
    xw = lattice((0.0, 0.0), (1.0, 0.5), d)
    xw = xw[~((xw[:, 0] > 0.4) & (xw[:, 0] < 0.6) & (xw[:, 1] > 0.1) & (xw[:, 1] < 0.3))]
    x = np.vstack([xw, lattice((0.4, 0.1), (0.6, 0.3), d)])
    n, nw = len(x), len(xw)
    vol = np.full(n, d * d)
    vol[:nw] *= np.where(patch & (xw[:, 0] > 0.85) & (xw[:, 1] > 0.35), 1.3, 0.9)
    mat = np.r_[np.zeros(nw, int), np.ones(n - nw, int)]
    v = np.zeros((n, 2))
    v[nw:] = U
    if patch:
        v[0] = (0.1, 0.0)   # one far water particle: the water's signal speed is the same at any U
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 20), H_CELL, {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0},
                       {"model": "rigid", "density": 2000.0, "velocity": list(U)}])
    sim.set_particles(x, v, np.where(mat == 0, RHO, 2000.0) * vol, vol, np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)),
                      mat)
    sim.set_bodies(mat)
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99, **options)
    return sim, x, nw


def test_volume_correction_is_idle_where_no_water_is_over_packed():
    """A rigid block moving at (0.05, -0.1) m/s through sparse water (no cell is over-filled
    during the 0.05 s): the volume correction has no packing to undo, so it moves nothing and
    does no work (correction_work exactly 0)."""
    sim, _, _ = rigid_block_in_sparse_water((0.05, -0.1))
    sim.advance(0.05)
    work, grid = sim.diagnostics()["correction_work"], sim.grid_pressure()
    sim.close()
    assert grid["fill"][grid["water"] == 1].max() < 1.0   # (measured 0.904)
    assert work == 0.0


def correction_displacement(U):
    """One step (0.02 s) of rigid_block_in_sparse_water with the packed patch: the volume
    correction's own displacement (beta 0.5 minus beta 0) of the water within a cell of the
    block."""
    out = []
    for beta in (0.0, 0.5):
        sim, x, nw = rigid_block_in_sparse_water(U, True, volume_correction=beta)
        sim.advance(0.02, max_steps=1)
        xw = x[:nw]
        near = (xw[:, 0] > 0.35) & (xw[:, 0] < 0.65) & (xw[:, 1] > 0.05) & (xw[:, 1] < 0.35)
        out.append(sim.state()["x"][:nw][near])
        sim.close()
    return out[1] - out[0]


def test_volume_correction_does_not_carry_a_moving_bodys_velocity():
    # the correction undoes packing with every wall held still: the water next to a rigid block
    # is moved by it the same whether the block moves at 0.11 m/s or rests. (Measured: equal to
    # 1e-16 m; before the correction's walls were held still it gave the body's faces the
    # body's velocity, and the moving block's neighbours 1.5e-3 m more.)
    resting = correction_displacement((0.0, 0.0))
    moving = correction_displacement((0.05, -0.1))
    assert np.abs(resting).max() > 5e-4      # the correction acts there (measured 8e-4 / 1.4e-2 m)
    np.testing.assert_allclose(moving, resting, rtol=0, atol=1e-12)


def test_coupled_state_keeps_j_equal_to_det_f_and_v_over_v0():
    """After coupled steps every particle's J (the full state's jbar, what the stress and a
    restart read) is det F and V / V0: the water's stay 1 (its particles keep their reference
    volume), the solid's follow its deformation."""
    sim, nw = tank_with_block(500.0, ((0.3, 0.4), (0.7, 0.6)))
    vol0 = sim.state()["vol"]
    sim.advance(0.05)
    full = sim.get_full_state()["particles"]
    sim.close()
    row = dict(zip([k for k, _ in FULL_STATE_ROWS], np.cumsum([0] + [w for _, w in FULL_STATE_ROWS])[:-1], strict=True))
    F = full[row["F"]:row["F"] + 4]
    det = F[0] * F[3] - F[1] * F[2]
    np.testing.assert_allclose(full[row["jbar"]], det, rtol=1e-14)   # (det F rounded in another order)
    np.testing.assert_allclose(full[row["vol"]], det * vol0, rtol=1e-14)
    assert np.abs(det[nw:] - 1).max() > 1e-9, "the solid must deform for the test to mean anything"


def hydrostatic_cells(h=H_CELL):
    ny = round(1.0 / h)
    yc = (np.arange(ny) + 0.5) * h
    return RHO * G * (DEPTH - yc)


def test_mixture_submerged_solid_at_rest_feels_exactly_the_buoyancy():
    # a neutrally buoyant block (the one density at which a free solid in
    # resting water is at rest): the water's force on it is rho_w g V, the state stays at rest,
    # and the pressure is hydrostatic in every cell, the solid's included (the face densities are
    # the mixture's: the projection holds the solid's volume, and its pressure carries its weight)
    block = ((0.4, 0.1), (0.6, 0.3))
    vol = 0.2 * 0.2
    sim, nw = tank_with_block(RHO, block)
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


def test_subcycled_neutral_block_at_rest_feels_exactly_the_buoyancy_at_the_waters_pace():
    # solid_substeps = "explicit": the Hencky block's explicit steps run inside the water's step
    # (cpdi_step subcycle_solids). A neutrally buoyant block at rest in resting water stays at
    # rest with the water's force rho_w g V on it, as with the acoustic step, and the coupled
    # step is the water's (its advective limit, cfl h / sqrt(g h) = 0.036 s here), not the
    # solid's (cfl h / c = 7e-4 s for E = 1 MPa).
    block = ((0.4, 0.1), (0.6, 0.3))
    buoyancy = RHO * G * 0.2 * 0.2
    sim, nw = tank_with_block(RHO, block, solid_substeps="explicit")
    steps, t = sim.advance(0.5, land=False)
    f, st = sim.solid_force(), sim.state()
    sim.close()
    c = np.sqrt(1.0e6 * 0.7 / (1.3 * 0.4) / RHO)   # P-wave speed, nu = 0.3
    assert t / steps >= 10 * 0.5 * H_CELL / c
    assert abs(f[1] - buoyancy) <= 1e-6 * buoyancy and abs(f[0]) <= 1e-6 * buoyancy
    assert np.abs(st["v"]).max() <= 1e-6 * G * t / steps


def test_implicit_substeps_compress_a_neutral_block_by_its_bulk_stiffness_at_the_waters_pace():
    # solid_substeps = "implicit": the projection carries the solid's volumetric stress (a
    # compliance term phi / K in solid cells, K = lam + mu, the plane-strain bulk modulus), so the
    # block is no longer held at its volume by the mixture's constraint: released unstressed, it
    # compresses under the water's pressure, backward-Euler, within a few water steps, to
    # dV / V = p / K with p = rho g (depth of its centre) (measured 0.3064 % against 0.3061 %), and
    # then feels rho_w g V of its new volume: it sinks slowly (g dV / V, less for its added mass).
    block = ((0.4, 0.1), (0.6, 0.3))
    sim, nw = tank_with_block(RHO, block, solid_substeps="implicit")
    steps, t = sim.advance(0.5, land=False)
    f, st = sim.solid_force(), sim.state()
    sim.close()
    lam, mu = 1.0e6 * 0.3 / (1.3 * 0.4), 1.0e6 / 2.6
    dv = 1.0 - st["vol"][nw:].sum() / 0.04
    assert dv == pytest.approx(RHO * G * (DEPTH - 0.2) / (lam + mu), rel=0.02)
    assert f[1] == pytest.approx(RHO * G * 0.04, rel=5e-3) and abs(f[0]) <= 1e-6 * f[1]
    assert 0.0 < -st["v"][nw:, 1].mean() <= G * dv * t
    c = np.sqrt(1.0e6 * 0.7 / (1.3 * 0.4) / RHO)
    assert t / steps >= 10 * 0.5 * H_CELL / c


@pytest.mark.parametrize("anchored, chosen", [(False, "implicit"), (True, "explicit")])
def test_auto_substeps_choose_by_what_the_solid_is(anchored, chosen):
    # solid_substeps = "auto" (the cases' default): the coupling picks the mode (cpdi_step
    # prepare_solids): a free deformable solid steps implicit (its volumetric stress in the
    # projection), and a solid held by a prescribed rigid body explicit; each run equals the
    # chosen mode's bit for bit, and differs from the other's (so the test sees which one ran)
    other = "explicit" if chosen == "implicit" else "implicit"

    def final(mode):
        if anchored:
            sim, _, _ = plate_on_anchor(mode)
        else:
            sim, _ = tank_with_block(800.0, ((0.4, 0.3), (0.6, 0.45)), solid_substeps=mode)
        try:
            sim.advance(0.1, land=False)
            return sim.state()["x"]
        finally:
            sim.close()

    got = final("auto")
    np.testing.assert_array_equal(got, final(chosen))
    assert np.abs(got - final(other)).max() > 0.0


def added_mass_coefficient(h, free_body):
    """A block 0.2 m square of density 1500 released at rest 0.1 m under the surface of
    tank_with_block's water (solid_substeps "auto"): its added-mass coefficient C from its mean
    acceleration over the first 0.1 s, a = g (rho_s - rho_w) / (rho_s + C rho_w)."""
    sim, nw = tank_with_block(1500.0, ((0.4, 0.2), (0.6, 0.4)), h=h, solid_substeps="auto", free_body=free_body)
    _, t = sim.advance(0.1, land=False)
    a = -sim.state()["v"][nw:, 1].mean() / t
    sim.close()
    return (G * (1500.0 - RHO) / a - 1500.0) / RHO


def test_deformable_block_added_mass_converges_at_first_order():
    # the one-continuum coupling is no-slip on the faces: the water on a solid's boundary faces
    # moves with it, so a sinking Hencky block carries about a cell's layer of water more than the
    # added mass of potential flow (C = 1.19 for a square, per rho_w b^2). The excess is O(h):
    # measured C = 2.45 at h = 0.05 (b / h = 4) and 1.85 at h = 0.025, the excess 1.26 -> 0.66
    # (ratio 0.52; the free rigid body, free-slip: 1.08 and 1.17)
    c1, c2 = added_mass_coefficient(H_CELL, False), added_mass_coefficient(H_CELL / 2, False)
    assert c1 > c2 > 1.19
    assert (c2 - 1.19) <= 0.6 * (c1 - 1.19)


def test_heavy_rigid_body_sinks_with_its_added_mass_and_lands():
    # a free rigid block of density 1500 released at rest 0.1 m under the surface
    # accelerates at g (rho_s - rho_w) / (rho_s + C rho_w), C = 1.19 the added mass of a square
    # per rho_w b^2 in unbounded water (1.51 rho_w pi b^2 / 4): 1.82 m/s^2 (measured over the first
    # 0.1 s: 1.90, C = 1.08 in this tank); it lands on the floor (its bottom within half a cell) and
    # stays; the energy, with the volume correction's lift, is not created.
    rho_s, b = 1500.0, 0.2
    sim, nw = tank_with_block(rho_s, ((0.4, 0.2), (0.6, 0.4)), free_body=True)
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


def test_no_pressure_spike_next_to_a_floating_solid():
    # a block of density 500 floating at Archimedes' draft (0.1 m of its 0.2 m): after it has
    # settled, the pressure of the water cells touching it (below and beside) is the far
    # field's hydrostatic pressure at their depth: no spike on the first fluid layer
    block = ((0.3, 0.4), (0.7, 0.6))
    sim, nw = tank_with_block(500.0, block)
    sim.advance(2.0)
    grid, f = sim.grid_pressure(), sim.solid_force()
    sim.close()
    p = grid["pressure"]
    exact = hydrostatic_cells()
    below = p[6:14, 7]                       # cells (6..13, 7): centres 0.025 m under the block
    beside = np.r_[p[5, 8:10], p[14, 8:10]]  # the water cells left and right of its wet part
    scale = RHO * G * 0.1
    # measured at 2 s: below within 0.23 % of rho g d, beside within 0.41 %
    assert np.abs(below - exact[7]).max() <= 0.02 * scale
    assert np.abs(beside - np.tile(exact[8:10], 2)).max() <= 0.02 * scale
    # and the water carries the block: the force on it is its weight (measured 1 + 2.6e-4)
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


def test_water_closes_the_wake_of_a_moving_rigid_body():
    # a rigid block (cells 4..7 x 2..5) driven at 0.5 m/s through the water for 0.3 s moves 3 cells:
    # the cells it left hold water again (a cell the body left must not go on bounding the water),
    # and the only dry cells below the surface are the four columns it covers now (7..10)
    sim, _ = tank_with_block(2000.0, ((0.2, 0.1), (0.4, 0.3)), rigid_velocity=(0.5, 0.0))
    sim.advance(0.3)
    water = sim.grid_pressure()["water"]
    sim.close()
    assert np.all(water[4:7, 2:6] == 1)
    dry = np.argwhere(water[:, :8] == 0)
    assert sorted({int(i) for i, _ in dry}) == [7, 8, 9, 10] and sorted({int(j) for _, j in dry}) == [2, 3, 4, 5]


def test_water_falls_freely_through_the_air_a_rigid_body_has_left():
    # a rigid block (0.2-0.4 x 0.5-0.6 m) driven right at 2 m/s through the air leaves the column
    # under a water drop (0.25-0.35 x 0.85-0.95 m, open top) by t = 0.1 s, while the drop is still
    # 4 cells above it: the air the block left bounds nothing, and the drop falls freely,
    # v = -g t, through it (water fills the cells behind a body in water at once, so only air
    # shows a stale wall)
    d = H_CELL / 2
    xw, xb = lattice((0.25, 0.85), (0.35, 0.95), d), lattice((0.2, 0.5), (0.4, 0.6), d)
    x = np.vstack([xw, xb])
    n, nw = len(x), len(xw)
    mat = np.r_[np.zeros(nw, int), np.ones(n - nw, int)]
    v = np.where(mat[:, None] == 1, [2.0, 0.0], 0.0)
    vol = np.full(n, d * d)
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 20), H_CELL, {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0},
                       {"model": "rigid", "density": 2000.0, "velocity": [2.0, 0.0]}])
    sim.set_particles(x, v, np.where(mat == 0, RHO, 2000.0) * vol, vol, np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)),
                      mat)
    sim.set_bodies(mat)
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99)
    _, t = sim.advance(0.25)
    st = sim.state()
    sim.close()
    np.testing.assert_allclose(st["v"][:nw], np.tile([0.0, -G * t], (nw, 1)), rtol=0, atol=1e-9 * G * t)
    assert st["x"][nw:, 0].min() > 0.65 and st["x"][:nw, 1].min() < 0.55   # the drop is in the block's old place


def drop_next_to_a_resting_block_falls_freely(drop, block, t_end):
    """Water particles filling `drop` (lo, hi corners) fall from rest next to a rigid block at
    rest filling `block`; returns (steps, t, water particles' positions), having asserted that
    every water particle moves at (0, -g t) to 1e-12 m/s."""
    d = H_CELL / 2
    xw = lattice(*drop, d)
    sim = water_and_solid(xw, lattice(*block, d), {"model": "rigid", "density": 2000.0, "velocity": [0.0, 0.0]},
                          cg_tolerance=1e-12)
    nw = len(xw)
    steps, t = sim.advance(t_end)
    st = sim.state()
    sim.close()
    np.testing.assert_allclose(st["v"][:nw], np.tile([0.0, -G * t], (nw, 1)), rtol=0, atol=1e-12)
    return steps, t, st["x"][:nw]


def test_drop_above_a_resting_block_falls_freely_until_it_reaches_its_cell():
    """A water drop (0.45-0.55 x 0.6-0.7 m) two cells above a rigid block at rest (0.3-0.7 x
    0.4-0.5 m) falls for 0.07 s at v = -g t, to 1e-12 m/s, half a cell short of the block's cell
    row: the air faces between them carry the water's extrapolated velocity; the block's own
    faces keep its normal velocity but are no source of the extrapolation (mixing it in gave
    0.016 m/s, 2.3 % of g t)."""
    steps, _, x = drop_next_to_a_resting_block_falls_freely(((0.45, 0.6), (0.55, 0.7)), ((0.3, 0.4), (0.7, 0.5)),
                                                            0.07)
    assert steps >= 3 and x[:, 1].min() > 0.55   # still short of the block's cell row


def test_drop_beside_a_resting_block_falls_freely():
    """A water drop (0.55-0.65 x 0.6-0.8 m) one cell to the right of a rigid block at rest
    (0.3-0.5 x 0.2-0.7 m), its top above the block's, falls for 0.1 s at v = -g t, to 1e-12
    m/s, down the block's side: the air faces in the gap carry the water's extrapolated
    velocity, not a mean with the block's top face or its inside (the drop never enters the
    block's cells, so nothing holds it)."""
    steps, _, x = drop_next_to_a_resting_block_falls_freely(((0.55, 0.6), (0.65, 0.8)), ((0.3, 0.2), (0.5, 0.7)),
                                                            0.1)
    assert steps >= 3 and x[:, 1].min() < 0.56 and x[:, 0].min() > 0.55   # below the block's top, beside it


@pytest.mark.parametrize("packing", [1.1, 1.0])
def test_water_sealed_in_a_falling_hollow_block_falls_with_it(packing):
    """A Hencky frame (0.3 x 0.3 m, rho 1100) sealing a 2 x 2 cell pocket of water, packed 10 %
    over (or not), falls through the air: everything moves at v = -g t (to 1e-12 m/s over 0.1 s;
    measured 1e-16). The frame's cells are pressure cells of the one continuum, so the pocket and
    the frame are one region with air around it, and neither the pressure nor the volume
    correction may push the water against the frame in free fall."""
    d = H_CELL / 2
    frame = lattice((0.3, 0.5), (0.6, 0.8), d)
    frame = frame[~((frame[:, 0] > 0.4) & (frame[:, 0] < 0.5) & (frame[:, 1] > 0.6) & (frame[:, 1] < 0.7))]
    xw = lattice((0.4, 0.6), (0.5, 0.7), d / packing)
    sim = water_and_solid(xw, frame, {"model": "hencky", "density": 1100.0, "youngs_modulus": 1.0e7,
                                      "poisson_ratio": 0.3}, cg_tolerance=1e-10)
    n = len(xw) + len(frame)
    steps, t = sim.advance(0.1)
    v = sim.state()["v"]
    sim.close()
    assert steps > 10
    np.testing.assert_allclose(v, np.tile([0.0, -G * t], (n, 1)), rtol=0, atol=1e-12)


def test_a_rigid_bodys_density_does_not_change_the_flow():
    """A rigid body moves with its prescribed velocity whatever its mass, so the density of a
    fixed rigid plate in the air (1000 or 1e16 kg/m^3) cannot change how the water holds a
    floating Hencky block: the states are bit for bit the same. (A solid face's mass counts from
    a tolerance of 1e-12 of the lightest particle's mass; scaled by the heaviest instead, the
    1e16 plate made the block's faces massless and it fell through the water at g.)"""
    d = H_CELL / 2
    lo, hi = (0.3, 0.2), (0.6, 0.35)
    xw = lattice((0.0, 0.0), (1.0, 0.3), d)
    xw = xw[~((xw[:, 0] > lo[0]) & (xw[:, 0] < hi[0]) & (xw[:, 1] > lo[1]) & (xw[:, 1] < hi[1]))]
    xb, xr = lattice(lo, hi, d), lattice((0.85, 0.8), (0.95, 0.9), d)
    x = np.vstack([xw, xb, xr])
    n, nw, nb = len(x), len(xw), len(xb)
    mat = np.r_[np.zeros(nw, int), np.ones(nb, int), np.full(len(xr), 2)]
    vol = np.full(n, d * d)
    runs = []
    for rho_r in (1000.0, 1.0e16):
        sim = Simulation()
        sim.set_grid((0.0, 0.0), (20, 20), H_CELL, {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
        sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0},
                           {"model": "hencky", "density": 500.0, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3},
                           {"model": "rigid", "density": rho_r, "velocity": [0.0, 0.0]}])
        sim.set_particles(x, np.zeros((n, 2)), np.array([RHO, 500.0, rho_r])[mat] * vol, vol,
                          np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)), mat)
        sim.set_bodies(mat)
        sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99)
        steps, t = sim.advance(0.05)
        runs.append((sim.state(), steps))
        sim.close()
    (a, sa), (b, sb) = runs
    assert sa == sb
    for k in ("x", "v", "F", "sigma"):
        np.testing.assert_array_equal(b[k], a[k], err_msg=k)
    assert abs(a["v"][nw:nw + nb, 1].mean()) < 0.2 * G * 0.05, "the water must hold the block up"


def test_a_rigid_body_in_the_top_cell_row_imposes_its_velocity_there_too():
    # the same in a tank filled to its top, the block in the top four cell rows (16..19 of 20):
    # every row of the face lattice, the last included, carries the block's velocity
    U = (0.1, -0.05)
    sim, _ = tank_with_block(2000.0, ((0.4, 1.0 - 4 * H_CELL), (0.6, 1.0)), rigid_velocity=U, depth=1.0)
    sim.advance(1.0, max_steps=3)
    u, _ = sim.face_velocity()
    sim.close()
    assert u.shape == (21, 20)
    assert np.all(u[8, 16:20] == U[0]) and np.all(u[12, 16:20] == U[0])


def test_solids_with_incompressible_water_need_a_water_and_no_contact():
    sim, nw = tank_with_block(500.0, ((0.3, 0.4), (0.7, 0.6)))
    sim.set_bodies(np.r_[np.zeros(nw, int), np.ones(sim.n - nw, int)], contact=True)
    with pytest.raises(CpdiError, match="contact is not available"):
        sim.advance(0.01)
    sim.close()


# Run in a fresh interpreter with the environment given: the final state's hash.
_FULL_TANK = """
import hashlib, sys
sys.path.insert(0, {tests!r})
from test_fsi_incompressible import tank_with_block
sim, _ = tank_with_block(1100.0, ((0.35, 0.0), (0.65, 0.3)), free_body={free_body!r}, depth=1.0)
sim.advance(0.02)
print(hashlib.sha1(sim.state()["x"].tobytes() + sim.state()["v"].tobytes()).hexdigest())
"""


@pytest.mark.parametrize("free_body", [True, False])
def test_coupled_run_does_not_depend_on_what_the_heap_held(free_body):
    """A run reads only what it wrote: the same run with freshly allocated memory filled with
    other bytes (glibc's MALLOC_PERTURB_) gives the same state, bit for bit. Water up to an open
    top (the cells beyond it are air) with a block (free rigid or Hencky) on the floor: the boundary-flux
    coupling read the
    solid fill of the cells beyond the open side, which nothing wrote (a sinking_block run that
    followed another in the same process ended with a 4 % different water volume)."""
    tests = str(Path(__file__).resolve().parent)
    code = _FULL_TANK.format(tests=tests, free_body=free_body)
    out = {}
    for perturb in ("", "165", "77"):
        env = {k: v for k, v in os.environ.items() if k != "MALLOC_PERTURB_"}
        if perturb:
            env["MALLOC_PERTURB_"] = perturb
        env["PYTHONPATH"] = os.pathsep.join([str(Path(tests).parent), env.get("PYTHONPATH", "")])
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        out[perturb] = r.stdout.split()[-1]
    assert out["165"] == out[""] and out["77"] == out[""], out


def test_coupled_water_step_is_the_advective_limit_of_its_fastest_particle():
    """With a solid coupled to it the water's stable step is still h / (sqrt 2 max|v_i| +
    sqrt(g h)) over its particles: a pool streaming at 3 m/s (open sides) under a soft Hencky
    block at rest (E = 1 kPa: its own limit, h / c_p = 0.035 s, is the looser one)."""
    sim, _, _ = pool_and_block(E=1.0e3, water_v=(3.0, 0.0), sides="open")
    dt = sim.stable_dt()
    sim.close()
    assert dt == pytest.approx(H_CELL / (np.sqrt(2) * 3.0 + np.sqrt(G * H_CELL)), rel=1e-14)


@pytest.mark.parametrize("mode", ["explicit", "implicit", "auto"])
def test_substeps_leave_a_run_without_deformable_solids_as_it_is(mode):
    # solid_substeps only concerns deformable solids: a free rigid body (coupled through its boundary
    # flux) runs bit for bit as with "off"
    from harness import cases, paths, runner

    def final(substeps):
        case = cases.load(paths.CASES / "floating_block.toml",
                          ['materials.1.model="rigid_body"', "solver.t_end=0.2", "solver.output_every=0.2",
                           f'solver.solid_substeps="{substeps}"'])
        return runner.run(case, None, progress=False).final["x"]

    np.testing.assert_array_equal(final(mode), final("off"))


def plate_on_anchor(solid_substeps, anchor_velocity=(0.0, 0.0), rho_s=RHO):
    """A Hencky plate (rho_s, E = 1 MPa; 0.45-0.55 x 0.05-0.35 m) standing on a prescribed rigid
    anchor (0.45-0.55 x 0-0.05 m, moving at anchor_velocity) in resting water 0.5 m deep, 20 x 20
    cells, coupling mixture. Returns the prepared simulation, the positions and the materials
    (0 water, 1 plate, 2 anchor)."""
    d = H_CELL / 2
    plate, anchor = ((0.45, 0.05), (0.55, 0.35)), ((0.45, 0.0), (0.55, 0.05))

    def inside(x, b):
        return (x[:, 0] > b[0][0]) & (x[:, 0] < b[1][0]) & (x[:, 1] > b[0][1]) & (x[:, 1] < b[1][1])

    xw = lattice((0.0, 0.0), (WIDTH, DEPTH), d)
    xw = xw[~(inside(xw, plate) | inside(xw, anchor))]
    x = np.vstack([xw, lattice(*plate, d), lattice(*anchor, d)])
    mat = np.r_[np.zeros(len(xw), int), np.ones(len(x) - len(xw) - 8, int), np.full(8, 2)]
    n, vol = len(x), np.full(len(x), d * d)
    v = np.zeros((n, 2))
    v[mat == 2] = anchor_velocity
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 20), H_CELL, {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 1.0, "viscosity": 0.0},
                       {"model": "hencky", "density": rho_s, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3},
                       {"model": "rigid", "density": 2500.0, "velocity": list(anchor_velocity)}])
    sim.set_particles(x, v, np.array([RHO, rho_s, 2500.0])[mat] * vol, vol, np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)),
                      mat)
    sim.set_bodies(mat)
    sim.set_options(shape="cpdi", gravity=(0.0, -G), fluid="incompressible", cfl=0.5, flip=0.99,
                    solid_substeps=solid_substeps)
    return sim, x, mat


@pytest.mark.parametrize("mode", ["explicit", "implicit"])
def test_subcycled_plate_is_held_by_its_moving_rigid_anchor(mode):
    # a prescribed rigid body joins the deformable solids' substeps (cpdi_step prepare_solids): its
    # nodes hold the plate in every substep (impose_rigid), and the substeps alone move it, once
    # per water step (the coupled step leaves it in place): the anchor, driven up at 0.1 m/s,
    # has moved U t to rounding (measured 1e-17 m), the plate's two lowest rows of particles
    # (on the anchor's nodes) go with it (measured 1.7e-5 / 2.2e-5 m explicit / implicit; the
    # acoustic step ("off") 1.1e-3 m), and the coupled step is the water's, >= 10 of the plate's
    # acoustic steps (12-13 steps in 0.3 s here against off's 447)
    U = np.array([0.0, 0.1])
    sim, x0, mat = plate_on_anchor(mode, U)
    steps, t = sim.advance(0.3, land=False)
    st = sim.state()
    sim.close()
    dx = st["x"] - x0
    np.testing.assert_allclose(dx[mat == 2], np.tile(U * t, ((mat == 2).sum(), 1)), rtol=0, atol=1e-14)
    lowest = (mat == 1) & (x0[:, 1] < 0.1)
    assert np.abs(dx[lowest] - U * t).max() <= 1e-4
    c = np.sqrt(1.0e6 * 0.7 / (1.3 * 0.4) / RHO)   # the plate's P-wave speed, nu = 0.3
    assert t / steps >= 10 * 0.5 * H_CELL / c


def test_subcycled_neutral_plate_on_a_fixed_anchor_stays_at_rest():
    # solid_substeps = "explicit", a neutrally buoyant plate on a fixed anchor in resting water: it
    # stays where it is (measured max |dx| 1.7e-5 m, |v| 4.8e-4 m/s after 0.3 s; the acoustic
    # step, "off", moves it 1.7e-3 m and rings at 0.42 m/s), the anchor does not move at all
    sim, x0, mat = plate_on_anchor("explicit")
    sim.advance(0.3, land=False)
    st = sim.state()
    sim.close()
    dx = st["x"] - x0
    assert np.all(dx[mat == 2] == 0.0)
    assert np.abs(dx[mat == 1]).max() <= 1e-4
    assert np.abs(st["v"][mat == 1]).max() <= 5e-3


@pytest.mark.parametrize("mode", ["explicit", "implicit"])
def test_subcycled_anchor_follows_its_velocity_table(mode):
    # the substeps carry the run's velocity tables: each substep moves the anchor by the table's mean
    # over it, so over the run it moves the table's integral (0.5 * 0.2 s * 0.2 m/s = 0.02 m up)
    # to round-off, and the plate's lowest rows with it (measured 4e-6 / 6e-6 m; off 1.2e-3 m)
    sim, x0, mat = plate_on_anchor(mode)
    sim.set_velocity_table(2, [[0.0, 0.0, 0.0], [0.1, 0.0, 0.2], [0.2, 0.0, 0.0]])
    sim.advance(0.3, land=False)
    st = sim.state()
    sim.close()
    dx = st["x"] - x0
    np.testing.assert_allclose(dx[mat == 2], np.tile([0.0, 0.02], ((mat == 2).sum(), 1)), rtol=0, atol=1e-14)
    lowest = (mat == 1) & (x0[:, 1] < 0.1)
    assert np.abs(dx[lowest] - [0.0, 0.02]).max() <= 1e-4
