"""Figure helpers shared by the checks. Conventions: solver results are lines, analytic
solutions dashed, experiments points, and the error metric is printed on the plot."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

COLORS = {"mpm": "tab:orange", "gimp": "tab:green", "cpdi": "tab:blue"}


def _finish(fig, ax, path: Path, title: str, annotate: str | None, legend_loc: str = "best") -> None:
    ax.set_title(title)
    if annotate:
        ax.text(0.98, 0.03, annotate, transform=ax.transAxes, fontsize=9, ha="right", va="bottom",
                bbox=dict(boxstyle="round", fc="white", ec="0.7", alpha=0.9))
    ax.grid(True, alpha=0.3)
    if legend_loc == "below":  # many curves: under the axes, where it hides none of them
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2)
    else:
        ax.legend(fontsize=8, loc=legend_loc)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def loglog_convergence(path: Path, curves: dict[str, tuple[np.ndarray, np.ndarray]], ref_orders=(1, 2),
                       title: str = "", ylabel: str = "error", annotate: str | None = None) -> None:
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name, (h, e) in curves.items():
        ax.loglog(h, e, "-o", color=COLORS.get(name), label=name.upper())
    if curves:
        h0, e0 = next(iter(curves.values()))
        for p in ref_orders:
            ax.loglog(h0, e0[0] * (h0 / h0[0]) ** p, "k--", lw=0.8, alpha=0.6, label=f"slope {p}")
    else:
        ax.text(0.5, 0.5, "no interpolation completed two levels", transform=ax.transAxes, ha="center")
    ax.set_xlabel("h [m]")
    ax.set_ylabel(ylabel)
    _finish(fig, ax, path, title, annotate)


def time_series(path: Path, t, series: dict[str, np.ndarray], exact=None, points=None, xlabel="t", ylabel="",
                title="", annotate: str | None = None, exact_label: str = "analytic", logy: bool = False,
                legend_loc: str = "best") -> None:
    fig, ax = plt.subplots(figsize=(6.5, 5.2 if legend_loc == "below" else 4))
    if logy:
        ax.set_yscale("log")
    for name, y in series.items():  # y is an array over t, or an (x, y) pair of its own
        ax.plot(y[0] if isinstance(y, tuple) else t, y[1] if isinstance(y, tuple) else y, "-", label=name)
    if exact is not None:
        ax.plot(exact[0], exact[1], "k--", lw=1, label=exact_label)
    if points is not None:
        for name, (px, py) in points.items():
            ax.plot(px, py, "o", mfc="none", label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    _finish(fig, ax, path, title, annotate, legend_loc)


def particle_panels(path: Path, frames: list[tuple[str, np.ndarray, np.ndarray]], xlim, ylim, clabel: str,
                    title: str = "") -> None:
    """Side-by-side particle scatter plots coloured by a field: frames = [(label, x (n,2), c (n,))].
    The colour range spans the 1st-99th percentiles of all frames so isolated spikes do not hide the field."""
    aspect = (ylim[1] - ylim[0]) / (xlim[1] - xlim[0])
    width = 4.2 if aspect <= 1.5 else 2.4
    fig, axes = plt.subplots(1, len(frames), figsize=(width * len(frames) + 1.2, width * aspect + 1.3),
                             squeeze=False)
    allc = np.concatenate([np.asarray(c, float) for _, _, c in frames])
    vmin, vmax = (float(v) for v in np.nanpercentile(allc, [1, 99]))
    for ax, (label, x, c) in zip(axes[0], frames, strict=True):
        sc = ax.scatter(x[:, 0], x[:, 1], c=c, s=2, cmap="viridis", vmin=vmin, vmax=vmax, linewidths=0)
        ax.set_xlabel("x [m]")
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_aspect("equal")
        ax.set_title(label, fontsize=9)
    fig.colorbar(sc, ax=axes[0].tolist(), label=clabel + " (1-99 % range)", shrink=0.85, extend="both")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
