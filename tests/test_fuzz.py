"""Property-based fuzzing: no input may crash the interpreter or escape as anything but
CaseError (case loader) or CpdiError (solver API)."""

import copy
import math
import tomllib
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from harness import cases
from harness.cases import CaseError
from harness.solver import CpdiError, Simulation

BASE = tomllib.loads((Path(__file__).resolve().parent.parent / "cases" / "water_column.toml").read_text())
SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True),
                    st.text(max_size=12), st.lists(st.floats(allow_nan=True), max_size=4))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                      st.dictionaries(st.text(max_size=8), inner, max_size=3)),
                      max_leaves=8)
PATHS = [("solver", "cfl"), ("solver", "t_end"), ("solver", "shape"), ("solver", "gravity"), ("grid", "cell"),
         ("grid", "size"), ("grid", "walls"), ("grid", "origin"), ("materials", 0, "density"),
         ("materials", 0, "bulk_modulus"), ("materials", 0, "model"), ("bodies", 0, "geometry"),
         ("bodies", 0, "ppc"), ("bodies", 0, "material"), ("probes", "front_x"), ("case", "name"), ("contact",),
         ("solver", "projection"), ("solver", "flip"), ("bodies",), ("materials",)]


@SETTINGS
@given(path=st.sampled_from(PATHS), value=values)
def test_case_loader_never_crashes(path, value):
    raw = copy.deepcopy(BASE)
    node = raw
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    try:
        cases.validate(raw)
    except CaseError:
        pass


@SETTINGS
@given(text=st.text(max_size=200))
def test_override_parser_never_crashes(text):
    raw = copy.deepcopy(BASE)
    try:
        cases.apply_override(raw, text)
        cases.validate(raw)
    except CaseError:
        pass


floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
arrays = st.one_of(
    st.lists(floats, max_size=12).map(np.array),
    st.lists(st.lists(floats, min_size=2, max_size=2), max_size=6).map(np.array),
    st.lists(st.lists(floats, min_size=4, max_size=4), max_size=6).map(np.array),
    st.lists(st.integers(-5, 5), max_size=8).map(np.array),
)


@SETTINGS
@given(x=arrays, v=arrays, m=arrays, vol=arrays, r=arrays, mat=arrays, h=floats, t=floats)
def test_api_never_crashes(x, v, m, vol, r, mat, h, t):
    sim = Simulation()
    try:
        for call in (lambda: sim.set_grid((0.0, 0.0), (10, 10), h if math.isfinite(h) else h),
                     lambda: sim.set_grid((0.0, 0.0), (10, 10), 0.1),
                     lambda: sim.set_materials([{"model": "hencky", "density": 1000.0, "youngs_modulus": 1e6,
                                                 "poisson_ratio": 0.3}]),
                     lambda: sim.set_particles(x, v, m, vol, r, mat),
                     lambda: sim.set_options(cfl=0.3, gravity=(0.0, -9.81)),
                     lambda: sim.advance(t, max_steps=20),
                     lambda: sim.state(),
                     lambda: sim.project(m, "cell")):
            try:
                call()
            except CpdiError:
                pass
    finally:
        sim.close()
