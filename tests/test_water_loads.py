"""Issue 40 through the runner: the water's force and moment on each solid body as series.csv
columns (fortran/src/cpdi_loads.f90, Simulation.water_loads, runner.WaterLoads), velocity tables of
prescribed rigid bodies (fortran/src/cpdi_motion.f90) and the initial spin of a free body. Small
tanks, h = 0.05 m, incompressible water."""

import math

import numpy as np
import pytest

from harness import cases, runner

RHO, G, H = 1000.0, 9.81, 0.05


def tank(solid, geometry, *, t_end=0.2, depth=0.5, omega=0.0, velocity=(0.0, 0.0),
         fluid="incompressible", substeps="implicit"):
    """A 1 m x 1 m tank (slip walls, open top) with water `depth` deep around a body of material
    `solid` (a dict) filling `geometry`. Returns the validated case."""
    raw = {
        "case": {"name": "loads", "requirement": "the water's load on a body"},
        "grid": {"size": [1.0, 1.0], "cell": H, "walls": {"top": "open"}},
        "solver": {"t_end": t_end, "fluid": fluid, "cfl": 0.5, "flip": 0.99,
                   "solid_substeps": substeps, "output_every": t_end, "series_every": 0.01},
        "materials": [{"name": "water", "model": "newtonian_fluid", "density": RHO, "bulk_modulus": 2.0e5},
                      {"name": "body", **solid}],
        "bodies": [{"name": "block", "material": "body", "geometry": geometry, "omega": omega,
                    "velocity": list(velocity)},
                   {"material": "water", "geometry": {"type": "rectangle", "min": [0.0, 0.0], "max": [1.0, depth]},
                    "fill": "around"}],
    }
    return cases.from_dict(raw)


BLOCK = {"type": "rectangle", "min": [0.4, 0.1], "max": [0.6, 0.3]}
SOLIDS = {
    "rigid": {"model": "rigid", "density": 2000.0},
    "hencky": {"model": "hencky", "density": RHO, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3},
    "rigid_body": {"model": "rigid_body", "density": RHO},
}


@pytest.mark.parametrize("kind", ["rigid", "hencky", "rigid_body"])
def test_body_at_rest_in_resting_water_feels_its_buoyancy_and_no_moment(kind):
    # a block 0.2 m x 0.2 m submerged in resting water, held (rigid) or neutrally buoyant (hencky,
    # rigid_body): after the first step the water's force is rho_w g V up and its moment about the
    # block's mass centre zero, to 1e-6 (measured 1e-10); nothing at t = 0, before any step. The
    # neutral bodies keep that in every row. Beside a held body the water does not stay at rest
    # (kinetic energy 3e-8 J after two steps), and
    # its load follows that water's pressure (4e-5 of rho_w g V off after 0.2 s).
    # The Hencky block with the solid's acoustic step (solid_substeps = "off"): the mixture's
    # constraint holds it at its volume, so resting water around it is an equilibrium. With the
    # default "implicit" the projection gives the solid its own bulk stiffness, so a block released
    # unstressed in pressurised water is not at equilibrium: it compresses by p / K, and its load
    # is rho_w g V of its new volume after the transient (tests/test_fsi_incompressible.py,
    # test_implicit_substeps_compress_a_neutral_block_by_its_bulk_stiffness_at_the_waters_pace).
    substeps = "off" if kind == "hencky" else "implicit"
    res = runner.run(tank(SOLIDS[kind], BLOCK, substeps=substeps), progress=False)
    s, b = res.series, RHO * G * 0.2 * 0.2
    assert kind != "rigid" or s["steps"][1] == 1
    assert s["water_fx_block"][0] == 0.0 and s["water_fy_block"][0] == 0.0
    rows = slice(1, None) if kind != "rigid" else slice(1, 2)
    np.testing.assert_allclose(s["water_fy_block"][rows], b, rtol=1e-6)
    assert np.abs(s["water_fx_block"][rows]).max() <= 1e-6 * b
    assert np.abs(s["water_moment_block"][rows]).max() <= 1e-6 * b * 0.2


@pytest.mark.parametrize("kind", ["rigid", "hencky", "rigid_body"])
def test_body_in_air_feels_no_water(kind):
    # the block above a pool 0.2 m deep: no load at all while it is in the air
    geo = {"type": "rectangle", "min": [0.4, 0.6], "max": [0.6, 0.8]}
    res = runner.run(tank(SOLIDS[kind], geo, depth=0.2, t_end=0.1), progress=False)
    for q in ("fx", "fy", "moment"):
        assert np.abs(res.series[f"water_{q}_block"]).max() <= 1e-9 * RHO * G * 0.04


def test_moment_of_the_water_on_an_l_shaped_prescribed_body():
    # an L held still: its leg (0.1 m x 0.3 m under water, centred at x = 0.5) in water symmetric
    # about the leg, its arm in the air. The water's resultant acts on the leg's centre line, so its
    # moment about the body's mass centre (x = 0.575) is -0.075 F_y (clockwise) after the first step,
    # to 1e-6 (measured 1e-12), and F_y is the leg's buoyancy within the free surface's
    # discretisation (measured +1.6 %). (Later the water beside the held body drifts, see above.)
    ell = {"type": "polygon", "vertices": [[0.45, 0.2], [0.55, 0.2], [0.55, 0.6], [0.85, 0.6], [0.85, 0.7],
                                           [0.45, 0.7]]}
    res = runner.run(tank(SOLIDS["rigid"], ell, t_end=0.1), progress=False)
    fy, m = res.series["water_fy_block"][1:2], res.series["water_moment_block"][1:2]
    x = res.parts.x[res.parts.body == 0]
    lever = 0.5 - x[:, 0].mean()
    assert lever == pytest.approx(-0.075, abs=1e-12)
    np.testing.assert_allclose(m, lever * fy, rtol=1e-6)
    np.testing.assert_allclose(fy, RHO * G * 0.1 * 0.3, rtol=0.03)
    assert np.abs(res.series["water_fx_block"][1:2]).max() <= 1e-6 * fy.max()


def table_displacement(table, t):
    """The integral of a piecewise-linear velocity table from 0 to t (held outside its rows)."""
    tab = np.asarray(table, float)
    ts = np.unique(np.r_[0.0, t, tab[:, 0]])
    ts = ts[ts <= t]
    v = np.column_stack([np.interp(ts, tab[:, 0], tab[:, 1]), np.interp(ts, tab[:, 0], tab[:, 2])])
    return np.sum(0.5 * np.diff(ts)[:, None] * (v[1:] + v[:-1]), axis=0)


TABLE = [[0.013, 0.05, 0.0], [0.071, -0.1, -0.3], [0.117, 0.2, 0.1], [0.16, 0.0, -0.2]]


@pytest.mark.parametrize("fluid", ["incompressible", "weakly_compressible"])
def test_prescribed_body_follows_its_velocity_table(fluid):
    # a held disc moved by a table whose breakpoints fall between steps (and whose first row is after
    # t = 0: held before it): after 0.2 s every particle has moved by the table's displacement
    # integral to round-off, whatever the steps; its velocity is the table's mean over the last step
    solid = {"model": "rigid", "density": 800.0, "velocity_table": TABLE}
    geo = {"type": "disc", "center": [0.5, 0.3], "radius": 0.1}
    case = tank(solid, geo, fluid=fluid)
    res = runner.run(case, progress=False)
    sel = res.parts.body == 0
    t = res.summary["simulated_time"]
    moved = res.final["x"][sel] - res.parts.x[sel]
    np.testing.assert_allclose(moved, np.tile(table_displacement(TABLE, t), (sel.sum(), 1)), rtol=0, atol=1e-13)
    assert res.summary["steps"] >= 5
    assert np.abs(res.final["v"][sel] - res.final["v"][sel][0]).max() == 0.0
    # the body moved through the water: the water's load on it is no longer its buoyancy alone
    if fluid == "incompressible":
        assert res.series["water_fx_block"][1:].std() > 0.0


def test_free_body_in_air_keeps_its_spin_and_rigid_body_energy():
    # a rigid_body block thrown with omega = 3 /s over a pool (case key omega): in the air it keeps
    # omega, and its kinetic energy is 1/2 M V^2 + 1/2 J omega^2 with V under gravity alone
    # (J the point masses' inertia about the centre, which the particles' velocities carry)
    geo = {"type": "rectangle", "min": [0.3, 0.6], "max": [0.6, 0.75]}
    case = tank({"model": "rigid_body", "density": 500.0}, geo, depth=0.2, t_end=0.15, omega=3.0, velocity=(0.3, 0.5))
    res = runner.run(case, progress=False)
    x0 = res.parts.x[res.parts.body == 0]
    m = res.parts.mass[res.parts.body == 0]
    j = np.sum(m * np.sum((x0 - x0.mean(axis=0)) ** 2, axis=1))
    s = res.series
    v2 = 0.3 ** 2 + (0.5 - G * s["t"]) ** 2
    # (row 0: the diagnostics before the first step are zero)
    np.testing.assert_allclose(s["kinetic_energy"][1:], (0.5 * m.sum() * v2 + 0.5 * j * 3.0 ** 2)[1:], rtol=1e-12)
    sel = res.parts.body == 0
    x, v = res.final["x"][sel], res.final["v"][sel]
    r = x - x.mean(axis=0)
    omega = np.sum(r[:, 0] * (v[:, 1] - v[:, 1].mean()) - r[:, 1] * (v[:, 0] - v[:, 0].mean())) / np.sum(r * r)
    assert omega == pytest.approx(3.0, abs=1e-12)
    assert math.isclose(np.abs(s["water_fy_block"]).max(), 0.0, abs_tol=0.0)
