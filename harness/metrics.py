"""Numerical verification metrics: error norms, observed orders, Richardson, GCI.

Pure numpy, no plotting. Conventions used throughout:

* Refinement sequences ``h`` / ``e`` are given **coarse -> fine** (h decreasing).
* Three-grid formulas follow Roache (1998) and Celik et al. (2008): ``f1`` is the
  **fine** solution, ``f2`` the medium and ``f3`` the coarse one, ``r = h_coarser /
  h_finer > 1``. To avoid ordering mistakes, :func:`richardson` and :func:`gci` take
  keyword-only arguments.
* Degenerate inputs (zero or negative errors, oscillation, divergence) yield ``nan``
  plus a flag rather than an exception; malformed inputs (shapes, r <= 1) raise
  ``ValueError``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "l2_norm",
    "linf_norm",
    "observed_orders",
    "richardson",
    "gci",
    "gci_from_errors",
    "convergence_table",
    "RichardsonResult",
    "GCIResult",
    "ErrorGCIResult",
]

MONOTONE = "monotone"
OSCILLATORY = "oscillatory"
DIVERGENT = "divergent"
INDETERMINATE = "indeterminate"


# --------------------------------------------------------------------------- norms


def _squared_magnitudes(err: ArrayLike) -> np.ndarray:
    """|e|^2 per entry: e^2 for shape (n,), sum over components for shape (n, d)."""
    e = np.asarray(err, dtype=float)
    if e.ndim == 1:
        return e * e
    if e.ndim == 2:
        return np.einsum("ij,ij->i", e, e)
    raise ValueError(f"error array must have shape (n,) or (n, d), got {e.shape}")


def l2_norm(err: ArrayLike, weights: ArrayLike | None = None) -> float:
    """Weighted RMS norm ``sqrt(sum_i w_i |e_i|^2 / sum_i w_i)``.

    ``err`` has shape (n,) (scalar field) or (n, d) (vector field; ``|e_i|`` is the
    Euclidean norm of row i). ``weights`` (n,) are typically particle masses or
    volumes; ``None`` means equal weights (plain RMS). Returns nan for an empty array.
    """
    sq = _squared_magnitudes(err)
    if sq.size == 0:
        return float("nan")
    if weights is None:
        return float(np.sqrt(np.mean(sq)))
    w = np.asarray(weights, dtype=float)
    if w.shape != sq.shape:
        raise ValueError(f"weights shape {w.shape} does not match error count {sq.shape}")
    if np.any(w < 0):
        raise ValueError("weights must be non-negative")
    wsum = float(np.sum(w))
    if wsum <= 0.0:
        raise ValueError("weights must have a positive sum")
    return float(np.sqrt(np.sum(w * sq) / wsum))


def linf_norm(err: ArrayLike) -> float:
    """Maximum norm ``max_i |e_i|`` (Euclidean norm of each row for (n, d) input)."""
    sq = _squared_magnitudes(err)
    if sq.size == 0:
        return float("nan")
    return float(np.sqrt(np.max(sq)))


# --------------------------------------------------------------------------- orders


def _as_sequence(h: ArrayLike, e: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    hh = np.asarray(h, dtype=float).ravel()
    ee = np.asarray(e, dtype=float).ravel()
    if hh.shape != ee.shape:
        raise ValueError(f"h and e must have the same length, got {hh.size} and {ee.size}")
    return hh, ee


def observed_orders(h: ArrayLike, e: ArrayLike) -> np.ndarray:
    """Observed orders between successive levels, ``p_i = log(e_i/e_{i+1}) / log(h_i/h_{i+1})``.

    ``h`` and ``e`` are ordered as given (normally coarse -> fine). Returns an array of
    length ``len(h) - 1``; an entry is nan when either error is zero, negative or not
    finite, or when the two spacings are equal.
    """
    hh, ee = _as_sequence(h, e)
    out = np.full(max(hh.size - 1, 0), np.nan)
    for i in range(hh.size - 1):
        e0, e1, h0, h1 = ee[i], ee[i + 1], hh[i], hh[i + 1]
        ok = all(np.isfinite(x) and x > 0 for x in (e0, e1, h0, h1)) and h0 != h1
        if ok:
            out[i] = math.log(e0 / e1) / math.log(h0 / h1)
    return out


def _classify(eps21: float, eps32: float) -> str:
    """Convergence type from the ratio R = eps21/eps32 (Stern et al. 2001).

    eps21 = f2 - f1 (medium - fine), eps32 = f3 - f2 (coarse - medium).
    0 < R < 1: monotone; -1 < R < 0: oscillatory convergence; |R| >= 1: divergent;
    a zero difference (or non-finite input): indeterminate.
    """
    if not (math.isfinite(eps21) and math.isfinite(eps32)) or eps32 == 0.0 or eps21 == 0.0:
        return INDETERMINATE
    ratio = eps21 / eps32
    if abs(ratio) >= 1.0:
        return DIVERGENT
    return MONOTONE if ratio > 0 else OSCILLATORY


def _three_level_order(eps21: float, eps32: float, r21: float, r32: float) -> float:
    """Order p from three solutions with ratios r21 (medium/fine h) and r32 (coarse/medium h).

    Constant ratio: closed form ``ln(eps32/eps21)/ln r``. Otherwise the fixed-point
    iteration of Celik et al. (2008), eq. (3). Requires eps32/eps21 > 0; returns nan when
    the iteration does not converge.
    """
    s = eps32 / eps21
    if s <= 0:
        return float("nan")
    if math.isclose(r21, r32, rel_tol=1e-12):
        return math.log(s) / math.log(r21)
    p = math.log(s) / math.log(r21)
    for _ in range(200):
        try:
            q = math.log((r21**p - 1.0) / (r32**p - 1.0))
        except (ValueError, ZeroDivisionError, OverflowError):
            return float("nan")
        p_new = (math.log(s) + q) / math.log(r21)
        if abs(p_new - p) < 1e-12 * max(1.0, abs(p)):
            return p_new
        p = p_new
    return float("nan")


def _check_ratio(r: float) -> float:
    r = float(r)
    if not (math.isfinite(r) and r > 1.0):
        raise ValueError(f"refinement ratio r must be > 1 (coarser h / finer h), got {r}")
    return r


# --------------------------------------------------------------------------- Richardson / GCI


@dataclass(frozen=True)
class RichardsonResult:
    """Three-grid Richardson extrapolation.

    p: observed order (nan unless ``convergence`` is monotone or monotone-divergent).
    f_extrapolated: estimate of the h -> 0 limit (nan unless monotone).
    convergence: ``"monotone"``, ``"oscillatory"``, ``"divergent"`` or ``"indeterminate"``.
    ratio: R = (f2 - f1) / (f3 - f2); 0 < R < 1 is monotone convergence.
    """

    p: float
    f_extrapolated: float
    convergence: str
    ratio: float

    @property
    def converging(self) -> bool:
        return self.convergence in (MONOTONE, OSCILLATORY)


def richardson(*, f_coarse: float, f_medium: float, f_fine: float, r: float) -> RichardsonResult:
    """Richardson extrapolation from three solutions with constant refinement ratio ``r``.

    In Roache's notation f1 = ``f_fine``, f2 = ``f_medium``, f3 = ``f_coarse`` and
    ``r = h_coarse/h_medium = h_medium/h_fine > 1``:

        p       = ln((f3 - f2) / (f2 - f1)) / ln r
        f_exact ~ f1 + (f1 - f2) / (r^p - 1)

    Oscillatory convergence (f3 - f2 and f2 - f1 of opposite sign) gives p = nan,
    f_extrapolated = nan and ``convergence == "oscillatory"``. Divergence (differences
    not shrinking) gives p <= 0 (nan if also oscillating) and f_extrapolated = nan.
    """
    r = _check_ratio(r)
    f1, f2, f3 = float(f_fine), float(f_medium), float(f_coarse)
    eps21, eps32 = f2 - f1, f3 - f2
    kind = _classify(eps21, eps32)
    ratio = eps21 / eps32 if eps32 != 0.0 else float("nan")
    p = _three_level_order(eps21, eps32, r, r) if kind in (MONOTONE, DIVERGENT) else float("nan")
    f_ext = f1 + (f1 - f2) / (r**p - 1.0) if kind == MONOTONE else float("nan")
    return RichardsonResult(p=p, f_extrapolated=f_ext, convergence=kind, ratio=ratio)


@dataclass(frozen=True)
class GCIResult:
    """Roache's grid convergence index (relative form).

    gci12: GCI of the fine solution, gci23: GCI of the medium solution, both as fractions
    (0.01 = 1 %). asymptotic_ratio = gci23 / (r^p gci12), ~1 in the asymptotic range.
    """

    p: float
    f_extrapolated: float
    gci12: float
    gci23: float
    asymptotic_ratio: float
    convergence: str

    @property
    def converging(self) -> bool:
        return self.convergence in (MONOTONE, OSCILLATORY)


def _relative_change(fa: float, fb: float) -> float:
    """|(fa - fb) / fa|, nan when fa == 0."""
    return abs((fa - fb) / fa) if fa != 0.0 else float("nan")


def gci(*, f1: float, f2: float, f3: float, r: float, fs: float = 1.25) -> GCIResult:
    """Grid convergence index for fine (f1), medium (f2) and coarse (f3) solutions.

    Keyword-only, Roache convention: **f1 is the fine solution**, f3 the coarse one,
    constant ratio ``r = h3/h2 = h2/h1 > 1``; ``fs`` is the safety factor (1.25 for
    three-grid studies).

        e_a12 = |(f1 - f2) / f1|,  GCI12 = fs e_a12 / (r^p - 1)
        e_a23 = |(f2 - f3) / f2|,  GCI23 = fs e_a23 / (r^p - 1)
        asymptotic_ratio = GCI23 / (r^p GCI12)   (~1 in the asymptotic range)

    Note: for a monotone sequence and constant r, asymptotic_ratio is identically
    |f1/f2| (substitute r^p = (f3-f2)/(f2-f1)), so it is ~1 whenever f1 ~ f2 and is a
    weak indicator on its own; compare ``p`` with the formal order as well.

    p and f_extrapolated come from :func:`richardson`. When the sequence is not
    monotonically converging the GCI values are nan (check ``convergence``); the
    relative form is also nan when f1 (or f2) is zero.
    """
    rich = richardson(f_coarse=f3, f_medium=f2, f_fine=f1, r=r)
    nan = float("nan")
    if rich.convergence != MONOTONE:
        return GCIResult(rich.p, nan, nan, nan, nan, rich.convergence)
    rp = r**rich.p
    gci12 = fs * _relative_change(float(f1), float(f2)) / (rp - 1.0)
    gci23 = fs * _relative_change(float(f2), float(f3)) / (rp - 1.0)
    asym = gci23 / (rp * gci12) if gci12 != 0.0 else nan
    return GCIResult(rich.p, rich.f_extrapolated, gci12, gci23, asym, rich.convergence)


@dataclass(frozen=True)
class ErrorGCIResult:
    """GCI-style summary of an error-norm refinement study (see :func:`gci_from_errors`)."""

    p: float  # order between the two finest levels (exact limit 0 known)
    p_medium: float  # order between the medium and coarse of the three finest levels
    p_lsq: float  # least-squares slope of log e vs log h over the three finest levels
    p_three_level: float  # Roache three-level order of the sequence f = e (limit not assumed)
    e_fine: float
    e_limit: float  # Richardson limit of the error sequence; ~0 if converging to the exact solution
    gci_fine: float  # absolute: fs |e1 - e2| / (r21^p - 1) == fs * e_fine
    gci_medium: float  # absolute: fs |e2 - e3| / (r32^p - 1)
    asymptotic_ratio: float  # (r32^p_medium - 1) / (r32^p - 1), ~1 in the asymptotic range
    convergence: str  # three-level classification of the error sequence

    @property
    def converging(self) -> bool:
        return self.convergence in (MONOTONE, OSCILLATORY)


def gci_from_errors(h: ArrayLike, e: ArrayLike, fs: float = 1.25) -> ErrorGCIResult:
    """GCI-style analysis when the exact solution is known and only error norms are available.

    ``h``, ``e`` are ordered coarse -> fine; the three finest levels are used (index -3
    coarse, -2 medium, -1 fine), i.e. e1 = fine, e2 = medium, e3 = coarse.

    Definition (and why). With an analytic reference the fine-grid error e1 is *known*,
    so the GCI's job -- estimating the unknown fine-grid error -- is already done. Two
    naive choices are meaningless and are deliberately **not** used:

    * Roache's relative form on f = e gives GCI12 = fs |e1 - e2| / (|e1| (r^p - 1)) = fs
      identically in the asymptotic range (e2 = r^p e1), whatever the solver does.
    * The absolute form with the three-level p gives asymptotic ratio == 1 identically
      (p is defined so that it holds).

    What is reported instead:

    * ``p``: order between the two finest levels, ``log(e2/e1)/log(h2/h1)`` -- the exact
      limit (zero error) is known, so two levels suffice. ``p_medium`` is the next pair,
      ``p_lsq`` the least-squares slope over the three levels.
    * ``gci_fine = fs |e1 - e2| / (r21^p - 1)`` (absolute, Roache with f = e). With the
      two-level p this equals ``fs * e1`` exactly: the GCI degenerates to the
      safety-factored known error. ``gci_medium = fs |e2 - e3| / (r32^p - 1)`` applies the
      *fine-pair* order to the medium pair.
    * ``asymptotic_ratio = (r32^p_medium - 1) / (r32^p - 1)``, which for a constant ratio
      equals Roache's ``gci_medium / (r^p gci_fine)``; it is ~1 exactly when the fine and
      medium pairs show the same order, i.e. the study is in the asymptotic range.
    * ``p_three_level`` / ``e_limit``: Roache's three-level order and Richardson limit of
      the sequence f = e *without* assuming the limit is zero (Celik iteration for
      non-constant ratios). ``e_limit`` ~ 0 (relative to e1) means the scheme converges
      to the analytic solution; a clearly positive value reveals an error floor or an
      inconsistency. ``convergence`` is the three-level classification of the errors.
    """
    hh, ee = _as_sequence(h, e)
    if hh.size < 3:
        raise ValueError(f"gci_from_errors needs at least three levels, got {hh.size}")
    h3, h2, h1 = hh[-3:]
    e3, e2, e1 = (float(x) for x in ee[-3:])
    if not (h3 > h2 > h1 > 0):
        raise ValueError(f"the three finest h must be positive and decreasing, got {hh[-3:]}")
    nan = float("nan")
    r21, r32 = h2 / h1, h3 / h2
    p_medium, p = observed_orders([h3, h2, h1], [e3, e2, e1])
    p_lsq = _lsq_slope(hh[-3:], ee[-3:])

    gci_fine = gci_medium = asym = nan
    if math.isfinite(p) and p > 0:
        gci_fine = fs * abs(e1 - e2) / (r21**p - 1.0)
        gci_medium = fs * abs(e2 - e3) / (r32**p - 1.0)
        if math.isfinite(p_medium):
            asym = (r32**p_medium - 1.0) / (r32**p - 1.0)

    eps21, eps32 = e2 - e1, e3 - e2
    kind = _classify(eps21, eps32)
    p3 = _three_level_order(eps21, eps32, r21, r32) if kind in (MONOTONE, DIVERGENT) else nan
    e_limit = e1 + (e1 - e2) / (r21**p3 - 1.0) if kind == MONOTONE and math.isfinite(p3) and p3 > 0 else nan
    return ErrorGCIResult(
        p=float(p),
        p_medium=float(p_medium),
        p_lsq=p_lsq,
        p_three_level=p3,
        e_fine=e1,
        e_limit=e_limit,
        gci_fine=gci_fine,
        gci_medium=gci_medium,
        asymptotic_ratio=asym,
        convergence=kind,
    )


def _lsq_slope(h: np.ndarray, e: np.ndarray) -> float:
    """Least-squares slope of log e against log h (nan if any value is non-positive)."""
    if np.any(~np.isfinite(e)) or np.any(e <= 0) or np.any(h <= 0):
        return float("nan")
    slope, _ = np.polyfit(np.log(h), np.log(e), 1)
    return float(slope)


# --------------------------------------------------------------------------- tables


def convergence_table(h: ArrayLike, e: ArrayLike, norm_name: str = "L2") -> str:
    """Markdown table with columns h, error and observed rate (blank on the first row)."""
    hh, ee = _as_sequence(h, e)
    rates = observed_orders(hh, ee)
    lines = [f"| h | {norm_name} error | rate |", "| ---: | ---: | ---: |"]
    for i, (hi, ei) in enumerate(zip(hh, ee, strict=True)):
        rate = "" if i == 0 else ("n/a" if not np.isfinite(rates[i - 1]) else f"{rates[i - 1]:.2f}")
        lines.append(f"| {hi:.4g} | {ei:.3e} | {rate} |")
    return "\n".join(lines) + "\n"
