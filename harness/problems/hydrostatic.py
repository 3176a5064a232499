"""Pressure error measures for water at rest and for a collapsing column (FORMULAS 7)."""

from __future__ import annotations

import numpy as np

from harness import cases, paths
from harness.solver import pressure

# the water of the settled column (cases/hydrostatic_column.toml); the collapsing columns the measures
# are also used on (water_column.toml, dam_break.toml) hold the same water and gravity
_CASE = cases.load(paths.CASES / "hydrostatic_column.toml")
RHO, G = _CASE["materials"][0]["density"], -_CASE["solver"]["gravity"][1]


def column_errors(x: np.ndarray, X0: np.ndarray, sigma: np.ndarray, mass: np.ndarray, H: float) -> dict:
    """Errors of particle pressure in a settled column of initial height H, normalised by rho0 g H.

    Two references: the Eulerian rho0 g (H - y) at the current position, and the exact
    Lagrangian weight above each particle, rho0 g (H0 - Y). The oscillation index is the RMS
    of the second difference, between successive particle rows (by initial Y), of the
    row-mean pressure error: zero for any linear error, large for a row-to-row checkerboard.
    """
    p = pressure(sigma)
    scale = RHO * G * H
    e = (p - RHO * G * (H - x[:, 1])) / scale
    e_lag = (p - RHO * G * (H - X0[:, 1])) / scale
    w = mass / mass.sum()
    rows = np.unique(np.round(X0[:, 1], 12))
    row_mean = np.array([e[np.isclose(X0[:, 1], y)].mean() for y in rows])
    d2 = row_mean[2:] - 2 * row_mean[1:-1] + row_mean[:-2]
    return {
        "l2": float(np.sqrt(np.sum(w * e * e))),
        "max": float(np.abs(e).max()),
        "l2_lagrangian": float(np.sqrt(np.sum(w * e_lag * e_lag))),
        "oscillation": float(np.sqrt(np.mean(d2 * d2))) if len(d2) else 0.0,
    }


def local_hydrostatic(x: np.ndarray, bin_width: float, spacing: float) -> np.ndarray:
    """rho g (local surface - y) for water particles, the surface being the highest particle
    (plus half a spacing) in a vertical bin of the given width."""
    bins = np.floor((x[:, 0] - x[:, 0].min()) / bin_width).astype(int)
    top = np.full(bins.max() + 1, -np.inf)
    np.maximum.at(top, bins, x[:, 1])
    return RHO * G * np.clip(top[bins] + 0.5 * spacing - x[:, 1], 0.0, None)


def pressure_noise(x: np.ndarray, sigma: np.ndarray, bin_width: float, spacing: float, height: float) -> float:
    """RMS deviation of particle pressure from the local hydrostatic estimate, / (rho g height)."""
    p = pressure(sigma)
    return float(np.sqrt(np.mean((p - local_hydrostatic(x, bin_width, spacing)) ** 2)) / (RHO * G * height))
