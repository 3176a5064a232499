"""Fill case bodies with particles: ppc x ppc per grid cell, kept where inside the body."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.cases import Case, CaseError


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
    if geo["type"] == "rectangle":
        lo, hi = np.asarray(geo["min"]), np.asarray(geo["max"])
        return np.all((pts >= lo) & (pts < hi), axis=1)  # half-open: touching bodies share no particle
    c = np.asarray(geo["center"])
    rad = np.hypot(pts[:, 0] - c[0], pts[:, 1] - c[1])
    return (rad >= geo["r_inner"]) & (rad <= geo["r_outer"])


def _bounds(geo: dict) -> tuple[np.ndarray, np.ndarray]:
    if geo["type"] == "rectangle":
        return np.asarray(geo["min"]), np.asarray(geo["max"])
    c, r = np.asarray(geo["center"]), geo["r_outer"]
    return c - r, c + r


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
        parts.append(dict(
            x=pts, v=np.tile(np.asarray(body["velocity"], float), (n, 1)), mass=mat["density"] * vol,
            vol=vol, r=np.tile([0.5 * d, 0.0, 0.0, 0.5 * d], (n, 1)),
            mat=np.full(n, names.index(body["material"]), dtype=np.int32), body=np.full(n, ib, dtype=np.int32),
            group=np.full(n, body.get("contact_group", ib), dtype=np.int32)))
    out = ParticleSet(**{k: np.concatenate([p[k] for p in parts]) for k in parts[0]})
    _, out.group = np.unique(out.group, return_inverse=True)  # groups numbered 0..G-1
    out.group = out.group.astype(np.int32)
    return out
