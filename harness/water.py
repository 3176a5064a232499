"""Measures of a body of water from its particles: the volume it occupies, its surface,
and the pressure a flush wall sensor reads.

All take plain arrays (positions (n, 2), CPDI half-vectors (n, 4), volumes (n,)), so a
check can apply them to a final state or to a snapshot.
"""

from __future__ import annotations

import numpy as np


def cell_fill(x: np.ndarray, vol: np.ndarray, origin, h: float, ncell) -> np.ndarray:
    """Fill fraction of every cell (ncell[0], ncell[1]): particle volume spread bilinearly
    over the cell centres, per cell area; at the domain's edges the share beyond lands in
    the edge cell (a wall mirrors the water), as the incompressible solver does."""
    nx, ny = int(ncell[0]), int(ncell[1])
    s = (np.asarray(x) - np.asarray(origin)) / h - 0.5
    i0 = np.floor(s).astype(np.int64)
    f = s - i0
    fill = np.zeros((nx, ny))
    for di in (0, 1):
        wx = f[:, 0] if di else 1.0 - f[:, 0]
        for dj in (0, 1):
            wy = f[:, 1] if dj else 1.0 - f[:, 1]
            np.add.at(fill, (np.clip(i0[:, 0] + di, 0, nx - 1), np.clip(i0[:, 1] + dj, 0, ny - 1)), wx * wy * vol)
    return fill / h**2


def _all_around(mask: np.ndarray) -> np.ndarray:
    """True where each of the 8 cells around (edge and corner neighbours) is True or lies
    beyond the domain's edge (a wall)."""
    nx, ny = mask.shape
    pad = np.ones((nx + 2, ny + 2), dtype=bool)
    pad[1:-1, 1:-1] = mask
    out = np.ones((nx, ny), dtype=bool)
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            if (di, dj) != (1, 1):
                out &= pad[di:di + nx, dj:dj + ny]
    return out


def interior_cells(fill: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """Cells inside the water: each of the 8 cells around it (edge and corner neighbours)
    is water or lies beyond the domain's edge (a wall). A cell is water when its fill is
    >= threshold, or when it is a one-cell gap: its fill lower but all 8 around it at
    >= threshold. The cell's own fill does not decide: an under-filled interior cell is
    water spread out.

    Why 8 neighbours and 1/2: cell_fill spreads volume with the bilinear hat, whose support
    for a cell is the 2h x 2h square around its centre. For water bounded by a straight
    surface, a cell's fill is >= 1/2 exactly when its centre is on the water's side; if all
    8 neighbours' centres are, so is the whole support square (convex, its corners are those
    centres), and the cell's fill is exactly 1 at the water's own volume: a level or tilted
    surface reads no change. With the 4 edge neighbours only, a cell under a 45 degree
    surface could count as interior at fill down to 23/24; with a threshold below 1/2, a
    cell under a level surface at fill below 1. A higher threshold would hand more of the
    water's noisy interior (fills 0.9-1.1) to the surface rule, which does not see
    spreading. The one-cell-gap rule makes a missing cell's worth of particles count as
    gained volume whole (without it the gap's neighbours, next to a cell below 1/2, would
    be surface cells); a gap two cells or more across reads as an air bubble with its own
    surface (no change)."""
    wet = fill >= threshold
    return _all_around(wet | _all_around(wet))


def volume_change(x: np.ndarray, vol: np.ndarray, origin, h: float, ncell) -> float:
    """Relative change of the volume the water occupies, (occupied - V) / V, V the particles'
    volume; positive when the water has spread out (gaps, sparse cells), negative when it
    has packed closer than its particles' volumes allow.

    The occupied volume counts every interior cell (interior_cells: its 8 neighbours water,
    fill >= 1/2, or wall) whole, whatever its fill (an under-filled interior cell is water
    spread out, volume gained; an over-filled one is water packed, volume lost), plus
    min(fill, 1) of every other cell: at the surface a part-filled cell is the surface's
    share of the water, not a change, and an over-filled surface cell counts full. So
    change = [sum over interior cells of (1 - fill) - sum over the others of max(fill - 1, 0)]
    h^2 / V. 0 for a body of water at its own volume, level or tilted surface (to the
    lattice's resolution).

    The measure before (overfill_change) counted the second sum only: it saw packing and
    never spreading, so it read the one-sided volume correction's spread-out water along
    walls as no change (docs/notes/dam_break_pressure_sensor4.md)."""
    fill = cell_fill(x, vol, origin, h, ncell)
    inner = interior_cells(fill)
    occupied = float(np.sum(inner)) + float(np.sum(np.minimum(fill, 1.0)[~inner]))
    v = float(np.sum(vol))
    return (occupied * h**2 - v) / v


def overfill_change(x: np.ndarray, vol: np.ndarray, origin, h: float, ncell) -> float:
    """The volume measure before volume_change counted spreading (reported beside it, not
    gated): - sum over cells of the fill beyond 1, times the cell area, over the particles'
    volume. Sees packing only: spray, gaps and sparse cells fill less than 1 and take
    nothing away."""
    fill = cell_fill(x, vol, origin, h, ncell)
    return -float(np.sum(np.clip(fill - 1.0, 0.0, None))) * h**2 / float(np.sum(vol))


def surface_columns(x: np.ndarray, r: np.ndarray, x_lo: float, x_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """The water's top (particle centre plus half its domain's height) in each particle column
    between x_lo and x_hi: (the column's mean particle x, its top), in column order."""
    half_y = np.abs(r[:, 1]) + np.abs(r[:, 3])
    sel = (x[:, 0] > x_lo) & (x[:, 0] < x_hi)
    cols = np.floor(x[sel, 0] / (2 * np.abs(r[sel, 0]).max())).astype(np.int64)
    tops: dict[int, float] = {}
    xs: dict[int, list[float]] = {}
    for c, xc, top in zip(cols, x[sel, 0], x[sel, 1] + half_y[sel], strict=True):
        tops[c] = max(tops.get(c, -np.inf), top)
        xs.setdefault(c, []).append(xc)
    return (np.array([np.mean(xs[c]) for c in tops]), np.array(list(tops.values())))


def surface_height(x: np.ndarray, r: np.ndarray, x_lo: float, x_hi: float) -> float:
    """Mean height of the water's top (particle centre plus half its domain's height) over
    the particle columns between x_lo and x_hi."""
    return float(np.mean(surface_columns(x, r, x_lo, x_hi)[1]))


def wall_sensor(cell_p: np.ndarray, origin: tuple[float, float], h: float, side: str, z: float,
                diameter: float) -> float:
    """Pressure a flush circular sensor of the given diameter, centred at height z on the
    left or right wall, reads from the cell pressures cell_p (nx, ny): the wall column's
    pressure, linear between cell centres in y, averaged over the sensor's face (weights of
    a disc's chord lengths, 64 points)."""
    col = cell_p[0 if side == "left" else -1, :]
    yc = origin[1] + (np.arange(col.size) + 0.5) * h
    s = np.linspace(-1.0, 1.0, 65)
    s = 0.5 * (s[1:] + s[:-1])
    w = np.sqrt(1.0 - s**2)
    y = z + 0.5 * diameter * s
    return float(np.sum(w * np.interp(y, yc, col)) / np.sum(w))


def wendland_c2(q: np.ndarray) -> np.ndarray:
    """2D Wendland C2 kernel shape of q = r / support (support radius 1), unnormalised:
    (1 - q)^4 (1 + 4 q) for q < 1, else 0. A Shepard average needs no normalisation."""
    q = np.asarray(q, dtype=float)
    return np.where(q < 1.0, (1.0 - np.minimum(q, 1.0)) ** 4 * (1.0 + 4.0 * q), 0.0)


def kernel_wall_sensor(x: np.ndarray, p: np.ndarray, vol: np.ndarray | None, wall_x: float, z: float,
                       length: float, support: float, npoints: int = 10) -> float:
    """Pressure a wall sensor reads as the SPH references of Lobovsky's dam break define it
    (TrixiParticles' pressure sensors; reference/data/lobovsky_2d_numerical/README.md): the
    mean over `npoints` evenly spaced points of a vertical segment of `length` centred at
    height z on the wall x = wall_x (end points included), each point's value a Shepard-
    normalised Wendland C2 average, of compact support radius `support`, of the water
    particles' pressures p (n,) at positions x (n, 2), every negative pressure clipped to 0
    first. Particles weigh by their volume (equal weights if vol is None). A point with no
    particle within its support reads 0."""
    x = np.asarray(x, dtype=float)
    pc = np.clip(np.asarray(p, dtype=float), 0.0, None)
    w0 = np.ones(len(pc)) if vol is None else np.asarray(vol, dtype=float)
    ys = z + length * (np.linspace(0.0, 1.0, npoints) - 0.5)
    vals = []
    for y in ys:
        r = np.hypot(x[:, 0] - wall_x, x[:, 1] - y)
        w = w0 * wendland_c2(r / support)
        s = float(w.sum())
        vals.append(float(np.dot(w, pc)) / s if s > 0.0 else 0.0)
    return float(np.mean(vals))
