"""harness.water: fill, volume change, surface height and wall sensor on constructed inputs with
known answers (the resting_tank, floating_block, dam_break_front and dam_break_pressure checks
gate on these measures)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness import water

ORIGIN = (-0.3, 0.2)  # not at zero, so a dropped origin shows
H = 0.1
NCELL = (5, 4)  # not square, so swapped axes show


def lattice(lo, hi, d):
    """Particles of spacing d (volume d*d, CPDI half-vectors (d/2, 0), (0, d/2)) tiling lo-hi."""
    xs = np.arange(lo[0] + d / 2, hi[0] - d / 4, d)
    ys = np.arange(lo[1] + d / 2, hi[1] - d / 4, d)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    x = np.column_stack([X.ravel(), Y.ravel()])
    r = np.tile([d / 2, 0.0, 0.0, d / 2], (len(x), 1))
    return x, r, np.full(len(x), d * d)


def centre(i, j):
    return np.array([ORIGIN[0] + (i + 0.5) * H, ORIGIN[1] + (j + 0.5) * H])


# --------------------------------------------------------------------------- cell_fill


def test_particle_at_a_cell_centre_fills_only_that_cell():
    vol = 0.3 * H**2
    fill = water.cell_fill(centre(3, 1)[None, :], np.array([vol]), ORIGIN, H, NCELL)
    expect = np.zeros(NCELL)
    expect[3, 1] = 0.3
    assert fill.shape == NCELL
    np.testing.assert_allclose(fill, expect, atol=1e-12)


def test_off_centre_particle_spreads_bilinearly_to_four_cells():
    # 0.25 h right of and 0.1 h above the centre of cell (1, 2)
    x = centre(1, 2) + [0.25 * H, 0.1 * H]
    fill = water.cell_fill(x[None, :], np.array([H**2]), ORIGIN, H, NCELL)
    expect = np.zeros(NCELL)
    expect[1, 2], expect[2, 2] = 0.75 * 0.9, 0.25 * 0.9
    expect[1, 3], expect[2, 3] = 0.75 * 0.1, 0.25 * 0.1
    np.testing.assert_allclose(fill, expect, atol=1e-12)


@pytest.mark.parametrize("shift", [-1e-9, 0.0, 1e-9])
def test_fill_is_continuous_as_a_particle_crosses_a_cell_centre_or_face(shift):
    """The bilinear weights switch their base cell at a cell centre: the fill must not jump."""
    vol = np.array([H**2])
    at_centre = water.cell_fill((centre(2, 1) + [shift, 0.0])[None, :], vol, ORIGIN, H, NCELL)
    ref = np.zeros(NCELL)
    ref[2, 1] = 1.0
    np.testing.assert_allclose(at_centre, ref, atol=1e-7)
    # on the face between cells (2, 1) and (3, 1): half in each
    at_face = water.cell_fill((centre(2, 1) + [0.5 * H + shift, 0.0])[None, :], vol, ORIGIN, H, NCELL)
    ref = np.zeros(NCELL)
    ref[2, 1] = ref[3, 1] = 0.5
    np.testing.assert_allclose(at_face, ref, atol=1e-7)


@pytest.mark.parametrize("corner, cell", [((0.2, 0.2), (0, 0)), ((4.8, 0.2), (4, 0)), ((0.2, 3.8), (0, 3)),
                                          ((4.8, 3.8), (4, 3))])
def test_share_beyond_the_domain_edge_lands_in_the_edge_cell(corner, cell):
    x = np.array([[ORIGIN[0] + corner[0] * H, ORIGIN[1] + corner[1] * H]])
    fill = water.cell_fill(x, np.array([H**2]), ORIGIN, H, NCELL)
    expect = np.zeros(NCELL)
    expect[cell] = 1.0
    np.testing.assert_allclose(fill, expect, atol=1e-12)


@pytest.mark.parametrize("ppc", [2, 3])
def test_lattice_filling_the_domain_fills_every_cell_exactly_once(ppc):
    hi = (ORIGIN[0] + NCELL[0] * H, ORIGIN[1] + NCELL[1] * H)
    x, _, vol = lattice(ORIGIN, hi, H / ppc)
    assert len(x) == NCELL[0] * NCELL[1] * ppc**2
    np.testing.assert_allclose(water.cell_fill(x, vol, ORIGIN, H, NCELL), 1.0, atol=1e-12)
    assert water.volume_change(x, vol, ORIGIN, H, NCELL) == pytest.approx(0.0, abs=1e-12)


def test_fill_conserves_the_particles_volume():
    rng = np.random.default_rng(3)
    x = np.column_stack([ORIGIN[0] + rng.uniform(0, NCELL[0] * H, 50), ORIGIN[1] + rng.uniform(0, NCELL[1] * H, 50)])
    vol = rng.uniform(0.1, 1.0, 50) * H**2
    fill = water.cell_fill(x, vol, ORIGIN, H, NCELL)
    assert fill.min() >= 0.0
    assert fill.sum() * H**2 == pytest.approx(vol.sum(), rel=1e-12)


# --------------------------------------------------------------------------- volume_change


def test_column_of_water_in_a_taller_domain_loses_nothing():
    """A body at its own volume (fill <= 1 everywhere, its surface cells part-filled): 0."""
    x, _, vol = lattice(ORIGIN, (ORIGIN[0] + NCELL[0] * H, ORIGIN[1] + 2 * H), H / 2)
    fill = water.cell_fill(x, vol, ORIGIN, H, NCELL)
    # the row above the surface gets the top particles' upper quarter share: 0.25 * 1/2
    np.testing.assert_allclose(fill[:, 2], 0.125, atol=1e-12)
    np.testing.assert_allclose(fill[:, 1], 0.875, atol=1e-12)
    np.testing.assert_allclose(fill[:, 0], 1.0, atol=1e-12)
    assert water.volume_change(x, vol, ORIGIN, H, NCELL) == pytest.approx(0.0, abs=1e-12)


def test_doubled_lattice_overfills_by_half_its_volume():
    hi = (ORIGIN[0] + NCELL[0] * H, ORIGIN[1] + NCELL[1] * H)
    x, _, vol = lattice(ORIGIN, hi, H / 2)
    x2, vol2 = np.vstack([x, x]), np.concatenate([vol, vol])
    assert water.volume_change(x2, vol2, ORIGIN, H, NCELL) == pytest.approx(-0.5, rel=1e-12)


def test_one_overfilled_cell_by_hand():
    # 3 h^2 in one cell and 0.5 h^2 alone in another: 2 h^2 beyond full, of 3.5 h^2
    x = np.array([centre(1, 1), centre(3, 2)])
    vol = np.array([3.0, 0.5]) * H**2
    assert water.volume_change(x, vol, ORIGIN, H, NCELL) == pytest.approx(-2.0 / 3.5, rel=1e-12)


def test_overfill_change_takes_nothing_away_for_sparse_water():
    """The measure before (reported beside volume_change): under-filled cells count nothing."""
    hi = (ORIGIN[0] + NCELL[0] * H, ORIGIN[1] + NCELL[1] * H)
    x, _, vol = lattice(ORIGIN, hi, H / 2)
    assert water.overfill_change(x, 0.5 * vol, ORIGIN, H, NCELL) == 0.0
    x2, vol2 = np.vstack([x, x]), np.concatenate([vol, vol])
    assert water.overfill_change(x2, vol2, ORIGIN, H, NCELL) == pytest.approx(-0.5, rel=1e-12)


def test_spread_out_water_gains_volume():
    """Water spread over the whole domain at fill 0.6 occupies 1/0.6 of its volume."""
    hi = (ORIGIN[0] + NCELL[0] * H, ORIGIN[1] + NCELL[1] * H)
    x, _, vol = lattice(ORIGIN, hi, H / 2)
    assert water.volume_change(x, 0.6 * vol, ORIGIN, H, NCELL) == pytest.approx(1.0 / 0.6 - 1.0, rel=1e-12)


def test_spray_takes_nothing_away():
    """Isolated drops (no neighbour at fill >= 1/2) are surface: they occupy what they fill."""
    x = np.array([centre(0, 3), centre(2, 1), centre(4, 3)])
    assert water.volume_change(x, np.full(3, 0.3 * H**2), ORIGIN, H, NCELL) == pytest.approx(0.0, abs=1e-12)


# A tank wider than NCELL, so the water has a free surface and an interior: 14 x 10 cells, the water
# 10 cells wide (its right side free) and 5 deep, 2 x 2 particles a cell.
TANK = (14, 10)
T0 = (0.0, 0.0)


def tank(width=1.0, depth=0.5, d=H / 2):
    return lattice(T0, (width, depth), d)


def test_lattice_at_its_own_volume_reads_zero():
    x, _, vol = tank()
    fill = water.cell_fill(x, vol, T0, H, TANK)
    inner = water.interior_cells(fill)
    assert inner[:9, :4].all() and not inner[9, :].any() and not inner[:, 4].any()   # the surface is not interior
    assert water.volume_change(x, vol, T0, H, TANK) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("squeeze", [0.98, 0.99])
def test_compressed_lattice_reads_its_compression(squeeze):
    """The lattice squeezed vertically in a box it spans (walls left and right, 20 rows deep): the
    19 interior rows over-fill by 1/squeeze; the top row, part-filled, shows nothing (the surface
    rule cannot tell packing from less water there), so the measure reads about 19/20 of the
    compression (to the lattice's sampling of the fill)."""
    box = (30, 30)
    x, _, vol = lattice(T0, (3.0, 2.0), H / 2)
    vc = water.volume_change(x * [1.0, squeeze], vol, T0, H, box)
    assert vc == pytest.approx(19 / 20 * (1.0 - 1.0 / squeeze), rel=0.02)
    assert vc == pytest.approx(-(1.0 - squeeze), rel=0.06)


def test_interior_gap_reads_the_gap():
    """Particles removed from the middle: the under-filled cells are water spread out, +gap / V."""
    x, _, vol = tank()
    for removed in (np.all(np.abs(x - [0.5 * H + 0.5, 2.5 * H]) < H / 2, axis=1),      # one cell's 4
                    np.all(np.abs(x - [0.575, 0.275]) < H / 8, axis=1)):               # one particle
        keep = ~removed
        gap = vol[removed].sum()
        assert gap > 0.0
        assert water.volume_change(x[keep], vol[keep], T0, H, TANK) == pytest.approx(gap / vol[keep].sum(), rel=1e-9)


def test_gap_two_cells_across_is_an_air_bubble():
    """Documented limit: a gap two cells across has its own surface and reads no change."""
    x, _, vol = tank()
    keep = ~np.all(np.abs(x - [0.6, 0.25]) < [H, H / 2], axis=1)
    assert (~keep).sum() == 8
    assert water.volume_change(x[keep], vol[keep], T0, H, TANK) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("depth", [0.25, 0.22, 0.24, 0.27])
def test_part_filled_surface_row_reads_zero(depth):
    """The top row half filled (depth 2.5 h), or any other part: the surface's share, not a change."""
    x, _, vol = tank(depth=depth, d=H / 10)
    fill = water.cell_fill(x, vol, T0, H, TANK)
    assert 0.2 < fill[0, 2] < 0.8
    assert water.volume_change(x, vol, T0, H, TANK) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("c", [0.63, 0.83])
def test_tilted_surface_reads_zero(c):
    """A 45 degree surface x + y < c: the 8-neighbour rule keeps its cells out of the interior
    (with 4 neighbours the cells under it would count whole at fills below 1)."""
    x, _, vol = lattice(T0, (1.0, 1.0), H / 10)
    k = x[:, 0] + x[:, 1] < c
    assert water.volume_change(x[k], vol[k], T0, H, TANK) == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------- surface_height


def test_surface_of_a_resting_column_is_its_height():
    x, r, _ = lattice((0.0, 0.0), (1.0, 0.35), 0.025)
    assert water.surface_height(x, r, 0.0, 1.0) == pytest.approx(0.35, abs=1e-12)
    # half-vectors of either sign: the domain's extent counts, not its orientation
    assert water.surface_height(x, -r, 0.0, 1.0) == pytest.approx(0.35, abs=1e-12)


def test_surface_counts_both_half_vectors_vertical_extent():
    d = 0.025
    x, r, _ = lattice((0.0, 0.0), (0.5, 0.2), d)
    sheared = r + [0.0, 0.1 * d, 0.0, 0.0]  # a sheared domain: half-height d/2 + d/10
    top = 0.2 - d / 2 + 0.6 * d
    assert water.surface_height(x, sheared, 0.0, 0.5) == pytest.approx(top, abs=1e-12)


def test_surface_is_the_mean_over_columns_of_each_columns_top():
    d = 0.05
    low, rl, _ = lattice((0.0, 0.0), (0.2, 0.3), d)  # 4 columns, 6 particles high
    high, rh, _ = lattice((0.2, 0.0), (0.5, 0.5), d)  # 6 columns, 10 particles high
    x, r = np.vstack([low, high]), np.vstack([rl, rh])
    order = np.random.default_rng(1).permutation(len(x))  # the top is found, not taken as the last
    x, r = x[order], r[order]
    assert water.surface_height(x, r, 0.0, 0.5) == pytest.approx((4 * 0.3 + 6 * 0.5) / 10, abs=1e-12)
    # only the columns strictly between x_lo and x_hi
    assert water.surface_height(x, r, 0.0, 0.2) == pytest.approx(0.3, abs=1e-12)
    assert water.surface_height(x, r, 0.2, 0.5) == pytest.approx(0.5, abs=1e-12)


def test_surface_excludes_particles_exactly_on_the_window_bounds():
    d = 0.05
    x, r, _ = lattice((0.0, 0.0), (0.5, 0.3), d)
    spike = np.array([[0.125, 2.0], [0.375, 2.0]])  # far above, at the window's two bounds
    xs = np.vstack([x, spike])
    rs = np.vstack([r, r[:2]])
    assert water.surface_height(xs, rs, 0.125, 0.375) == pytest.approx(0.3, abs=1e-12)


# --------------------------------------------------------------------------- wall_sensor


def linear_field(a_left, b_left, a_right, b_right, ny=12):
    yc = ORIGIN[1] + (np.arange(ny) + 0.5) * H
    p = np.zeros((NCELL[0], ny))
    p[0] = a_left + b_left * yc
    p[-1] = a_right + b_right * yc
    p[1:-1] = 1e6  # interior cells are not read
    return p


@pytest.mark.parametrize("diameter", [0.05, 0.3])
def test_sensor_on_a_linear_pressure_field_reads_the_value_at_its_centre(diameter):
    p = linear_field(1000.0, -2000.0, 500.0, -3000.0)
    z = ORIGIN[1] + 0.57
    assert water.wall_sensor(p, ORIGIN, H, "left", z, diameter) == pytest.approx(1000.0 - 2000.0 * z, rel=1e-12)
    assert water.wall_sensor(p, ORIGIN, H, "right", z, diameter) == pytest.approx(500.0 - 3000.0 * z, rel=1e-12)


def test_sensor_averages_over_a_disc_face():
    """p = |y - z| with the kink at a cell centre (so the linear interpolation is exact): the
    chord-weighted mean of |s| over a disc of radius R is R * 4 / (3 pi) (a uniform average
    over the diameter would give R / 2)."""
    ny = 40
    yc = ORIGIN[1] + (np.arange(ny) + 0.5) * H
    z = yc[20]
    p = np.zeros((NCELL[0], ny))
    p[-1] = np.abs(yc - z)
    diameter = 0.8
    got = water.wall_sensor(p, ORIGIN, H, "right", z, diameter)
    assert got == pytest.approx(0.4 * 4 / (3 * math.pi), rel=2e-3)
    assert water.wall_sensor(p, ORIGIN, H, "left", z, diameter) == 0.0


def test_sensor_below_the_first_cell_centre_reads_the_bottom_cell():
    p = linear_field(1000.0, -2000.0, 0.0, 0.0)
    z = ORIGIN[1] + 0.2 * H
    assert water.wall_sensor(p, ORIGIN, H, "left", z, 0.2 * H) == pytest.approx(p[0, 0], rel=1e-12)
