"""Water-structure cases: published obstacle-tip curves, snapshot frames, energy budget."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from harness import refdata

TIP = refdata.read("elastic_obstacle_tip_displacement_mitsume2023_digitized.csv")
CURVES = ("walhorn", "idelsohn", "rafiee", "ryzhakov", "li")


def published(name: str) -> tuple[np.ndarray, np.ndarray]:
    sel = TIP["source_curve"] == name
    t, u = TIP["t"][sel], TIP["ux"][sel]
    order = np.argsort(t)
    return t[order], u[order]


def envelope(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound of the five published curves at times t (linear interpolation)."""
    vals = np.array([np.interp(t, *published(c)) for c in CURVES])
    return vals.min(axis=0), vals.max(axis=0)


def outside_envelope_rms(t: np.ndarray, u: np.ndarray, t0: float = 0.1, t1: float = 0.5) -> float:
    """RMS distance of u(t) outside the published band over t0 <= t <= t1 (0 inside the band)."""
    tt = np.linspace(t0, t1, 401)
    uu = np.interp(tt, t, u)
    lo, hi = envelope(tt)
    d = np.where(uu < lo, lo - uu, np.where(uu > hi, uu - hi, 0.0))
    return float(np.sqrt(np.mean(d**2)))


def frames(run_dir: Path, times) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    """(t, position, pressure, material) of the snapshots nearest to the given times."""
    out = []
    with h5py.File(run_dir / "snapshots.h5", "r") as f:
        g = f["snapshots"]
        stamps = {float(g[k].attrs["time"]): k for k in g}
        for t in times:
            k = stamps[min(stamps, key=lambda s: abs(s - t))]
            out.append((float(g[k].attrs["time"]), g[k]["position"][:], g[k]["pressure"][:], g[k]["material"][:]))
    return out


def fsi_panels(path: Path, frames_, fluid_mat: int, xlim, ylim, title: str, prange=None) -> None:
    """Snapshots side by side: water coloured by pressure, solids in one colour."""
    import matplotlib.pyplot as plt

    from harness import plots  # noqa: F401  (Agg backend)

    n = len(frames_)
    aspect = (ylim[1] - ylim[0]) / (xlim[1] - xlim[0])
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n + 1.2, 3.6 * aspect + 1.2), squeeze=False)
    allp = np.concatenate([p[m == fluid_mat] for _, _, p, m in frames_]) / 1e3
    vmin, vmax = prange if prange else np.nanpercentile(allp, [1, 99])
    for ax, (t, x, p, m) in zip(axes[0], frames_, strict=True):
        w = m == fluid_mat
        sc = ax.scatter(x[w, 0], x[w, 1], c=p[w] / 1e3, s=1.0, cmap="viridis", vmin=vmin, vmax=vmax, linewidths=0)
        ax.scatter(x[~w, 0], x[~w, 1], c="tab:red", s=1.5, linewidths=0)
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_aspect("equal")
        ax.set_title(f"t = {t:.2f} s", fontsize=9)
    fig.colorbar(sc, ax=axes[0].tolist(), label="water pressure [kPa] (solid in red)", shrink=0.85)
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
