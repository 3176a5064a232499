"""The multigrid preconditioner of the pressure CG (fortran/src/cpdi_multigrid.f90), through the
test hooks cpdi_poisson_precond (z = M^-1 r) and cpdi_poisson_project (the solve) of tests/_cpdi_test.

The CG needs M^-1 symmetric positive definite; a preconditioner worth its cost keeps the
iterations flat as h falls, where MIC(0)'s grow like sqrt(cells); and it must not change the
answer beyond the solve's tolerance. Test grids as in tests/test_incompressible.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from harness import solver
from harness.solver import CpdiError
from tests import fortran_hooks
from tests.test_incompressible import (
    AIR,
    PRECONDS,
    WALL,
    WATER,
    apply_op,
    flat,
    irregular_region,
    project,
    surface_tank_problem,
    tank,
)


def precond(cell, fill, r, kind="multigrid"):
    nx, ny = cell.shape
    z = fortran_hooks.call("cpdi_poisson_precond", nx, ny, flat(cell, np.int32), flat(fill), PRECONDS[kind], flat(r))
    return z.reshape((nx, ny), order="F")


def dense_preconditioner(cell, fill, kind="multigrid"):
    """M^-1 restricted to the water cells, column by column."""
    idx = np.flatnonzero(flat(cell == WATER, bool))
    m = np.zeros((idx.size, idx.size))
    for n, k in enumerate(idx):
        e = np.zeros(cell.size)
        e[k] = 1.0
        z = flat(precond(cell, fill, e.reshape(cell.shape, order="F"), kind))
        assert np.all(z[flat(cell != WATER, bool)] == 0.0), "M^-1 r must vanish outside the water"
        m[:, n] = z[idx]
    return m


def odd_tank(rng):
    """37 x 23 cells (odd counts: coarse cells with a single child and the ring), walls left,
    right and bottom, a surface 4 rows below the top, an interior wall block and air holes."""
    cell = tank(37, 23)
    cell[1:-1, -5:] = AIR
    cell[10:14, 5:9] = WALL
    interior = cell[1:-1, 1:-5]
    interior[rng.random(interior.shape) < 0.05] = AIR
    return cell


@pytest.mark.parametrize("grid", ["irregular", "odd_tank"])
def test_multigrid_preconditioner_is_symmetric_positive_definite(rng, grid):
    cell = irregular_region(rng) if grid == "irregular" else odd_tank(rng)
    # every surface branch (theta clamped at 0.1, at 1, in between): coefficients 1..10
    fill = rng.uniform(0.0, 1.3, cell.shape)
    m = dense_preconditioner(cell, fill)
    scale = np.abs(m).max()
    # symmetric to round-off: R = P^T with the same weights, post-smoothing the adjoint of
    # pre-smoothing, a palindromic sweep sequence on the coarsest level
    np.testing.assert_allclose(m, m.T, rtol=0, atol=1e-13 * scale)
    # and in the form the CG uses it: x . M^-1 y == y . M^-1 x for random x, y
    for _ in range(3):
        x, y = rng.standard_normal(cell.shape), rng.standard_normal(cell.shape)
        x[cell != WATER] = y[cell != WATER] = 0.0
        a, b = np.sum(x * precond(cell, fill, y)), np.sum(y * precond(cell, fill, x))
        assert abs(a - b) <= 1e-13 * (abs(a) + abs(b))
    lam = np.linalg.eigvalsh(0.5 * (m + m.T))
    assert lam.min() > 1e-3 * lam.max()  # positive definite, and well so
    # a good approximate inverse: the spectrum of M^-1 A is clustered (condition number measured
    # 1.15-1.25 on the irregular region, 1.46-1.48 on the odd tank; MIC(0)'s 1.7-3.0 and 3.6-6.1),
    # A from the solver's operator
    idx = np.flatnonzero(flat(cell == WATER, bool))
    a_op = np.zeros((idx.size, idx.size))
    for n, k in enumerate(idx):
        e = np.zeros(cell.size)
        e[k] = 1.0
        a_op[:, n] = flat(apply_op(cell, fill, e.reshape(cell.shape, order="F")))[idx]
    w = np.linalg.eigvals(m @ a_op).real
    assert w.min() > 0 and w.max() / w.min() < 3.0, (w.min(), w.max())


def test_the_symmetry_check_can_fail(rng):
    """Contrast: a preconditioner that is not symmetric would be seen. One multigrid V-cycle
    followed by a Jacobi step (z -> z + D^-1 (r - A z) with D = 4, an unsymmetric composition)
    is caught by the same check at the same tolerance."""
    cell = odd_tank(rng)
    fill = rng.uniform(0.0, 1.3, cell.shape)
    x, y = rng.standard_normal(cell.shape), rng.standard_normal(cell.shape)
    x[cell != WATER] = y[cell != WATER] = 0.0

    def composed(r):
        z = precond(cell, fill, r)
        return z + (r - apply_op(cell, fill, z)) / 4.0 * (cell == WATER)

    a, b = np.sum(x * composed(y)), np.sum(y * composed(x))
    assert abs(a - b) > 1e-6 * (abs(a) + abs(b))


def test_multigrid_iterations_stay_flat_as_h_is_halved_twice(rng):
    """A tank (walls left, right and bottom, surface a quarter below the top, random faces) at
    n = 32, 64 and 128 cells a side, solved to 1e-8 (the solver's default tolerance): MIC(0)-CG
    needs more iterations at every halving (measured 27, 42, 72: 2.7x over the two halvings,
    the sqrt(cells) growth), multigrid-CG few and about the same (measured 8, 10, 11: a slow growth
    from the ghost-fluid surface, whose coarse coefficients are the fine ones' mean, not the
    coarse cells' own distance to the surface), fewer than 30 everywhere. With a surface at the
    top cell centres only (no ghost distance) the counts measured 7, 7, 7."""
    its = {"mic0": [], "multigrid": []}
    for n in (32, 64, 128):
        cell = tank(n + 2, n + 2)
        cell[1:-1, -(n // 4):] = AIR
        fill = np.where(cell == WATER, 1.0, 0.2)
        u, v = rng.standard_normal(cell.shape), rng.standard_normal(cell.shape)
        for kind in its:
            _, _, _, iters, resid = project(cell, fill, u, v, dt=0.01, rho=1000.0, h=1.0 / n, tol=1e-8, precond=kind)
            assert resid <= 1e-8
            its[kind].append(iters)
    assert its["mic0"][0] < its["mic0"][1] < its["mic0"][2] and its["mic0"][2] > 2 * its["mic0"][0], its
    assert max(its["multigrid"]) < 30 and its["multigrid"][2] < 1.5 * its["multigrid"][0], its
    assert its["multigrid"][2] < its["mic0"][2] / 4, its


@pytest.mark.parametrize("grid", ["surface_tank", "irregular", "odd_tank"])
def test_multigrid_cg_gives_the_mic0_cg_solution(rng, grid):
    """Both solves stop at the same relative residual, 1e-10: their pressures agree to that
    times the condition number (~1e2-1e3 here), and so do the projected faces."""
    if grid == "surface_tank":
        cell, fill, u, v, _, _ = surface_tank_problem(rng)
    else:
        cell = irregular_region(rng) if grid == "irregular" else odd_tank(rng)
        fill = np.where(cell == WATER, rng.uniform(0.3, 1.0, cell.shape), rng.uniform(0.0, 0.7, cell.shape))
        u, v = rng.standard_normal(cell.shape), rng.standard_normal(cell.shape)
    tol = 1e-10
    out = {k: project(cell, fill, u, v, dt=0.01, rho=1000.0, h=0.05, tol=tol, precond=k) for k in PRECONDS}
    (pm, um, vm, im, rm), (pg, ug, vg, ig, rg) = out["mic0"], out["multigrid"]
    assert rm <= tol and rg <= tol and 1 <= ig < im
    w = cell == WATER
    np.testing.assert_allclose(pg[w], pm[w], rtol=0, atol=1e-7 * np.abs(pm).max())
    np.testing.assert_allclose(ug, um, rtol=0, atol=1e-7 * np.abs(um).max())
    np.testing.assert_allclose(vg, vm, rtol=0, atol=1e-7 * np.abs(vm).max())
    assert not np.any(pg[~w])


def test_multigrid_solve_is_bitwise_independent_of_the_thread_count(rng):
    """Grids above the threading threshold (8192 cells a level): red-black sweeps, residuals,
    transfers and coarse operators run threaded, each cell's value computed in one fixed order,
    so 1, 2 and 3 threads give the same bits."""
    n = 130
    cell = tank(n + 2, n + 2)
    cell[1:-1, -20:] = AIR
    fill = np.where(cell == WATER, 1.0, 0.3)
    u, v = rng.standard_normal(cell.shape), rng.standard_normal(cell.shape)
    before = solver.threads()
    try:
        res = []
        for t in (1, 2, 3):
            assert solver.threads(t) == t
            res.append(project(cell, fill, u, v, dt=0.01, rho=1000.0, h=1.0 / n, tol=1e-10, precond="multigrid"))
    finally:
        solver.threads(before)
    for r in res[1:]:
        assert r[3] == res[0][3] and r[4] == res[0][4]
        for a, b in zip(r[:3], res[0][:3], strict=True):
            np.testing.assert_array_equal(a, b)


def test_multigrid_run_is_bitwise_independent_of_the_thread_count():
    """A dam break stepped with the multigrid preconditioner on a grid above the threshold:
    the same particles at 1 and 2 threads."""
    from harness import cases, runner
    from tools import bench

    d = bench.dam_break_case(16, "cpdi", "none")
    before = solver.threads()
    states = []
    try:
        for t in (1, 2):
            case = cases.from_dict({**d, "solver": {**d["solver"], "fluid": "incompressible", "transfer": "apic",
                                                   "pressure_precond": "multigrid"},
                                   "grid": {**d["grid"], "cell": d["grid"]["cell"] / 8}})
            assert solver.threads(t) == t
            sim, _ = runner.build(case)
            sim.advance(10.0, max_steps=5, land=False)
            states.append((sim.state(), sim.pressure_stats()))
            sim.close()
    finally:
        solver.threads(before)
    (s1, p1), (s2, p2) = states
    assert p1["precond"] == "multigrid" and p1["iterations"] >= 1
    assert p1 == p2
    for key in ("x", "v", "sigma"):
        np.testing.assert_array_equal(s1[key], s2[key])


def test_an_unknown_preconditioner_is_refused():
    cell = tank(6, 6)
    with pytest.raises(CpdiError, match="precond must be 0"):
        fortran_hooks.call("cpdi_poisson_precond", 6, 6, flat(cell, np.int32), flat(np.ones(cell.shape)), 2,
                           flat(np.ones(cell.shape)))
    sim = solver.Simulation()
    with pytest.raises(CpdiError, match="pressure_precond"):
        sim.set_options(fluid="incompressible", pressure_precond="amg")
    sim.close()


def test_make_bench_pressure_rows_compare_both_preconditioners_from_one_state():
    """make bench's pressure rows (tools/bench.py, tools/pressure_bench.py): the dam break at H/30
    stepped to t* = 1, then the same steps from that one state with each preconditioner. The
    multigrid needs fewer iterations than MIC(0) and stays below the issue's 30."""
    from tools import bench

    lines: list[str] = []
    rows = bench.pressure_solver_rows((0.01,), 3, lines.append)
    (r,) = rows
    assert r["H_over_h"] == 30 and r["water_cells"] > 0
    m, g = r["mic0"], r["multigrid"]
    assert g["iterations_max"] < bench.MG_ITERATIONS_MAX
    assert g["iterations_mean"] < m["iterations_mean"]
    assert m["solve_s_per_step"] > 0 and g["solve_s_per_step"] > 0
    assert "MIC(0)" in lines[0] and "multigrid" in lines[0]
