"""Issue 40 item 3: the surface_pressure probe (harness/probes.py SurfacePressure) samples the
incompressible water's pressure at points on a solid body's surface that move with it. Small tank,
h = 0.05 m: a wedge held under resting water reads the hydrostatic pressure on its faces."""

import numpy as np
import pytest

from harness import cases, runner
from harness.probes import boundary_normal

RHO, G, H, DEPTH = 1000.0, 9.81, 0.05, 0.6
WEDGE = [[0.5, 0.2], [0.8, 0.4], [0.2, 0.4]]   # apex down, top face at y = 0.4, 0.2 m under the surface
S = np.linspace(0.1, 0.9, 5)
RIGHT = [[0.5 + 0.3 * s, 0.2 + 0.2 * s] for s in S]    # apex -> right top corner
LEFT = [[0.2 + 0.3 * s, 0.4 - 0.2 * s] for s in S]     # left top corner -> apex
TOP = [[0.3, 0.4], [0.5, 0.4], [0.7, 0.4]]


def tank(points, velocity=(0.0, 0.0), depth=DEPTH, t_end=0.01, gravity=(0.0, -G)):
    raw = {
        "case": {"name": "surface_probe", "requirement": "the probe reads the water's pressure on a body"},
        "grid": {"size": [1.0, 1.0], "cell": H, "walls": {"top": "open"}},
        "solver": {"t_end": t_end, "fluid": "incompressible", "cfl": 0.5, "flip": 0.99, "gravity": list(gravity),
                   "output_every": t_end, "series_every": 0.01},
        "materials": [{"name": "water", "model": "newtonian_fluid", "density": RHO},
                      {"name": "steel", "model": "rigid", "density": 7800.0, "velocity": list(velocity)}],
        "bodies": [{"name": "wedge", "material": "steel", "geometry": {"type": "polygon", "vertices": WEDGE}},
                   {"name": "water", "material": "water",
                    "geometry": {"type": "rectangle", "min": [0.0, 0.0], "max": [1.0, depth]}, "fill": "around"}],
        "probes": {"p": {"kind": "surface_pressure", "body": "wedge", "points": points}},
    }
    return cases.from_dict(raw)


def test_boundary_normal_of_the_wedge_faces_points_out():
    d, n = boundary_normal({"type": "polygon", "vertices": WEDGE}, RIGHT[2])
    assert d < 1e-12
    np.testing.assert_allclose(n, np.array([0.2, -0.3]) / np.hypot(0.2, 0.3))
    _, n = boundary_normal({"type": "polygon", "vertices": WEDGE}, TOP[1])
    np.testing.assert_allclose(n, [0.0, 1.0])
    d, n = boundary_normal({"type": "disc", "center": [0.5, 0.5], "radius": 0.1}, [0.5, 0.38])
    assert d == pytest.approx(0.02) and np.allclose(n, [0.0, -1.0])
    _, n = boundary_normal({"type": "rectangle", "min": [0.0, 0.0], "max": [1.0, 1.0], "angle": 90.0}, [0.5, 1.0])
    np.testing.assert_allclose(n, [0.0, 1.0], atol=1e-12)


def test_held_wedge_in_resting_water_reads_hydrostatic_pressure_on_its_faces():
    # after the first step, each point reads rho g (surface - y) of the water cell it samples: the
    # cell centre lies within 1.5 h of the face along its normal, so the reading is rho g times the
    # depth of the point give or take 1.5 h |n_y| (+ the free surface's place in its cell, h/2)
    pts = RIGHT + LEFT + TOP
    res = runner.run(tank(pts), progress=False)
    s = res.series
    assert s["steps"][1] == 1
    p = np.array([s[f"p_{k}"][1] for k in range(len(pts))])
    assert np.all(np.array([s[f"p_{k}"][0] for k in range(len(pts))]) == 0.0)   # no step, no pressure
    y = np.array(pts)[:, 1]
    expect = RHO * G * (DEPTH - y)
    assert np.all(p > 0)
    assert np.abs(p - expect).max() <= RHO * G * 2.0 * H
    # deeper points read no less (two points may sample one cell), on each sloping face; the two faces
    # read alike (the wedge is symmetric)
    assert np.all(np.diff(p[:5]) <= 1e-6) and np.all(np.diff(p[5:10]) >= -1e-6) and p[0] > p[4] + RHO * G * H
    np.testing.assert_allclose(p[:5], p[5:10][::-1], rtol=1e-6)
    # exactly: each reading is rho g (surface - y_c) of a cell centre y_c at most 1.5 h from its point,
    # on the water's side (below the sloping faces, above the top face)
    yc = DEPTH - p / (RHO * G)
    k = yc / H - 0.5
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)
    assert np.all(y[:10] - yc[:10] > 0) and np.all(yc[10:] - y[10:] > 0)
    assert np.abs(yc - y).max() <= 1.5 * H + 1e-9


def test_points_in_the_air_read_zero_and_the_points_move_with_the_body():
    # the wedge half out of the water (surface at y = 0.3): the top face is dry. Then the wedge moves
    # down at 1 m/s for 0.1 s: the probe's points go with it (by the body's particles' displacement)
    res = runner.run(tank(RIGHT + TOP, depth=0.3), progress=False)
    p = res.series
    assert all(p[f"p_{k}"][1] == 0.0 for k in range(5, 8))
    assert p["p_0"][1] > 0.0                   # the deepest point of the face is wet
    case = tank(RIGHT, velocity=(0.0, -1.0), depth=0.3, t_end=0.1, gravity=(0.0, 0.0))
    sim, parts = runner.build(case)
    try:
        from harness.probes import SurfacePressure

        probe = SurfacePressure(case, parts)
        sim.advance(0.1)
        x = sim.state()["x"]
        name, idx, pts, normals = probe.probes[0]
        moved, n = probe.placed(idx, pts, normals, x)
        np.testing.assert_allclose(moved - pts, np.tile([0.0, -0.1], (len(pts), 1)), atol=1e-9)
        np.testing.assert_allclose(n, normals, atol=1e-9)
    finally:
        sim.close()


def test_a_body_driven_into_water_at_rest_limits_the_step():
    # no gravity, water at rest: only the prescribed body's speed (1 m/s down) sets the step,
    # cfl h / (sqrt(2) |v|) (cpdi_fsi solid_stress); before, the first step went to t = 1e305 s
    case = tank(RIGHT, velocity=(0.0, -1.0), depth=0.3, t_end=0.1, gravity=(0.0, 0.0))
    sim, parts = runner.build(case)
    try:
        steps, t = sim.advance(0.1)
        bound = 0.5 * H / (2.0**0.5 * 1.0)
        assert t == pytest.approx(0.1)
        assert steps >= 0.1 / bound and sim.diagnostics()["dt"] <= bound * (1 + 1e-12)
    finally:
        sim.close()
