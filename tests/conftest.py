"""Shared helpers: small solver set-ups built directly through the API."""

from __future__ import annotations

import os

import numpy as np
import pytest

from harness.solver import FULL_STATE_ROWS, FULL_STATE_SCALARS, Simulation

# A step uses fewer threads than asked for below 16384 particles per thread (cpdi_step
# MIN_PER_THREAD); the tests' cases are small, and the determinism tests must really run on
# 2 and 3 threads.
os.environ.setdefault("CPDI_MIN_PER_THREAD", "1")


def block_particles(lo, hi, h, ppc, density, v=(0.0, 0.0)):
    """ppc x ppc particles per cell filling the rectangle lo-hi (aligned to cells of size h)."""
    d = h / ppc
    xs = np.arange(lo[0] + d / 2, hi[0], d)
    ys = np.arange(lo[1] + d / 2, hi[1], d)
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    x = np.column_stack([X.ravel(), Y.ravel()])
    n = len(x)
    vol = np.full(n, d * d)
    return dict(x=x, v=np.tile(np.asarray(v, float), (n, 1)), mass=density * vol, vol=vol,
                r=np.tile([d / 2, 0.0, 0.0, d / 2], (n, 1)), mat=np.zeros(n, dtype=np.int32))


def make_sim(parts, *, ncell, h, origin=(0.0, 0.0), walls=("open",) * 4, materials=None, **options):
    sim = Simulation()
    sim.set_grid(origin, ncell, h, list(walls))
    sim.set_materials(materials or [{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6,
                                     "poisson_ratio": 0.3}])
    sim.set_particles(**parts)
    sim.set_options(**options)
    return sim


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


def named(full):
    """Full state split into named arrays (rows of FULL_STATE_ROWS, then the scalars)."""
    out, i = {}, 0
    for name, width in FULL_STATE_ROWS:
        out[name] = full["particles"][i:i + width]
        i += width
    assert i == full["particles"].shape[0], "FULL_STATE_ROWS does not cover the solver's rows"
    assert len(FULL_STATE_SCALARS) == full["scalars"].size, "FULL_STATE_SCALARS does not match the solver"
    out.update({k: full["scalars"][j] for j, k in enumerate(FULL_STATE_SCALARS) if not k.startswith("timer.")})
    return out
