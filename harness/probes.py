"""Case probes: scalar measurements of the particle state written to series.csv.

* ``front_x``: surge front. Among particles of the material in the floor layer
  (y < floor + layer, layer = one cell by default), the largest x that has at least
  ``min_count`` floor-layer particles within two particle spacings behind it, so an
  isolated droplet ahead of the front does not count; plus half a particle spacing, the
  extent of the particle's domain (so the front of a fresh column is exactly its width).
* ``column_height``: largest y of the material's particles in the wall layer
  (x < left wall + layer), plus half a particle spacing, measured from the floor.
* ``displacement_x`` / ``displacement_y``: displacement of the particle that started
  nearest to ``point``.
* ``com_x``, ``com_y``, ``com_vx``, ``com_vy``: centre of mass and its velocity.
* ``bottom``, ``top``, ``left``, ``right``: extent of the particles (centre -/+ half a spacing).
* ``surface_pressure`` (:class:`SurfacePressure`, incompressible water only): the water's pressure on
  a solid body's surface at given points, one column ``<name>_<i>`` per point [Pa].
"""

from __future__ import annotations

import numpy as np

from harness.cases import Case
from harness.seeding import ParticleSet

SURFACE_STEPS = 12  # surface_pressure: steps of h/4 along the normal, so at most 3 h out


class ProbeSet:
    """Evaluates every probe of a case on a particle state."""

    def __init__(self, case: Case, parts: ParticleSet):
        self.names = list(case["probes"])
        self.specs = case["probes"]
        grid = case["grid"]
        self.h = grid["cell"]
        self.origin = np.asarray(grid["origin"])
        mats = [m["name"] for m in case["materials"]]
        self.spacing = min(self.h / b["ppc"] for b in case["bodies"])
        self.x0 = parts.x.copy()
        self.mass = parts.mass
        self.masks = {}
        self.anchor = {}
        self.names = [n for n in self.names if self.specs[n]["kind"] != "surface_pressure"]
        for name, p in self.specs.items():
            if p["kind"] == "surface_pressure":
                continue
            mask = np.ones(parts.n, bool)
            if "material" in p:
                mask = parts.mat == mats.index(p["material"])
            self.masks[name] = mask
            if p["kind"].startswith("displacement"):
                cand = np.flatnonzero(mask)
                d = np.hypot(*(self.x0[cand] - np.asarray(p["point"])).T)
                self.anchor[name] = int(cand[np.argmin(d)])

    def evaluate(self, x: np.ndarray, v: np.ndarray | None = None) -> dict[str, float]:
        out = {}
        for name in self.names:
            p = self.specs[name]
            kind = p["kind"]
            layer = p.get("layer", self.h)
            mask = self.masks[name]
            sel = x[mask]
            if kind.startswith("com_"):
                w = self.mass[mask]
                arr = sel if kind in ("com_x", "com_y") else v[mask]
                out[name] = float(np.average(arr[:, 0 if kind.endswith("x") else 1], weights=w))
                continue
            if kind in ("bottom", "top", "left", "right"):
                c = sel[:, 1] if kind in ("bottom", "top") else sel[:, 0]
                lo = kind in ("bottom", "left")
                out[name] = float(c.min() - 0.5 * self.spacing if lo else c.max() + 0.5 * self.spacing)
                continue
            if kind == "front_x":
                out[name] = front_x(sel, self.origin[1] + layer, self.spacing, p["min_count"]) \
                    + 0.5 * self.spacing - self.origin[0]
            elif kind == "column_height":
                wall = sel[sel[:, 0] < self.origin[0] + layer]
                out[name] = float(wall[:, 1].max() + 0.5 * self.spacing - self.origin[1]) if len(wall) else 0.0
            else:
                comp = 0 if kind == "displacement_x" else 1
                a = self.anchor[name]
                out[name] = float(x[a, comp] - self.x0[a, comp])
        return out


def front_x(x: np.ndarray, floor_top: float, spacing: float, min_count: int) -> float:
    """Largest x in the floor layer backed by min_count particles within 2 spacings."""
    xs = np.sort(x[x[:, 1] < floor_top, 0])[::-1]
    if len(xs) == 0:
        return float("nan")
    window = 2.0 * spacing
    # number of floor particles in (xs[i] - window, xs[i]]
    counts = np.searchsorted(-xs, -(xs - window), side="left") - np.arange(len(xs))
    ok = np.flatnonzero(counts >= min_count)
    return float(xs[ok[0]] if len(ok) else xs[-1])


def boundary_normal(geo: dict, pt) -> tuple[float, np.ndarray]:
    """Distance from pt to the boundary of a rectangle, disc or polygon, and the outward unit normal
    there (the nearest edge's for a rectangle or polygon, the radial direction for a disc)."""
    pt = np.asarray(pt, float)
    kind = geo["type"]
    if kind == "disc":
        r = pt - np.asarray(geo["center"], float)
        rad = float(np.hypot(*r))
        n = r / rad if rad > 0 else np.array([0.0, 1.0])
        return abs(rad - geo["radius"]), n
    if kind == "rectangle":
        lo, hi = np.asarray(geo["min"], float), np.asarray(geo["max"], float)
        c, a = 0.5 * (lo + hi), np.radians(geo.get("angle", 0.0))
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        corners = [lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]]
        v = np.array([c + rot @ (np.asarray(q) - c) for q in corners])
    elif kind == "polygon":
        v = np.asarray(geo["vertices"], float)
    else:
        raise ValueError(f"surface_pressure takes a rectangle, disc or polygon, not a {kind}")
    best, normal = np.inf, None
    for a, b in zip(v, np.roll(v, -1, axis=0), strict=True):  # counter-clockwise: outward is the edge turned right
        e = b - a
        s = float(np.clip(np.dot(pt - a, e) / np.dot(e, e), 0.0, 1.0))
        d = float(np.hypot(*(pt - (a + s * e))))
        if d < best:
            best, normal = d, np.array([e[1], -e[0]]) / float(np.hypot(*e))
    return best, normal


class SurfacePressure:
    """The ``surface_pressure`` probes of a case: the incompressible water's pressure at points on a
    solid body's surface, as series.csv columns ``<name>_<i>`` [Pa].

    Each point is given on the body's boundary at t = 0, with the outward normal n0 of its geometry
    there (:func:`boundary_normal`). It moves with the body: x = c + R (x0 - c0), n = R n0, with c0, c
    the body's particle centroid (mass-weighted) at t = 0 and now and R the rotation that fits the
    particles' displacement best (least squares; a prescribed ``rigid`` body only translates). The
    pressure read there is the cell pressure of the first water cell met walking out along n from the
    point in steps of h/4, at most 3 h (``SURFACE_STEPS``): a cell holding a water particle and no
    particle of the body (the body's own staircase of cells is skipped). None within 3 h: the point is
    dry, 0. So the reading is the pressure of the water at a distance between 0 and about 1.5 h from
    the surface (a cell centre), without extrapolation onto it."""

    def __init__(self, case: Case, parts: ParticleSet):
        grid = case["grid"]
        self.h, self.origin = grid["cell"], np.asarray(grid["origin"], float)
        self.ncell = (round(grid["size"][0] / self.h), round(grid["size"][1] / self.h))
        self.probes: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
        for name, p in case["probes"].items():
            if p["kind"] != "surface_pressure":
                continue
            i = next(k for k, b in enumerate(case["bodies"]) if b["name"] == p["body"])
            idx = np.flatnonzero(parts.body == i)
            geo = case["bodies"][i]["geometry"]
            pts = np.asarray(p["points"], float)
            normals = np.array([boundary_normal(geo, q)[1] for q in pts])
            self.probes.append((name, idx, pts, normals))
        self.mass = parts.mass
        self.x0 = parts.x.copy()

    @property
    def names(self) -> list[str]:
        return [f"{name}_{k}" for name, _, pts, _ in self.probes for k in range(len(pts))]

    def placed(self, idx: np.ndarray, pts: np.ndarray, normals: np.ndarray, x: np.ndarray):
        """The points and normals moved with the body's particles idx (now at x[idx])."""
        m = self.mass[idx]
        c0 = np.average(self.x0[idx], axis=0, weights=m)
        c = np.average(x[idx], axis=0, weights=m)
        r0, r = self.x0[idx] - c0, x[idx] - c
        theta = np.arctan2(np.sum(m * (r0[:, 0] * r[:, 1] - r0[:, 1] * r[:, 0])), np.sum(m * np.sum(r0 * r, axis=1)))
        rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
        return c + (pts - c0) @ rot.T, normals @ rot.T

    def sample(self, cell_p: np.ndarray, water: np.ndarray, body_x: np.ndarray, pts: np.ndarray,
               normals: np.ndarray) -> np.ndarray:
        """Pressure of the first water cell (not holding a particle of the body) along each normal."""
        nx, ny = self.ncell
        body = np.zeros((nx, ny), bool)
        ij = np.floor((body_x - self.origin) / self.h).astype(int)
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        body[ij[ok, 0], ij[ok, 1]] = True
        out = np.zeros(len(pts))
        for k, (q, n) in enumerate(zip(pts, normals, strict=True)):
            for step in range(1, SURFACE_STEPS + 1):
                i, j = np.floor((q + 0.25 * step * self.h * n - self.origin) / self.h).astype(int)
                if not (0 <= i < nx and 0 <= j < ny):
                    break
                if water[i, j] > 0 and not body[i, j]:
                    out[k] = cell_p[i, j]
                    break
        return out

    def evaluate(self, sim, x: np.ndarray) -> dict[str, float]:
        if not self.probes:
            return {}
        g = sim.grid_pressure()
        out = {}
        for name, idx, pts, normals in self.probes:
            q, n = self.placed(idx, pts, normals, x)
            for k, val in enumerate(self.sample(g["pressure"], g["water"], x[idx], q, n)):
                out[f"{name}_{k}"] = float(val)
        return out
