"""Fill case bodies with particles: ppc x ppc per grid cell, kept where inside the body."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.cases import Case, CaseError, geometry_bounds


@dataclass
class ParticleSet:
    x: np.ndarray  # (n, 2) positions [m]
    v: np.ndarray  # (n, 2) velocities [m/s]
    mass: np.ndarray  # (n,) [kg/m]
    vol: np.ndarray  # (n,) [m^2]
    r: np.ndarray  # (n, 4) CPDI half-vectors [r1x, r1y, r2x, r2y]
    mat: np.ndarray  # (n,) 0-based material index
    body: np.ndarray  # (n,) 0-based body index
    group: np.ndarray  # (n,) 0-based contact group (velocity field under contact)

    @property
    def n(self) -> int:
        return self.x.shape[0]


def _inside(geo: dict, pts: np.ndarray) -> np.ndarray:
    """Whether each point (n, 2) lies in the geometry: a particle is kept by its centre."""
    kind = geo["type"]
    if kind == "rectangle":
        lo, hi = np.asarray(geo["min"]), np.asarray(geo["max"])
        a = np.radians(geo.get("angle", 0.0))
        if a != 0.0:  # into the rectangle's own frame, about its centre
            c = 0.5 * (lo + hi)
            d = pts - c
            pts = c + np.column_stack([np.cos(a) * d[:, 0] + np.sin(a) * d[:, 1],
                                       -np.sin(a) * d[:, 0] + np.cos(a) * d[:, 1]])
        return np.all((pts >= lo) & (pts < hi), axis=1)  # half-open: touching bodies share no particle
    if kind == "polygon":
        return _in_polygon(np.asarray(geo["vertices"], float), pts)
    c = np.asarray(geo["center"])
    rad = np.hypot(pts[:, 0] - c[0], pts[:, 1] - c[1])
    if kind == "disc":
        return rad <= geo["radius"]
    return (rad >= geo["r_inner"]) & (rad <= geo["r_outer"])


def _in_polygon(v: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Even-odd rule, half-open in y: of two polygons sharing an edge, a point on it is in one only."""
    inside = np.zeros(len(pts), bool)
    px, py = pts[:, 0], pts[:, 1]
    for (x1, y1), (x2, y2) in zip(v, np.roll(v, -1, axis=0), strict=True):
        if y1 == y2:
            continue
        crosses = (y1 <= py) != (y2 <= py)
        xi = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (px < xi)
    return inside


def _bounds(geo: dict) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = geometry_bounds(geo)
    return np.asarray(lo), np.asarray(hi)


def _lattice_index(x: np.ndarray, origin: np.ndarray, d: float) -> np.ndarray:
    """Index (n, 2) of the lattice site (spacing d from origin) of particle centres x."""
    return np.rint((x - origin) / d - 0.5).astype(np.int64)


def _overlapped(pts: np.ndarray, d: float, origin: np.ndarray, others: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """Which candidate sites pts (spacing d) have a domain (a square of side d) that overlaps, by more
    than an edge, the domain of a particle of the other bodies ((centres, spacing) each)."""
    tol = 1e-9
    idx = _lattice_index(pts, origin, d)
    blocked = []
    for q, dq in others:
        s = (q - origin) / d - 0.5  # the other particle's centre, in this lattice's index units
        half = 0.5 * (1.0 + dq / d)  # overlap when |i - s| < half in both directions
        lo = np.floor(s - half + tol).astype(np.int64) + 1
        hi = np.ceil(s + half - tol).astype(np.int64) - 1
        span = int((hi - lo).max()) + 1
        for di in range(span):
            for dj in range(span):
                ij = lo + [di, dj]
                ok = np.all(ij <= hi, axis=1)
                blocked.append(ij[ok])
    if not blocked:
        return np.zeros(len(pts), bool)
    b = np.concatenate(blocked)
    key = lambda a: a[:, 0] * (1 << 31) + a[:, 1]  # noqa: E731
    return np.isin(key(idx), key(b))


def seed(case: Case) -> ParticleSet:
    """Particles of every body at the centres of a ppc x ppc subdivision of each cell."""
    grid = case["grid"]
    h = grid["cell"]
    origin = np.asarray(grid["origin"])
    names = [m["name"] for m in case["materials"]]
    parts = []
    taken: dict[tuple[int, int], int] = {}
    for ib, body in enumerate(case["bodies"]):
        ppc = body["ppc"]
        d = h / ppc
        lo, hi = _bounds(body["geometry"])
        i0 = np.floor((lo - origin) / d + 1e-9).astype(int)
        i1 = np.ceil((hi - origin) / d - 1e-9).astype(int)
        ii, jj = np.meshgrid(np.arange(i0[0], i1[0]), np.arange(i0[1], i1[1]), indexing="xy")
        pts = np.column_stack([origin[0] + (ii.ravel() + 0.5) * d, origin[1] + (jj.ravel() + 0.5) * d])
        pts = pts[_inside(body["geometry"], pts)]
        around = [j for j, other in enumerate(case["bodies"][:ib])
                  if body["fill"] == "around" or other["name"] in body.get("subtract", ())]
        if around and len(pts):
            pts = pts[~_overlapped(pts, d, origin, [(parts[j]["x"], h / case["bodies"][j]["ppc"]) for j in around])]
        if len(pts) == 0:
            raise CaseError(f"bodies[{ib}] contains no particle centre; make it at least one particle "
                            f"spacing ({d:g} m) wide or raise ppc")
        # refuse overlapping bodies: two particles may not share a sub-cell
        keys = np.floor((pts - origin) / (h / 8) ).astype(np.int64)
        for k in map(tuple, keys):
            other = taken.get(k)
            if other is not None and other != ib:
                raise CaseError(f"bodies[{ib}] overlaps bodies[{other}]; bodies must not share space")
            taken[k] = ib
        mat = case["materials"][names.index(body["material"])]
        n = len(pts)
        vol = np.full(n, d * d)
        v = np.tile(np.asarray(body["velocity"], float), (n, 1))
        if "velocity_table" in mat:  # a prescribed body starts with its table's velocity at t = 0
            tab = np.asarray(mat["velocity_table"])
            v[:] = [np.interp(0.0, tab[:, 0], tab[:, 1]), np.interp(0.0, tab[:, 0], tab[:, 2])]
        if body["omega"] != 0.0:  # a spin about the centroid of the body's particles
            rel = pts - pts.mean(axis=0)
            v += body["omega"] * np.column_stack([-rel[:, 1], rel[:, 0]])
        parts.append(dict(
            x=pts, v=v, mass=mat["density"] * vol,
            vol=vol, r=np.tile([0.5 * d, 0.0, 0.0, 0.5 * d], (n, 1)),
            mat=np.full(n, names.index(body["material"]), dtype=np.int32), body=np.full(n, ib, dtype=np.int32),
            group=np.full(n, body.get("contact_group", ib), dtype=np.int32)))
    out = ParticleSet(**{k: np.concatenate([p[k] for p in parts]) for k in parts[0]})
    _, out.group = np.unique(out.group, return_inverse=True)  # groups numbered 0..G-1
    out.group = out.group.astype(np.int32)
    return out
