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
"""

from __future__ import annotations

import numpy as np

from harness.cases import Case
from harness.seeding import ParticleSet


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
        for name, p in self.specs.items():
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
