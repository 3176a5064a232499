"""Dam break (Martin & Moyce 1952, n^2 = 2): set-up variants and the comparison with the data.

Z = x_front / L against T = t sqrt(2 g / L) (Table 2), H = eta / (2L) against
tau = t sqrt(g / L) (Table 6). The experiment's time origin is uncertain by ~0.1-0.2 in T,
so the best-fit shift of the simulated T is reported next to the unshifted misfit.
"""

from __future__ import annotations

import numpy as np

from harness import cases, paths, refdata, runner

CASE = paths.CASES / "dam_break.toml"
_CASE = cases.load(CASE)
L = cases.geometry_bounds(_CASE["bodies"][0]["geometry"])[1][0]   # the column's width
G = -_CASE["solver"]["gravity"][1]
K_REAL = _CASE["materials"][0]["bulk_modulus"]   # real water: the weakly compressible runs'
RHO = _CASE["materials"][0]["density"]
T_END = _CASE["solver"]["t_end"]
CFL = _CASE["solver"]["cfl"]
FRONT = refdata.read("martin_moyce_1952_front_n2eq2_a2.25in_table2.csv")
HEIGHT = refdata.read("martin_moyce_1952_height_n2eq2_a2.25in_table6.csv")


# The case file's water is the incompressible one (APIC, no volumetric projection); the weakly
# compressible water (the seed paper's, FLIP) is these overrides.
WEAKLY_COMPRESSIBLE = ['solver.fluid="weakly_compressible"', 'solver.transfer="flip"']


def load(cell: float, *, fluid: str, shape: str = "cpdi", projection: str = "cell", K: float | None = None,
         kinematics: str = "log", t_end: float | None = None):
    """cases/dam_break.toml at cell size ``cell``; ``fluid``: "incompressible" (the case file's water)
    or "weakly_compressible" (WEAKLY_COMPRESSIBLE; K is its bulk modulus, the case's by default). The
    incompressible water refuses a volumetric projection: give it projection="none"."""
    K = K_REAL if K is None else K
    t_end = T_END if t_end is None else t_end
    if fluid not in ("incompressible", "weakly_compressible"):
        raise ValueError(f"fluid must be incompressible or weakly_compressible, got {fluid!r}")
    water = WEAKLY_COMPRESSIBLE if fluid == "weakly_compressible" else []
    return cases.load(CASE, [*water, f"grid.cell={cell}", f'solver.shape="{shape}"',
                             f'solver.projection="{projection}"', f"materials.0.bulk_modulus={K}",
                             f'solver.kinematics="{kinematics}"', f"solver.t_end={t_end}"])


def run(cell, out_dir=None, progress=False, **kw):
    return runner.run(load(cell, **kw), out_dir, progress=progress, snapshots=out_dir is not None)


def dimensionless(series: dict) -> dict:
    t = series["t"]
    return {"T": t * np.sqrt(2 * G / L), "Z": series["front_x"] / L, "tau": t * np.sqrt(G / L),
            "H": series["column_height"] / (2 * L)}


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def front_metrics(series: dict, z_max: float | None = None) -> dict:
    """Misfits against Table 2 (front) and Table 6 (height). With z_max, front data at
    Z >= z_max are left out: a simulated tank of z_max L cannot show a front beyond it."""
    d = dimensionless(series)
    Texp, Zexp = FRONT["T"], FRONT["Z"]
    ok = Texp <= d["T"][-1]
    if z_max is not None:
        ok &= Zexp < z_max
    Texp, Zexp = Texp[ok], Zexp[ok]

    def misfit(shift):  # simulated curve moved later by `shift` in T
        return np.interp(Texp - shift, d["T"], d["Z"]) - Zexp

    shifts = np.linspace(-0.5, 0.5, 1001)
    costs = [_rms(misfit(s)) for s in shifts]
    best = float(shifts[int(np.argmin(costs))])
    hok = HEIGHT["tau"] <= d["tau"][-1]
    dh = np.interp(HEIGHT["tau"][hok], d["tau"], d["H"]) - HEIGHT["H"][hok]
    return {"front_rms_dz": _rms(misfit(0.0)), "front_time_shift": best, "front_rms_dz_shifted": _rms(misfit(best)),
            "front_max_dz": float(np.abs(misfit(0.0)).max()), "height_rms_dh": _rms(dh),
            "front_points": int(ok.sum()), "height_points": int(hok.sum())}
