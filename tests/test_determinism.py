"""The same input gives the same bits at any OpenMP thread count.

The solver divides every particle loop into fixed blocks (reductions summed block by block in
a fixed order) and every scatter to the grid into two-colour strips (each node receives its
contributions in one fixed order), see fortran/src/cpdi_schedule.f90. So a run on 1, 2 or 3
threads must agree bit for bit: positions, velocities, F, stress, volumes, domains and every
diagnostic (energies, works, momentum). A race in a scatter or a thread-dependent summation
order would break the equality within a few steps.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from harness import cases, runner, solver
from tools import bench


def _dam_break(shape: str, projection: str) -> dict:
    return bench.dam_break_case(16, shape, projection)


def _with_block() -> dict:
    """Dam break against a free elastic block, with multi-field contact and friction."""
    d = _dam_break("cpdi", "cell")
    d["materials"].append({"name": "block", "model": "hencky", "density": 1500.0, "youngs_modulus": 5e6,
                           "poisson_ratio": 0.3})
    d["bodies"].append({"material": "block", "ppc": 2,
                        "geometry": {"type": "rectangle", "min": [0.2, 0.0], "max": [0.26, 0.06]}})
    d["contact"] = {"enabled": True, "friction": 0.3}
    return d


def _stretched() -> dict:
    """A soft block (one particle per cell) thrown at the floor: its CPDI domains stretch over
    more than a 2x2-cell block, so their slots 10..16 live in the overflow pool."""
    d = _dam_break("cpdi", "none")
    d["materials"] = [{"name": "block", "model": "hencky", "density": 1000.0, "youngs_modulus": 5e4,
                       "poisson_ratio": 0.3}]
    d["bodies"] = [{"material": "block", "ppc": 1, "velocity": [0.5, -2.0],
                    "geometry": {"type": "rectangle", "min": [0.1, 0.05], "max": [0.3, 0.25]}}]
    return d


def _subcycled(substeps: str = "explicit") -> dict:
    """A Hencky block dropped into incompressible water, its explicit steps subcycled inside the
    water's step (solid_substeps; cpdi_step subcycle_solids): the solid's substeps run the
    explicit stages of the weakly compressible step, with the same threads. substeps "implicit":
    the solid's volumetric stress in the projection too (cpdi_fsi solid_compliance)."""
    return {
        "case": {"name": "subcycled_block", "requirement": "determinism"},
        "grid": {"size": [1.0, 1.0], "cell": 0.05,
                 "walls": {"left": "slip", "right": "slip", "bottom": "slip", "top": "open"}},
        "solver": {"fluid": "incompressible", "shape": "cpdi", "update": "usl", "cfl": 0.5, "t_end": 10.0,
                   "gravity": [0.0, -9.81], "flip": 0.99, "solid_substeps": substeps},
        "materials": [{"name": "water", "model": "newtonian_fluid", "density": 1000.0, "viscosity": 1e-3},
                      {"name": "block", "model": "hencky", "density": 1500.0, "youngs_modulus": 1e6,
                       "poisson_ratio": 0.3}],
        "bodies": [{"material": "water", "geometry": {"type": "rectangle", "min": [0.0, 0.0], "max": [1.0, 0.4]}},
                   {"material": "block", "velocity": [0.3, -1.0],
                    "geometry": {"type": "rectangle", "min": [0.3, 0.5], "max": [0.6, 0.65]}}],
    }


def _incompressible(transfer: str) -> dict:
    """The dam break with the incompressible water alone: the weights on both face lattices
    (cpdi_incompressible weights), P2G to the faces by strips of rows (p2g_faces), the
    multigrid-preconditioned solve and the water's G2P, all threaded."""
    d = _dam_break("cpdi", "none")
    d["solver"].update({"fluid": "incompressible", "transfer": transfer, "pressure_precond": "multigrid",
                        "cfl": 0.4, "flip": 0.99})
    return d


def _anchored() -> dict:
    """A Hencky plate clamped by a prescribed rigid anchor (moving, so that the substeps move it)
    and struck by a collapsing water column, subcycled ("implicit"): the anchor's particles are in
    the substeps' simulation (cpdi_step prepare_solids), its nodes hold the plate there."""
    d = _subcycled("implicit")
    d["grid"]["cell"] = 0.025
    d["materials"] += [{"name": "anchor", "model": "rigid", "density": 2500.0, "velocity": [0.02, 0.0]}]
    d["materials"][1]["density"] = 2500.0
    d["bodies"] = [{"material": "water", "geometry": {"type": "rectangle", "min": [0.0, 0.0], "max": [0.3, 0.5]}},
                   {"material": "block", "geometry": {"type": "rectangle", "min": [0.5, 0.05], "max": [0.55, 0.3]}},
                   {"material": "anchor", "geometry": {"type": "rectangle", "min": [0.5, 0.0], "max": [0.55, 0.05]}}]
    return d


CASES = {
    "cpdi-cell": _dam_break("cpdi", "cell"),
    "cpdi-nodal": _dam_break("cpdi", "nodal"),
    "gimp-cell": _dam_break("gimp", "cell"),
    "mpm-none": _dam_break("mpm", "none"),
    "cpdi-contact": _with_block(),
    "cpdi-pool": _stretched(),
    "incompressible-flip": _incompressible("flip"),
    "incompressible-apic": _incompressible("apic"),
    "fsi-subcycled": _subcycled(),
    "fsi-implicit": _subcycled("implicit"),
    "fsi-anchored": _anchored(),
}


@pytest.fixture
def restore_threads():
    before = solver.threads()
    yield
    solver.threads(before)


def _run(d: dict, threads: int, steps: int, pool: bool = False):
    assert solver.threads(threads) == threads
    sim, _ = runner.build(cases.from_dict(copy.deepcopy(d)))
    try:
        sim.advance(10.0, max_steps=steps)
        if pool:  # the particles using more than 9 slots (CPDI's overflow pool)
            w = sim.shape_functions()[1]
            return int(np.count_nonzero((w[:, 9:] != 0.0).any(axis=1)))
        return sim.state(), sim.diagnostics()
    finally:
        sim.close()


def test_stretched_case_uses_the_overflow_pool(restore_threads):
    """Without pool particles the cpdi-pool comparison would not exercise the pool."""
    assert _run(CASES["cpdi-pool"], 1, 120, pool=True) > 0


@pytest.mark.parametrize("name", list(CASES))
def test_bitwise_identical_at_1_2_and_3_threads(name, restore_threads):
    steps = 120
    ref_state, ref_diag = _run(CASES[name], 1, steps)
    assert ref_diag["steps"] == steps
    assert ref_diag["kinetic_energy"] > 0.0  # the column is moving: the comparison is not of a rest state
    for threads in (2, 3):
        state, diag = _run(CASES[name], threads, steps)
        for key, ref in ref_state.items():
            assert np.array_equal(state[key], ref), f"{name}: {key} differs between 1 and {threads} threads"
        assert diag == ref_diag, f"{name}: diagnostics differ between 1 and {threads} threads"
