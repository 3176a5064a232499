"""The incompressible water's pressure projection (cpdi_pressure) and transfer.

Test grids are nx x ny cells numbered i fastest; their outer ring is boundary (wall or
air). u(k) is the left face of cell k, v(k) its bottom face. With fill 1 in water and 0.5 in
air the ghost-fluid surface sits at the air cell's centre (theta = 1: Dirichlet p = 0 there).
"""

import numpy as np
import pytest

from harness.solver import CpdiError, Simulation, _call

AIR, WATER, WALL = 0, 1, 2


def tank(nx=8, ny=7, air_rows=1):
    """Walls left, right and bottom, air in the top `air_rows` rows (and the top ring)."""
    cell = np.full((nx, ny), WATER, dtype=np.int32)
    cell[0, :] = cell[-1, :] = WALL
    cell[:, 0] = WALL
    cell[:, ny - air_rows:] = AIR
    cell[0, ny - air_rows:] = cell[-1, ny - air_rows:] = WALL
    fill = np.where(cell == WATER, 1.0, 0.5)
    return cell, fill


def flat(a, dtype=np.float64):
    return np.asfortranarray(a, dtype=dtype).ravel(order="F")


def apply(cell, fill, x):
    nx, ny = cell.shape
    y = _call("cpdi_poisson_apply", nx, ny, flat(cell, np.int32), flat(fill), flat(x))
    return y.reshape((nx, ny), order="F")


def project(cell, fill, u, v, dt=0.01, rho=1000.0, h=0.1, beta=0.0, tol=1e-12, maxit=500):
    nx, ny = cell.shape
    p, uo, vo, iters, resid = _call("cpdi_poisson_project", nx, ny, flat(cell, np.int32), flat(fill), flat(u),
                                    flat(v), dt, rho, h, beta, tol, maxit)
    shp = (nx, ny)
    return p.reshape(shp, order="F"), uo.reshape(shp, order="F"), vo.reshape(shp, order="F"), iters, resid


def water_faces(cell):
    """Masks of the u and v faces next to water (the faces the projection sets)."""
    w = cell == WATER
    fu = np.zeros_like(w)
    fv = np.zeros_like(w)
    fu[1:, :] = w[1:, :] | w[:-1, :]
    fv[:, 1:] = w[:, 1:] | w[:, :-1]
    return fu, fv


def test_operator_symmetric_positive_definite():
    rng = np.random.default_rng(7)
    nx, ny = 9, 8
    cell = np.where(rng.random((nx, ny)) < 0.8, WATER, AIR).astype(np.int32)
    cell[0, :] = cell[-1, :] = WALL
    cell[:, 0] = WALL
    cell[:, -1] = AIR
    fill = np.where(cell == WATER, rng.uniform(0.4, 1.3, (nx, ny)), rng.uniform(0.0, 0.6, (nx, ny)))
    idx = np.flatnonzero(flat(cell == WATER, bool))
    a = np.zeros((idx.size, idx.size))
    for j, k in enumerate(idx):
        e = np.zeros(nx * ny)
        e[k] = 1.0
        a[:, j] = flat(apply(cell, fill, e.reshape((nx, ny), order="F")))[idx]
    assert np.allclose(a, a.T, atol=1e-12)  # exactly symmetric: the same coefficient serves both cells
    assert np.linalg.eigvalsh(a).min() > 1e-3  # positive definite: the surface pins the pressure


def test_operator_exact_on_manufactured_pressure():
    # p = B (ya^2 - y^2) in cell units: zero at the air cells' centre ya, zero slope at the
    # floor (the wall face), independent of x (walls left and right): the 5-point stencil with
    # these boundaries is exact, A p = -Laplacian(p) = 2 B on every water cell
    cell, fill = tank(8, 7)
    y = np.arange(7) - 0.5  # cell centres, the floor face at 0 (row 0 is the wall ring)
    ya = y[-1]
    p = np.tile(3.0 * (ya**2 - y**2), (8, 1))
    ap = apply(cell, fill, p)
    assert np.allclose(ap[cell == WATER], 6.0, rtol=1e-12)
    # a surface at the top face of the water (air fill 0, water 1: theta = 1/2) and the
    # hydrostatic pressure p = H - y that vanishes on it: A p = 0 in the water, but for the
    # floor row, whose wall face carries no pressure flux: there A p = the unit gradient
    fill0 = np.where(cell == WATER, 1.0, 0.0)
    hyd = np.tile(np.clip(5.0 - y, 0.0, None), (8, 1))
    ap = apply(cell, fill0, hyd)
    floor = np.zeros_like(cell, dtype=bool)
    floor[:, 1] = True
    assert np.abs(ap[(cell == WATER) & ~floor]).max() < 1e-12
    assert np.allclose(ap[(cell == WATER) & floor], 1.0, rtol=1e-12)


def test_projection_makes_gravity_hydrostatic():
    # v* = -g dt on every face (the first step of water at rest): the projection returns
    # v = 0 on every face next to water and p = rho g (H - y) with H on the water's top face
    cell, _ = tank(8, 7)
    fill = np.where(cell == WATER, 1.0, 0.0)
    dt, rho, h, g = 0.01, 1000.0, 0.1, 9.81
    u = np.zeros((8, 7))
    v = np.full((8, 7), -g * dt)
    p, uo, vo, iters, resid = project(cell, fill, u, v, dt, rho, h)
    fu, fv = water_faces(cell)
    assert np.abs(vo[fv]).max() < 1e-10 * g * dt and np.abs(uo[fu]).max() < 1e-12
    yc = (np.arange(7) - 0.5) * h
    exact = rho * g * (5 * h - yc)
    assert np.allclose(p[cell == WATER], np.tile(exact, (8, 1))[cell == WATER], rtol=1e-9)


def stream_field(nx, ny, rng):
    """A discretely divergence-free face field: the curl of a node stream function that is
    zero on the walls' nodes (no flow through them)."""
    psi = rng.standard_normal((nx + 1, ny + 1))
    psi[:2, :] = psi[-2:, :] = 0.0
    psi[:, :2] = 0.0
    u = psi[:-1, 1:] - psi[:-1, :-1]  # u(i, j) = psi(i, j+1) - psi(i, j)  (h = 1 here)
    v = -(psi[1:, :-1] - psi[:-1, :-1])
    return u, v


def test_projection_keeps_divergence_free_and_removes_gradient():
    rng = np.random.default_rng(3)
    nx, ny = 10, 9
    cell, fill = tank(nx, ny)  # theta = 1: phi = 0 at the air cells' centres
    w0u, w0v = stream_field(nx, ny, rng)
    fu, fv = water_faces(cell)
    # divergence-free: unchanged, no pressure
    p, uo, vo, _, _ = project(cell, fill, w0u, w0v, dt=1.0, rho=1.0, h=1.0)
    assert np.abs(uo - w0u)[fu].max() < 1e-12 and np.abs(vo - w0v)[fv].max() < 1e-12
    assert np.abs(p).max() < 1e-10
    # Helmholtz: w = w0 + grad(phi), phi = 0 in air, no flux through walls; the projection
    # returns w0 and p = rho phi / dt
    phi = np.where(cell == WATER, rng.standard_normal((nx, ny)), 0.0)
    gu = np.zeros((nx, ny))
    gv = np.zeros((nx, ny))
    gu[1:, :] = phi[1:, :] - phi[:-1, :]
    gv[:, 1:] = phi[:, 1:] - phi[:, :-1]
    wall_u = np.zeros((nx, ny), bool)
    wall_v = np.zeros((nx, ny), bool)
    wall_u[1:, :] = (cell[1:, :] == WALL) != (cell[:-1, :] == WALL)
    wall_v[:, 1:] = (cell[:, 1:] == WALL) != (cell[:, :-1] == WALL)
    gu[wall_u] = 0.0
    gv[wall_v] = 0.0
    p, uo, vo, _, _ = project(cell, fill, w0u + gu, w0v + gv, dt=1.0, rho=1.0, h=1.0)
    assert np.abs(uo - w0u)[fu].max() < 1e-9 and np.abs(vo - w0v)[fv].max() < 1e-9
    assert np.allclose(p[cell == WATER], phi[cell == WATER], atol=1e-9)


def test_cg_reaches_its_tolerance_and_fails_clearly():
    rng = np.random.default_rng(11)
    cell, fill = tank(24, 20)
    u = rng.standard_normal(cell.shape)
    v = rng.standard_normal(cell.shape)
    its = []
    for tol in (1e-4, 1e-8, 1e-12):
        *_, iters, resid = project(cell, fill, u, v, tol=tol)
        assert resid <= tol
        its.append(iters)
    assert its[0] < its[1] < its[2]  # a real iteration, not a direct solve that ignores tol
    with pytest.raises(CpdiError, match=r"did not converge \(relative residual") as ei:
        project(cell, fill, u, v, tol=1e-12, maxit=2)
    assert ei.value.kind == "solve"


def disc_sim(transfer, shape):
    """A disc of water (radius 0.2 m, 2x2 particles per cell of 0.05 m) rotating rigidly
    about the centre of a 1 m box, no gravity, incompressible water."""
    h, c, omega = 0.05, np.array([0.5, 0.5]), 2.0
    g = (np.arange(0, 1.0, h / 2) + h / 4)
    x = np.array([(a, b) for b in g for a in g if np.hypot(a - c[0], b - c[1]) < 0.2])
    n = len(x)
    v = omega * np.stack([-(x[:, 1] - c[1]), x[:, 0] - c[0]], axis=1)
    r = np.tile([h / 4, 0.0, 0.0, h / 4], (n, 1))
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 20), h, ("slip",) * 4)
    sim.set_materials([{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 1.0}])
    sim.set_particles(x, v, np.full(n, 1000.0 * (h / 2) ** 2), np.full(n, (h / 2) ** 2), r, np.zeros(n, int))
    sim.set_bodies(np.zeros(n, int))
    sim.set_options(shape=shape, gravity=(0.0, 0.0), fluid="incompressible", transfer=transfer, flip=0.0)
    full = sim.get_full_state()  # the affine matrix of the rotation, C = L = [0, omega, -omega, 0]
    full["particles"][8:12, :] = np.array([0.0, omega, -omega, 0.0])[:, None]
    sim.set_full_state(full["particles"], full["scalars"])
    return sim, c


def angular_momentum(sim, c):
    st = sim.state()
    d = st["x"] - c
    return float(np.sum(d[:, 0] * st["v"][:, 1] - d[:, 1] * st["v"][:, 0])), st["v"].sum(axis=0)


@pytest.mark.parametrize("shape", ["mpm", "cpdi"])
def test_apic_keeps_angular_momentum_through_the_transfer(shape):
    sim, c = disc_sim("apic", shape)
    l0, p0 = angular_momentum(sim, c)
    for _ in range(3):
        sim.transfer_cycle()
    l1, p1 = angular_momentum(sim, c)
    sim.close()
    assert abs(l1 - l0) <= 1e-12 * abs(l0)  # affine fields are exact through APIC
    assert np.abs(p1 - p0).max() <= 1e-12 * abs(l0) / 0.2
    sim, c = disc_sim("flip", shape)  # PIC (flip = 0) on the same disc loses it
    l0, _ = angular_momentum(sim, c)
    sim.transfer_cycle()
    l1, _ = angular_momentum(sim, c)
    sim.close()
    assert l1 < 0.99 * l0


def test_small_resting_tank_stays_at_rest():
    h, depth = 0.05, 0.5
    g = np.arange(0, 1.0, h / 2) + h / 4
    x = np.array([(a, b) for b in g for a in g if b < depth])
    n = len(x)
    sim = Simulation()
    sim.set_grid((0.0, 0.0), (20, 20), h, {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"})
    sim.set_materials([{"model": "newtonian_fluid", "density": 1000.0, "bulk_modulus": 1.0}])
    sim.set_particles(x, np.zeros((n, 2)), np.full(n, 1000.0 * (h / 2) ** 2), np.full(n, (h / 2) ** 2),
                      np.tile([h / 4, 0.0, 0.0, h / 4], (n, 1)), np.zeros(n, int))
    sim.set_bodies(np.zeros(n, int))
    sim.set_options(gravity=(0.0, -9.81), fluid="incompressible", cfl=0.5)
    sim.advance(2.0)
    st, d = sim.state(), sim.diagnostics()
    sim.close()
    mgh = 1000.0 * depth * 1.0 * 9.81 * depth
    assert d["kinetic_energy"] < 1e-12 * mgh  # exact at rest up to the CG tolerance
    assert np.abs(st["x"] - x).max() < 1e-6 * h
    p = -st["sigma"][:, 0]
    inner = (x[:, 0] > h) & (x[:, 0] < 1.0 - h) & (x[:, 1] > h)  # away from the wall-clamped cells
    exact = 1000.0 * 9.81 * (depth - st["x"][:, 1])
    assert np.abs(p - exact)[inner].max() < 1e-6 * 1000.0 * 9.81 * depth
