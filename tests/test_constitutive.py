"""Each constitutive model against its textbook Cauchy stress for a given deformation.

The solver refreshes the stress of an imposed state (set_state, then stable_dt); these tests
compare it with the closed forms written out here from the models' definitions (plane strain,
F33 = 1; stress rows sxx, syy, sxy, szz):
- Hencky: Kirchhoff stress tau = lam tr(e) I + 2 mu e with e = ln V = (1/2) ln b, sigma = tau / J;
- compressible neo-Hookean: sigma = (mu / J) (b - I) + (lam ln J / J) I;
- weakly compressible Newtonian fluid: sigma = K ln J I + 2 visc dev(D);
- rigid: no stress.
Lame constants from E and nu: lam = E nu / ((1 + nu)(1 - 2 nu)), mu = E / (2 (1 + nu)).
"""

from __future__ import annotations

import numpy as np
import pytest

from harness.solver import FULL_STATE_ROWS, FULL_STATE_SCALARS
from tests.conftest import block_particles, make_sim

E, NU, RHO = 2.0e6, 0.3, 1000.0
LAM = E * NU / ((1 + NU) * (1 - 2 * NU))
MU = E / (2 * (1 + NU))

# deformation gradients [F11, F21, F12, F22]: stretch, shear, rotation with stretch, compression
CASES = {
    "uniaxial stretch": [1.05, 0.0, 0.0, 1.0],
    "simple shear": [1.0, 0.0, 0.08, 1.0],
    "rotated stretch": [1.1 * np.cos(0.4), 1.1 * np.sin(0.4), -0.95 * np.sin(0.4), 0.95 * np.cos(0.4)],
    "compression": [0.9, 0.02, -0.03, 0.93],
}


def logm_spd(b):
    """Matrix logarithm of a symmetric positive definite matrix (numpy's eigh)."""
    w, q = np.linalg.eigh(b)
    return q @ np.diag(np.log(w)) @ q.T


def _mat3(F4):
    """The plane-strain 3x3 deformation gradient of [F11, F21, F12, F22]."""
    return np.array([[F4[0], F4[2], 0.0], [F4[1], F4[3], 0.0], [0.0, 0.0, 1.0]])


def _rows(s):
    return np.array([s[0, 0], s[1, 1], s[0, 1], s[2, 2]])


def hencky(F4):
    F = _mat3(F4)
    J = np.linalg.det(F)
    e = 0.5 * logm_spd(F @ F.T)
    return _rows((LAM * np.trace(e) * np.eye(3) + 2 * MU * e) / J)


def neo_hookean(F4):
    F = _mat3(F4)
    J = np.linalg.det(F)
    return _rows(MU / J * (F @ F.T - np.eye(3)) + LAM * np.log(J) / J * np.eye(3))


def solver_stress(material, F4, kinematics="log"):
    parts = block_particles((0.4, 0.4), (0.5, 0.5), 0.05, 1, RHO)
    sim = make_sim(parts, ncell=(20, 20), h=0.05, gravity=(0.0, 0.0), materials=[material], kinematics=kinematics)
    n = len(parts["x"])
    sim.set_state(np.zeros((n, 2)), np.tile(F4, (n, 1)), 0.0)
    sim.stable_dt()
    sig = sim.state()["sigma"]
    sim.close()
    return sig


@pytest.mark.parametrize("case", CASES)
def test_hencky_stress_is_the_log_strain_law(case):
    sig = solver_stress({"model": "hencky", "density": RHO, "youngs_modulus": E, "poisson_ratio": NU}, CASES[case])
    np.testing.assert_allclose(sig, np.tile(hencky(CASES[case]), (len(sig), 1)), rtol=1e-10, atol=1e-9 * E)


@pytest.mark.parametrize("case", CASES)
def test_neo_hookean_stress_is_the_compressible_law(case):
    sig = solver_stress({"model": "neo_hookean", "density": RHO, "youngs_modulus": E, "poisson_ratio": NU},
                        CASES[case])
    np.testing.assert_allclose(sig, np.tile(neo_hookean(CASES[case]), (len(sig), 1)), rtol=1e-10,
                               atol=1e-9 * E)


def small_strain(F4):
    """Linear elasticity of the small strain eps = sym(F) - I (plane strain: eps_zz = 0, so
    szz = lam tr(eps)); no J factor, no rotation correction."""
    F = _mat3(F4)
    eps = 0.5 * (F + F.T) - np.eye(3)
    return _rows(LAM * np.trace(eps) * np.eye(3) + 2 * MU * eps)


@pytest.mark.parametrize("case", CASES)
def test_small_strain_stress_is_the_linear_law(case):
    """kinematics = "small": sigma = lam tr(eps) I + 2 mu eps with eps = sym(F) - I, each of
    the four rows (sxx, syy, sxy and the plane-strain szz = lam tr(eps))."""
    sig = solver_stress({"model": "hencky", "density": RHO, "youngs_modulus": E, "poisson_ratio": NU}, CASES[case],
                        kinematics="small")
    np.testing.assert_allclose(sig, np.tile(small_strain(CASES[case]), (len(sig), 1)), rtol=1e-10,
                               atol=1e-9 * E)


def test_the_two_solid_laws_agree_to_first_order_and_part_beyond():
    """Both reduce to linear elasticity for small strain (same lam, mu) and differ at second order:
    a check that the comparison is sensitive to the law, not only to the moduli."""
    small = [1.0 + 1e-5, 0.0, 2e-6, 1.0]
    h, nh = hencky(small), neo_hookean(small)
    assert np.allclose(h, nh, rtol=1e-4, atol=0)
    large = CASES["compression"]
    assert np.abs(hencky(large) - neo_hookean(large)).max() > 1e-3 * E


@pytest.mark.parametrize("J", [0.98, 1.0, 1.01])
def test_fluid_pressure_is_minus_k_ln_j_and_isotropic(J):
    K = 2.0e6
    sig = solver_stress({"model": "newtonian_fluid", "density": RHO, "bulk_modulus": K, "viscosity": 0.0},
                        [J, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(sig, np.tile([K * np.log(J), K * np.log(J), 0.0, K * np.log(J)], (len(sig), 1)),
                               rtol=1e-12, atol=1e-6)


VISC_L = np.array([0.3, -0.2, 0.5, 0.1])  # [L11, L21, L12, L22]: shear and a volume rate (tr L = 0.4)


def fluid_with_rate(visc, dt_last=0.0):
    """A fluid block at J = 1 with the velocity gradient VISC_L (and the last step's length
    dt_last) imposed through the full state; its stress refreshed. Returns (sigma, diagnostics,
    particle volumes)."""
    parts = block_particles((0.4, 0.4), (0.5, 0.5), 0.05, 1, RHO)
    sim = make_sim(parts, ncell=(20, 20), h=0.05, gravity=(0.0, 0.0),
                   materials=[{"model": "newtonian_fluid", "density": RHO, "bulk_modulus": 2.0e6, "viscosity": visc}])
    full = sim.get_full_state()
    p, s = full["particles"].copy(), full["scalars"].copy()
    row = sum(w for _, w in FULL_STATE_ROWS[:FULL_STATE_ROWS.index(("L", 4))])
    p[row:row + 4] = VISC_L[:, None]
    s[FULL_STATE_SCALARS.index("dt_last")] = dt_last
    sim.set_full_state(p, s)
    sim.stable_dt()
    out = sim.state()["sigma"], sim.diagnostics(), sim.state()["vol"]
    sim.close()
    return out


def deviatoric_rate(L):
    """dev(D) of the plane-strain rate of deformation (D_zz = 0), 3 x 3."""
    Lm = np.array([[L[0], L[2], 0.0], [L[1], L[3], 0.0], [0.0, 0.0, 0.0]])
    D = 0.5 * (Lm + Lm.T)
    return D - np.trace(D) / 3 * np.eye(3)


def test_fluid_viscous_stress_is_two_mu_deviatoric_rate():
    """With a velocity gradient L imposed through the full state, the fluid adds 2 visc dev(D)."""
    visc = 3.0
    sig, _, _ = fluid_with_rate(visc)
    expect = _rows(2 * visc * deviatoric_rate(VISC_L))
    np.testing.assert_allclose(sig, np.tile(expect, (len(sig), 1)), rtol=1e-10, atol=1e-9)


def test_viscous_dissipation_is_two_mu_dev_d_squared():
    """The viscous_dissipation diagnostic grows by the dissipation rate 2 visc dev(D):dev(D) V
    times the step (here the imposed last step dt_last), dev(D) including the out-of-plane
    -tr(D)/3 of a plane-strain volume rate."""
    visc, dt_last = 3.0, 1.0e-3
    _, diag, vol = fluid_with_rate(visc, dt_last)
    dev = deviatoric_rate(VISC_L)
    expect = 2 * visc * np.sum(dev * dev) * vol.sum() * dt_last
    assert diag["viscous_dissipation"] == pytest.approx(expect, rel=1e-12)


def test_rigid_material_carries_no_stress():
    sig = solver_stress({"model": "rigid", "density": RHO, "velocity": [0.0, 0.0]}, CASES["simple shear"])
    assert np.all(sig == 0.0)


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.45])
def test_stable_step_is_the_p_wave_crossing_time(nu):
    """An elastic block at rest: the stable explicit step is h / c_p with the P-wave speed
    c_p = sqrt((lam + 2 mu) / rho) = sqrt((K + 4 G / 3) / rho) of the law's moduli."""
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    parts = block_particles((0.4, 0.4), (0.5, 0.5), 0.05, 2, RHO)
    sim = make_sim(parts, ncell=(20, 20), h=0.05, gravity=(0.0, 0.0),
                   materials=[{"model": "hencky", "density": RHO, "youngs_modulus": E, "poisson_ratio": nu}])
    dt = sim.stable_dt()
    sim.close()
    assert dt == pytest.approx(0.05 / np.sqrt((lam + 2 * mu) / RHO), rel=1e-12)


@pytest.mark.parametrize("model", ["hencky", "neo_hookean", "hencky small strain", "newtonian_fluid"])
def test_strain_energy_is_the_laws_stored_energy(model):
    """The strain_energy diagnostic of a uniformly deformed block is psi(F) V0 with the law's
    stored energy: Hencky psi = mu e:e + lam/2 tr(e)^2 (e = ln V; with small-strain
    kinematics e = sym(F) - I), neo-Hookean psi = mu/2 (tr C - 3) - mu ln J + lam/2 (ln J)^2,
    the weakly compressible fluid psi = K/2 (ln J)^2."""
    F4 = [1.05, 0.02, 0.03, 0.97]
    K = 2.0e6
    parts = block_particles((0.4, 0.4), (0.5, 0.5), 0.05, 2, RHO)
    material = {"model": model.split()[0], "density": RHO, "youngs_modulus": E, "poisson_ratio": NU,
                "bulk_modulus": K, "viscosity": 0.0}
    sim = make_sim(parts, ncell=(20, 20), h=0.05, gravity=(0.0, 0.0), materials=[material],
                   kinematics="small" if "small" in model else "log")
    n = len(parts["x"])
    sim.set_state(np.zeros((n, 2)), np.tile(F4, (n, 1)), 0.0)
    sim.stable_dt()
    energy = sim.diagnostics()["strain_energy"]
    sim.close()
    F = _mat3(F4)
    J = np.linalg.det(F)
    if model == "hencky":
        e = 0.5 * logm_spd(F @ F.T)
        psi = MU * np.trace(e @ e) + LAM / 2 * np.trace(e) ** 2
    elif model == "hencky small strain":
        e = 0.5 * (F + F.T) - np.eye(3)
        psi = MU * np.trace(e @ e) + LAM / 2 * np.trace(e) ** 2
    elif model == "neo_hookean":
        psi = MU / 2 * (np.trace(F.T @ F) - 3) - MU * np.log(J) + LAM / 2 * np.log(J) ** 2
    else:  # the fluid keeps only its volume ratio (F = sqrt(J) I): psi depends on J alone
        psi = K / 2 * np.log(J) ** 2
    assert energy == pytest.approx(psi * parts["vol"].sum(), rel=1e-12)
