"""Case geometry (issue 40): polygons, discs, rotated rectangles and bodies that fill around earlier
ones, seeded on the grid's particle lattice (ppc x ppc per cell, a particle kept by its centre);
and the initial spin `omega`. harness/seeding.py; the keys' malformed inputs: tests/malformed/36-54."""

import math

import numpy as np
import pytest

from harness import cases
from harness.seeding import seed

H = 0.02


def case_with(*bodies, size=(1.0, 1.0), h=H, materials=None):
    raw = {
        "case": {"name": "geo", "requirement": "seeding"},
        "grid": {"size": list(size), "cell": h},
        "solver": {"t_end": 0.1, "fluid": "incompressible"},
        "materials": materials or [{"name": "water", "model": "newtonian_fluid", "density": 1000.0},
                                   {"name": "solid", "model": "rigid_body", "density": 500.0}],
        "bodies": list(bodies),
    }
    return seed(cases.from_dict(raw))


def body(geometry, material="solid", **kw):
    return {"material": material, "geometry": geometry, **kw}


def shoelace(v):
    v = np.asarray(v)
    return 0.5 * np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])


def placements(make, n=40, seed=40):
    """Seeded-area errors, in particle areas, of n random translations of a shape; make(rng)
    returns (geometry, exact area, spacing d)."""
    rng = np.random.default_rng(seed)
    errors = []
    for _ in range(n):
        geo, exact, d, perimeter = make(rng)
        parts = case_with(body(geo, ppc=round(H / d)))
        errors.append((parts.vol.sum() - exact) / (d * d))
        # a particle straddling the boundary is kept or dropped by its centre: the error is at most
        # the area of the strip of half a diagonal either side of the boundary
        assert abs(errors[-1]) <= perimeter * d / math.sqrt(2) / (d * d)
    return np.asarray(errors)


def assert_unbiased(errors):
    # kept or dropped by its centre, a particle straddling the boundary is as likely in as out: the
    # mean error over placements lies within one particle's area of zero, give or take three
    # standard errors of the sample (a rule that kept a domain by any of its corners would gain
    # half the boundary strip: ~60 particle areas here)
    assert abs(errors.mean()) <= 1.0 + 3.0 * errors.std(ddof=1) / math.sqrt(len(errors))


def test_disc_area_is_unbiased_and_bounded():
    # A disc's lattice count carries the Gauss circle problem's error: one particle's area is not a
    # bound for every placement (at R = 20 d: mean |error| 2.4, largest 10 particle areas).
    d = H / 2

    def make(rng):
        c, r = rng.uniform(0.4, 0.6, 2), 20 * d * rng.uniform(0.9, 1.1)
        return {"type": "disc", "center": c.tolist(), "radius": float(r)}, math.pi * r * r, d, 2 * math.pi * r

    assert_unbiased(placements(make))


def test_wedge_area_is_unbiased_and_bounded():
    # a 30-degree wedge 0.4 m wide: its horizontal top edge alone can be half a particle row off
    d, t = H / 2, 0.2 * math.tan(math.radians(30))

    def make(rng):
        o = rng.uniform(0.3, 0.4, 2)
        v = [[o[0] + 0.2, o[1]], [o[0] + 0.4, o[1] + t], [o[0], o[1] + t]]
        return {"type": "polygon", "vertices": v}, 0.2 * t, d, 0.4 + 2 * math.hypot(0.2, t)

    assert_unbiased(placements(make))


@pytest.mark.parametrize("ppc", [1, 2, 4])
def test_polygon_on_the_lattice_has_its_exact_area(ppc):
    # a wedge (sides of slope 1/2, deadrise 26.6 degrees) and a hexagon whose corners lie on the
    # particle lattice's lines and whose edges are level, upright or of slope +-1/2 or +-2 (no
    # particle centre on them): their seeded areas are exact to one particle's area (measured: to
    # round-off). (Slope 1 through lattice corners runs through particle centres: half a row off.)
    d = H / ppc
    for v in ([[0.5, 0.3], [0.7, 0.4], [0.3, 0.4]],
              [[0.3, 0.3], [0.7, 0.3], [0.8, 0.5], [0.6, 0.6], [0.4, 0.6], [0.2, 0.5]]):
        parts = case_with(body({"type": "polygon", "vertices": v}, ppc=ppc))
        assert abs(parts.vol.sum() - shoelace(v)) <= d * d
        assert parts.x[:, 1].min() > 0.3   # every centre inside: none below the apex or the base


def test_rotated_rectangle_matches_its_area_centroid_and_second_moments():
    # 0.4 m x 0.2 m turned by 30 degrees counter-clockwise about its centre (0.5, 0.5): the seeded
    # area, centroid and second moments of area about the centroid against the exact ones
    # (Ixx, Iyy, Ixy of the turned rectangle; Ixy < 0 for a counter-clockwise turn of a wide one)
    a, w, hgt, c = math.radians(30.0), 0.4, 0.2, np.array([0.5, 0.5])
    parts = case_with(body({"type": "rectangle", "min": [0.3, 0.4], "max": [0.7, 0.6], "angle": 30.0}, ppc=4))
    d = H / 4
    area = parts.vol.sum()
    assert abs(area - w * hgt) <= 0.005 * w * hgt                    # measured 0.03 %
    centroid = np.average(parts.x, axis=0, weights=parts.vol)
    assert np.all(np.abs(centroid - c) <= 0.05 * d)
    r = parts.x - centroid
    # the particles' own domains add d^2/12 per particle to each axis' moment
    ixx = np.sum(parts.vol * (r[:, 1] ** 2 + d * d / 12))
    iyy = np.sum(parts.vol * (r[:, 0] ** 2 + d * d / 12))
    ixy = np.sum(parts.vol * r[:, 0] * r[:, 1])
    i_u, i_v = w * hgt ** 3 / 12, hgt * w ** 3 / 12                     # about the body's own axes
    exact_xx = i_u * math.cos(a) ** 2 + i_v * math.sin(a) ** 2
    exact_yy = i_u * math.sin(a) ** 2 + i_v * math.cos(a) ** 2
    exact_xy = (i_v - i_u) * math.sin(a) * math.cos(a)
    scale = i_v
    assert abs(ixx - exact_xx) <= 0.005 * scale
    assert abs(iyy - exact_yy) <= 0.005 * scale
    assert abs(ixy - exact_xy) <= 0.005 * scale
    assert exact_xy > 0.1 * scale   # (the check can tell the turn's sense)


FINE = 0.001   # sampling of the tank for overlaps and gaps


def coverage(x, dd, shape):
    """Per fine sample point (FINE-spaced cell centres over `shape` cells): how many square domains
    (centres x on a lattice of spacing dd from the origin, side dd) hold it."""
    count = np.zeros(shape, int)
    k = round(dd / FINE)
    i0 = np.rint((x - dd / 2) / FINE).astype(int)   # the domain's first fine cell per axis
    for a in range(k):
        for b in range(k):
            np.add.at(count, (i0[:, 0] + a, i0[:, 1] + b), 1)
    return count


def box_max(mask, k):
    """True where a True of mask lies within k fine cells (max norm)."""
    out = mask.copy()
    for axis in (0, 1):
        acc = out.copy()
        for s in range(1, k + 1):
            acc |= np.roll(out, s, axis) | np.roll(out, -s, axis)
        out = acc
    return out


@pytest.mark.parametrize("ppc_body", [2, 4, 1])
@pytest.mark.parametrize("geometry", [
    {"type": "disc", "center": [0.503, 0.311], "radius": 0.117},
    {"type": "polygon", "vertices": [[0.5, 0.2], [0.7, 0.2 + 0.2 * math.tan(math.radians(20))],
                                     [0.3, 0.2 + 0.2 * math.tan(math.radians(20))]]},
], ids=["disc", "wedge"])
def test_water_filled_around_a_body_leaves_no_overlap_and_no_gap(geometry, ppc_body):
    # water (2 particles per cell) around a disc or a wedge seeded with 1, 2 or 4 per cell: no
    # water domain overlaps the body's; with the same lattice the two tile the tank exactly, and
    # otherwise no point of the tank is farther than one water particle spacing from a domain
    dw = H / 2
    parts = case_with(body(geometry, ppc=ppc_body),
                      body({"type": "rectangle", "min": [0.0, 0.0], "max": [1.0, 0.6]}, "water", fill="around"))
    solid, water = parts.x[parts.body == 0], parts.x[parts.body == 1]
    db = H / ppc_body
    shape = (round(1.0 / FINE), round(0.6 / FINE))
    cw, cs = coverage(water, dw, shape), coverage(solid, db, shape)
    assert not np.any((cw > 0) & (cs > 0))          # no overlap
    gap = (cw + cs) == 0
    if ppc_body == 2:
        assert len(water) + len(solid) == round(1.0 * 0.6 / dw ** 2)
        assert not gap.any()                        # the two tile the tank
    # no gap as wide as a water particle: every uncovered point lies within half a water spacing of
    # a covered one, in both directions (a gap of width w leaves points w/2 from cover)
    assert box_max(~gap, round(dw / 2 / FINE) - 1).all()


def test_subtract_leaves_out_only_the_named_bodies():
    discs = [body({"type": "disc", "center": [0.3, 0.3], "radius": 0.1}, name="a"),
             body({"type": "disc", "center": [0.7, 0.3], "radius": 0.1}, name="b")]
    water = {"type": "rectangle", "min": [0.0, 0.0], "max": [1.0, 0.6]}
    parts = case_with(*discs, body(water, "water", subtract=["a", "b"]))
    assert np.sum(parts.body == 2) == round(0.6 / (H / 2) ** 2) - np.sum(parts.body < 2)
    with pytest.raises(cases.CaseError, match=r"bodies\[2\] overlaps bodies\[1\]"):   # b was not subtracted
        case_with(*discs, body(water, "water", subtract=["a"]))


def test_omega_spins_the_body_about_its_centroid():
    parts = case_with(body({"type": "disc", "center": [0.5, 0.5], "radius": 0.1}, velocity=[0.3, -0.2], omega=4.0))
    r = parts.x - parts.x.mean(axis=0)
    np.testing.assert_allclose(parts.v, np.array([0.3, -0.2]) + 4.0 * np.column_stack([-r[:, 1], r[:, 0]]),
                               rtol=0, atol=1e-15)
    # the spin adds no momentum
    np.testing.assert_allclose((parts.mass[:, None] * parts.v).sum(axis=0) / parts.mass.sum(), [0.3, -0.2],
                               atol=1e-14)
