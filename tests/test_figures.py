"""What the figures claim: a curve whose legend names a time shift is drawn shifted by it."""

from __future__ import annotations

import numpy as np

from harness.checks import dam_break_front
from harness.problems import dam_break as db


def _series_leading_by(dT: float) -> dict:
    """A simulated run whose front is the experiment's, dT earlier in T."""
    T = np.linspace(0.0, 4.0, 401)
    t = T / np.sqrt(2 * db.G / db.L)
    Z = np.interp(T + dT, db.FRONT["T"], db.FRONT["Z"])
    return {"t": t, "front_x": Z * db.L, "column_height": np.full_like(t, 2 * db.L)}


def test_shifted_front_is_drawn_shifted() -> None:
    runs = {}
    for name, lead in (("gated", 0.2), ("inc", 0.3)):
        series = _series_leading_by(lead)
        runs[name] = {"series": series, **db.front_metrics(series)}
        assert abs(runs[name]["front_time_shift"] - lead) < 2e-3  # the shift grid is 1e-3
    curves = dam_break_front.front_curves(runs["gated"], runs["inc"])
    shifted = {k: v for k, v in curves.items() if "shifted by dT" in k}
    assert sorted(shifted) == ["CPDI + projection, drawn shifted by dT = +0.20",
                               "incompressible, drawn shifted by dT = +0.30"]
    inside = (db.FRONT["T"] > 0.5) & (db.FRONT["T"] < 3.5)
    for label, (T, Z) in shifted.items():  # drawn shifted, the curve lies on the experiment's points
        assert np.max(np.abs(np.interp(db.FRONT["T"][inside], T, Z) - db.FRONT["Z"][inside])) < 1e-9, label
    for label in ("CPDI + projection (gated), unshifted", "incompressible, unshifted"):
        T, Z = curves[label]  # and unshifted, it does not
        assert np.max(np.abs(np.interp(db.FRONT["T"][inside], T, Z) - db.FRONT["Z"][inside])) > 0.05
