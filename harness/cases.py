"""Case files: load a TOML case, validate every key, fill defaults.

A case is data. Each key has a type, a range, a unit and a one-line doc; the same table
drives validation, the defaults and ``cases/README.md`` (see :func:`schema_markdown`).
An unknown key, a wrong type or a non-physical value raises :class:`CaseError` naming
the key, the value and a fix.
"""

from __future__ import annotations

import copy
import difflib
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


class CaseError(ValueError):
    """A case file is malformed; the message names the key and the fix."""


# --------------------------------------------------------------------------- schema
@dataclass(frozen=True)
class Key:
    kind: str  # "str", "float", "int", "bool", "vec2", "choice", "table", "any"
    doc: str
    unit: str = ""
    default: Any = None
    required: bool = False
    choices: tuple = ()
    check: Callable[[Any], str | None] | None = None  # returns an error text or None
    sub: dict[str, Key] | None = None  # for "table"


def positive(v):
    return None if v > 0 else "must be positive"


def nonneg(v):
    return None if v >= 0 else "must be zero or positive"


def in_range(lo, hi, lo_open=False, hi_open=False):
    def chk(v):
        ok_lo = v > lo if lo_open else v >= lo
        ok_hi = v < hi if hi_open else v <= hi
        if ok_lo and ok_hi:
            return None
        return f"must lie in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
    return chk


def positive_vec(v):
    return None if all(x > 0 for x in v) else "both components must be positive"


WALL = ("slip", "noslip", "open")

GEOMETRY = {
    "type": Key("choice", "shape of the body", choices=("rectangle", "annulus", "disc", "polygon"), required=True),
    "min": Key("vec2", "lower-left corner (rectangle, before its rotation)", "m"),
    "max": Key("vec2", "upper-right corner (rectangle, before its rotation)", "m"),
    "angle": Key("float", "rotation about the rectangle's centre, counter-clockwise; default 0 (rectangle)",
                 "deg"),
    "center": Key("vec2", "centre (annulus, disc)", "m"),
    "r_inner": Key("float", "inner radius (annulus)", "m", check=nonneg),
    "r_outer": Key("float", "outer radius (annulus)", "m", check=positive),
    "radius": Key("float", "radius (disc)", "m", check=positive),
    "vertices": Key("points", "corners [[x, y], ...], counter-clockwise, not self-intersecting (polygon)", "m"),
}
GEOMETRY_KEYS = {"rectangle": ("min", "max", "angle"), "annulus": ("center", "r_inner", "r_outer"),
                 "disc": ("center", "radius"), "polygon": ("vertices",)}

PROBE = {
    "kind": Key("choice", "what to measure (defaults to the probe's name)",
                choices=("front_x", "column_height", "displacement_x", "displacement_y", "com_x", "com_y", "com_vx",
                         "com_vy", "bottom", "top", "left", "right", "surface_pressure")),
    "material": Key("str", "material whose particles are probed (default: all)"),
    "point": Key("vec2", "initial position of the probed point (displacement probes)", "m"),
    "body": Key("str", "name of the solid body whose wetted surface is probed (surface_pressure)"),
    "points": Key("pointlist", "initial positions [[x, y], ...] on the body's surface, within half a cell of "
                  "it; they move with the body (surface_pressure: one column NAME_i per point, Pa)", "m"),
    "layer": Key("float", "thickness of the floor / wall layer (default: one cell)", "m", check=positive),
    "min_count": Key("int", "front: particles needed within 2 spacings behind the front", default=3,
                     check=lambda v: None if v >= 1 else "must be at least 1"),
}

SCHEMA: dict[str, Key] = {
    "case": Key("table", "identity of the case", required=True, sub={
        "name": Key("str", "short name, used for the run directory", required=True),
        "requirement": Key("str", "one-line requirement the case verifies", required=True),
        "description": Key("str", "free text", default=""),
    }),
    "grid": Key("table", "background grid", required=True, sub={
        "origin": Key("vec2", "lower-left corner of the domain", "m", default=[0.0, 0.0]),
        "size": Key("vec2", "domain width and height (whole cells)", "m", required=True, check=positive_vec),
        "cell": Key("float", "square cell size h", "m", required=True, check=positive),
        "walls": Key("table", "wall kind per side: slip, noslip or open", sub={
            side: Key("choice", f"{side} wall", choices=WALL, default="slip")
            for side in ("left", "right", "bottom", "top")}),
    }),
    "solver": Key("table", "time integration and discretisation", required=True, sub={
        "shape": Key("choice", "interpolation", choices=("mpm", "gimp", "cpdi"), default="cpdi"),
        "update": Key("choice", "update scheme", choices=("usl", "musl"), default="musl"),
        "projection": Key("choice", "volumetric anti-locking projection of ln J increments and mean stress: "
                          "none, cell (cell-wise constant) or nodal (bilinear, banded LAPACK solve)",
                          choices=("none", "cell", "nodal"), default="none"),
        "projection_stabilization": Key("float", "beta: the projected volumetric fields keep beta of each particle's "
                                                 "own value, giving sub-cell (hourglass) motions a stiffness beta K",
                                        default=0.0, check=in_range(0.0, 1.0)),
        "kinematics": Key("choice", "log: finite strain (Hencky); small: sym(F) - I",
                          choices=("log", "small"), default="log"),
        "domain_scaling": Key("bool", "Homel et al. (2016) CPDI domain scaling", default=False),
        "cfl": Key("float", "Courant number of the explicit step", default=0.3,
                   check=in_range(0.0, 1.0, lo_open=True)),
        "dt": Key("float", "fixed time step (overrides cfl; refused if above the stable limit)", "s",
                  check=positive),
        "t_end": Key("float", "simulated end time", "s", required=True, check=positive),
        "gravity": Key("vec2", "gravitational acceleration", "m/s^2", default=[0.0, -9.81]),
        "body_acceleration": Key("vec2", "uniform, constant body force per unit mass on every particle, added to "
                                         "gravity through the solver's per-particle body force (a tank accelerating "
                                         "at a: -a, the frame's inertial force)", "m/s^2", default=[0.0, 0.0]),
        "output_every": Key("float", "interval between snapshots", "s", check=positive),
        "series_every": Key("float", "interval between series.csv rows (default output_every/10)", "s",
                            check=positive),
        "damping": Key("float", "Cundall local damping coefficient (0 = none)", default=0.0,
                       check=in_range(0.0, 1.0, hi_open=True)),
        "flip": Key("float", "FLIP fraction of the particle velocity update (1 = FLIP, 0 = PIC)", default=1.0,
                    check=in_range(0.0, 1.0)),
        "max_steps": Key("int", "abort after this many steps", default=50_000_000, check=positive),
        "max_estimated_steps": Key("float", "refuse a run whose first time step forecasts more steps than this to "
                                            "t_end (a hopeless run); raise it to run anyway", default=1.0e8,
                                   check=positive),
        "fluid": Key("choice", "water model: weakly_compressible (the paper's explicit model, p from K ln J; "
                               "time step from the speed of sound) or incompressible (pressure projection on a "
                               "staggered grid; time step from the flow; water-only cases for now)",
                     choices=("weakly_compressible", "incompressible"), default="weakly_compressible"),
        "transfer": Key("choice", "particle-grid velocity transfer: flip (FLIP/PIC blend set by flip) or apic "
                                  "(affine PIC; incompressible only)", choices=("flip", "apic"), default="flip"),
        "cg_tolerance": Key("float", "incompressible: relative residual of the pressure solve", default=1e-8,
                            check=in_range(0.0, 1.0, lo_open=True, hi_open=True)),
        "correction_tolerance": Key("float", "incompressible, water alone: relative residual of the volume "
                                             "correction's solve (coupled runs: cg_tolerance)", default=1e-4,
                                    check=in_range(0.0, 1.0, lo_open=True, hi_open=True)),
        "cg_max_iterations": Key("int", "incompressible: CG iteration limit (0: 4 sqrt(cells) + 200)", default=0,
                                 check=nonneg),
        "volume_correction": Key("float", "incompressible: an over-filled cell gets div v = beta (fill - 1) / dt",
                                 default=0.5, check=in_range(0.0, 2.0)),
        "pressure_precond": Key("choice", "incompressible: preconditioner of the pressure CG, mic0 (incomplete "
                                          "Cholesky; iterations grow like sqrt(cells)) or multigrid (a geometric "
                                          "multigrid V-cycle; iterations about constant)",
                                choices=("mic0", "multigrid"), default="mic0"),
        "solid_substeps": Key("choice", "incompressible water with deformable solids: auto (the coupling chooses "
                                        "by what the solids are: implicit, or explicit for a solid held by a "
                                        "prescribed rigid body), off (the coupled step is the solid's acoustic "
                                        "step), explicit (the solids' explicit steps subcycled inside the water's "
                                        "step) or implicit (explicit with the solids' volumetric stress implicit "
                                        "in the projection); docs/fsi_incompressible.md",
                              choices=("auto", "off", "explicit", "implicit"), default="auto"),
    }),
    "materials": Key("list", "materials, referenced by name from bodies", required=True),
    "bodies": Key("list", "bodies filled with particles", required=True),
    "contact": Key("table", "Bardenhagen multi-velocity-field frictional contact between contact groups", sub={
        "enabled": Key("bool", "each contact group gets its own velocity field, with contact between them "
                               "(false: one field for all, a single continuum)", default=False),
        "friction": Key("float", "Coulomb friction coefficient", default=0.0, check=nonneg),
        "fullness": Key("float", "a node is in contact when the bodies fill this fraction of its support "
                                 "(Bardenhagen volume constraint; 0 = any shared node)", default=0.9,
                        check=in_range(0.0, 1.0)),
    }),
    "probes": Key("table", "case-specific outputs written to series.csv (name = {kind, ...})"),
}

MATERIAL = {
    "name": Key("str", "name used by bodies", required=True),
    "model": Key("choice", "constitutive model", required=True,
                 choices=("hencky", "neo_hookean", "newtonian_fluid", "rigid", "rigid_body")),
    "density": Key("float", "reference density", "kg/m^3", required=True, check=positive),
    "youngs_modulus": Key("float", "Young's modulus (hencky, neo_hookean)", "Pa", check=positive),
    "poisson_ratio": Key("float", "Poisson's ratio (hencky, neo_hookean)",
                         check=in_range(-1.0, 0.5, lo_open=True, hi_open=True)),
    "bulk_modulus": Key("float", "bulk modulus K (newtonian_fluid)", "Pa", check=positive),
    "viscosity": Key("float", "dynamic viscosity (newtonian_fluid)", "Pa s", default=0.0, check=nonneg),
    "velocity": Key("vec2", "prescribed velocity (rigid)", "m/s", default=[0.0, 0.0]),
    "velocity_table": Key("rows3", "prescribed velocity in time, rows [t, vx, vy] with t increasing: piecewise "
                                   "linear, held before the first and after the last row (rigid; replaces velocity)",
                          "s, m/s"),
    "friction": Key("float", "Coulomb friction coefficient against the walls (rigid_body)", default=0.0,
                    check=nonneg),
    "projection": Key("bool", "takes part in the volumetric projection (default: fluids yes, solids no)"),
}
MODEL_NEEDS = {
    "hencky": ("youngs_modulus", "poisson_ratio"),
    "neo_hookean": ("youngs_modulus", "poisson_ratio"),
    "newtonian_fluid": ("bulk_modulus",),
    "rigid": (),
    "rigid_body": (),
}

BODY = {
    "name": Key("str", "label", default=""),
    "material": Key("str", "name of a [[materials]] entry", required=True),
    "geometry": Key("table", "region filled with particles", required=True, sub=GEOMETRY),
    "ppc": Key("int", "particles per cell per direction", default=2,
               check=lambda v: None if 1 <= v <= 8 else "must be between 1 and 8"),
    "velocity": Key("vec2", "initial velocity", "m/s", default=[0.0, 0.0]),
    "omega": Key("float", "initial angular velocity about the body's centroid, counter-clockwise: "
                          "v = velocity + omega x (x - centroid) (not for rigid)", "1/s", default=0.0),
    "fill": Key("choice", "solid: the whole region; around: the region less every earlier body (water "
                          "around a disc or a wedge)", choices=("solid", "around"), default="solid"),
    "subtract": Key("strlist", "names of earlier bodies whose particles this body leaves out (as fill = "
                               "\"around\" does for all of them)"),
    "contact_group": Key("int", "bodies with the same group share a velocity field under contact "
                                "(default: each body its own)", check=lambda v: None if v >= 0 else "must be >= 0"),
}


# --------------------------------------------------------------------------- validation
def _type_name(v) -> str:
    return type(v).__name__


def _suggest(key: str, allowed) -> str:
    close = difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)
    if close:
        return f"; did you mean '{close[0]}'?"
    return f"; allowed keys: {', '.join(sorted(allowed))}"


def _number_rows(path: str, value, width: int, least: int, what: str) -> list[list[float]]:
    """A list of at least `least` rows of `width` finite numbers, as floats."""
    if (not isinstance(value, list) or len(value) < least
            or any(not isinstance(r, list) or len(r) != width
                   or any(isinstance(x, bool) or not isinstance(x, int | float) for x in r) for r in value)):
        raise CaseError(f"{path} = {value!r} must be a list of {what}")
    value = [[float(x) for x in r] for r in value]
    if not all(math.isfinite(x) for r in value for x in r):
        raise CaseError(f"{path} = {value!r} must be finite")
    return value


def _coerce(path: str, spec: Key, value):
    kind = spec.kind
    if kind == "str":
        if not isinstance(value, str):
            raise CaseError(f"{path} = {value!r} must be a string")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise CaseError(f"{path} = {value!r} must be true or false")
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise CaseError(f"{path} = {value!r} must be a whole number")
        return value
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CaseError(f"{path} = {value!r} must be a number, got {_type_name(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise CaseError(f"{path} = {value!r} must be finite")
        return value
    if kind == "vec2":
        if (not isinstance(value, list) or len(value) != 2
                or any(isinstance(x, bool) or not isinstance(x, int | float) for x in value)):
            raise CaseError(f"{path} = {value!r} must be a list of two numbers, e.g. [0.0, 1.0]")
        value = [float(x) for x in value]
        if not all(math.isfinite(x) for x in value):
            raise CaseError(f"{path} = {value!r} must be finite")
        return value
    if kind == "points":
        return _number_rows(path, value, 2, 3, "at least three [x, y] points, e.g. [[0.0, 0.0], [1.0, 0.0], "
                                               "[0.0, 1.0]]")
    if kind == "pointlist":
        return _number_rows(path, value, 2, 1, "one or more [x, y] points, e.g. [[0.5, 0.4], [0.6, 0.45]]")
    if kind == "rows3":
        value = _number_rows(path, value, 3, 1, "[t, vx, vy] rows, e.g. [[0.0, 0.0, -1.0], [0.1, 0.0, -2.0]]")
        bad = [i for i in range(1, len(value)) if not value[i][0] > value[i - 1][0]]
        if bad:
            raise CaseError(f"{path}: the times must increase strictly, row {bad[0]} (t = {value[bad[0]][0]:g}) "
                            f"does not follow row {bad[0] - 1} (t = {value[bad[0] - 1][0]:g}); sort the rows by time")
        return value
    if kind == "strlist":
        if not isinstance(value, list) or not value or not all(isinstance(x, str) for x in value):
            raise CaseError(f"{path} = {value!r} must be a non-empty list of body names, e.g. [\"disc\"]")
        return value
    if kind == "choice":
        if not isinstance(value, str) or value not in spec.choices:
            hint = difflib.get_close_matches(str(value), spec.choices, n=1, cutoff=0.5)
            extra = f"; did you mean '{hint[0]}'?" if hint else ""
            raise CaseError(f"{path} = {value!r} is not one of {', '.join(spec.choices)}{extra}")
        return value
    return value


# Keys a case could once set, with why they went and what to do instead.
RETIRED = {
    "solver.coupling": "the coupling is chosen by what the solids are (a deformable or prescribed solid "
                       "and the water are one continuum on the MAC faces, a free rigid body enters through its "
                       "boundary flux; docs/fsi_incompressible.md); delete the key",
}


def _validate_table(path: str, schema: dict[str, Key], data) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise CaseError(f"[{path}] must be a table, got {_type_name(data)}")
    for key in data:
        if key not in schema:
            where = f"{path}.{key}" if path else key
            if where in RETIRED:
                raise CaseError(f"'{where}' was removed: {RETIRED[where]}")
            raise CaseError(f"unknown key '{where}'{_suggest(key, schema)}")
    out: dict[str, Any] = {}
    for key, spec in schema.items():
        where = f"{path}.{key}" if path else key
        if key not in data:
            if spec.required:
                raise CaseError(f"missing required key '{where}' ({spec.doc}{', ' + spec.unit if spec.unit else ''})")
            if spec.kind == "table" and spec.sub is not None:
                out[key] = _validate_table(where, spec.sub, {})
            elif spec.default is not None:
                out[key] = copy.deepcopy(spec.default)
            continue
        value = data[key]
        if spec.kind == "table" and spec.sub is not None:
            out[key] = _validate_table(where, spec.sub, value)
        elif spec.kind in ("table", "list"):
            out[key] = value
        else:
            out[key] = _coerce(where, spec, value)
            if spec.check is not None:
                problem = spec.check(out[key])
                if problem:
                    raise CaseError(f"{where} = {value!r} {problem}"
                                    + (f" ({spec.unit})" if spec.unit else ""))
    return out


def _validate_list(path: str, schema: dict[str, Key], data) -> list[dict[str, Any]]:
    if not isinstance(data, list) or not data or not all(isinstance(x, dict) for x in data):
        raise CaseError(f"[[{path}]] must be a non-empty array of tables")
    return [_validate_table(f"{path}[{i}]", schema, item) for i, item in enumerate(data)]


def _polygon_problem(pts: list[list[float]]) -> str | None:
    """Why a polygon is not a simple counter-clockwise one (None if it is)."""
    n = len(pts)
    for i in range(n):
        if pts[i] == pts[(i + 1) % n]:
            return f"vertices {i} and {(i + 1) % n} coincide; remove one"
    area2 = sum(pts[i][0] * pts[(i + 1) % n][1] - pts[(i + 1) % n][0] * pts[i][1] for i in range(n))
    scale = max(max(abs(x) for p in pts for x in p), 1e-300)

    def orient(a, b, c):
        v = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        return 0 if abs(v) <= 1e-14 * scale * scale else (1 if v > 0 else -1)

    def on(a, b, c):  # c on the segment a-b (collinear)
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    for i in range(n):
        a, b = pts[i], pts[(i + 1) % n]
        for j in range(i + 1, n):
            if j == i or (j + 1) % n == i or j == (i + 1) % n:
                continue  # adjacent edges share a vertex
            c, d = pts[j], pts[(j + 1) % n]
            o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
            if ((o1 * o2 < 0 and o3 * o4 < 0) or (o1 == 0 and on(a, b, c)) or (o2 == 0 and on(a, b, d))
                    or (o3 == 0 and on(c, d, a)) or (o4 == 0 and on(c, d, b))):
                return (f"edges {i}-{(i + 1) % n} and {j}-{(j + 1) % n} cross or touch: the polygon intersects "
                        "itself; list its corners in order around its boundary")
    if abs(area2) <= 1e-12 * scale * scale:
        return "the polygon has no area (its vertices lie on a line); give its corners"
    if area2 < 0:
        return "the vertices run clockwise; list them counter-clockwise (reverse the list)"
    return None


def geometry_bounds(geo: dict) -> tuple[list[float], list[float]]:
    """Lower-left and upper-right corners of a validated geometry's bounding box."""
    kind = geo["type"]
    if kind == "rectangle":
        lo, hi = geo["min"], geo["max"]
        a = math.radians(geo.get("angle", 0.0))
        if a == 0.0:
            return list(lo), list(hi)
        c = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2]
        hw, hh = (hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2
        ex = abs(math.cos(a)) * hw + abs(math.sin(a)) * hh
        ey = abs(math.sin(a)) * hw + abs(math.cos(a)) * hh
        return [c[0] - ex, c[1] - ey], [c[0] + ex, c[1] + ey]
    if kind == "polygon":
        xs, ys = [p[0] for p in geo["vertices"]], [p[1] for p in geo["vertices"]]
        return [min(xs), min(ys)], [max(xs), max(ys)]
    c, r = geo["center"], geo["r_outer"] if kind == "annulus" else geo["radius"]
    return [c[0] - r, c[1] - r], [c[0] + r, c[1] + r]


def _validate_geometry(where: str, geo: dict, grid: dict) -> None:
    lo = grid["origin"]
    hi = [lo[0] + grid["size"][0], lo[1] + grid["size"][1]]
    kind = geo["type"]
    for k in geo:
        if k != "type" and k not in GEOMETRY_KEYS[kind]:
            raise CaseError(f"{where}.{k} does not apply to a {kind}; a {kind} takes "
                            f"{', '.join(GEOMETRY_KEYS[kind])}")
    if kind == "rectangle":
        for k in ("min", "max"):
            if k not in geo:
                raise CaseError(f"missing required key '{where}.{k}' for a rectangle (m)")
        if not (geo["min"][0] < geo["max"][0] and geo["min"][1] < geo["max"][1]):
            raise CaseError(f"{where}: min {geo['min']} must lie below and left of max {geo['max']}")
    elif kind == "annulus":
        for k in ("center", "r_outer"):
            if k not in geo:
                raise CaseError(f"missing required key '{where}.{k}' for an annulus")
        geo.setdefault("r_inner", 0.0)
        if not geo["r_inner"] < geo["r_outer"]:
            raise CaseError(f"{where}: r_inner {geo['r_inner']} must be smaller than r_outer {geo['r_outer']}")
    elif kind == "disc":
        for k in ("center", "radius"):
            if k not in geo:
                raise CaseError(f"missing required key '{where}.{k}' for a disc")
    else:
        if "vertices" not in geo:
            raise CaseError(f"missing required key '{where}.vertices' for a polygon ([[x, y], ...], m)")
        problem = _polygon_problem(geo["vertices"])
        if problem:
            raise CaseError(f"{where}.vertices: {problem}")
    bmin, bmax = geometry_bounds(geo)
    tol = 1e-9 * max(grid["size"])
    if bmin[0] < lo[0] - tol or bmin[1] < lo[1] - tol or bmax[0] > hi[0] + tol or bmax[1] > hi[1] + tol:
        raise CaseError(f"{where} spans {bmin}-{bmax}, outside the grid {lo}-{hi}; enlarge [grid] size or move it")


def validate(raw: dict[str, Any]) -> dict[str, Any]:
    """Validate a parsed case and return it with every default filled in."""
    data = _validate_table("", SCHEMA, raw)
    grid = data["grid"]
    h = grid["cell"]
    for i in range(2):
        n = grid["size"][i] / h
        if abs(n - round(n)) > 1e-6 * max(1.0, n):
            raise CaseError(f"grid.size[{i}] = {grid['size'][i]} is not a whole number of cells of {h} m; "
                            f"use {round(n) * h:.6g} or change grid.cell")
    solver = data["solver"]
    solver.setdefault("output_every", solver["t_end"] / 10.0)
    solver.setdefault("series_every", solver["output_every"] / 10.0)
    if solver["output_every"] > solver["t_end"]:
        raise CaseError(f"solver.output_every = {solver['output_every']} exceeds t_end = {solver['t_end']} s")

    mats = _validate_list("materials", MATERIAL, data["materials"])
    names = [m["name"] for m in mats]
    if len(set(names)) != len(names):
        raise CaseError(f"material names must be unique, got {names}")
    for i, m in enumerate(mats):
        m.setdefault("projection", m["model"] == "newtonian_fluid")
        if "velocity_table" in m:
            if m["model"] != "rigid":
                raise CaseError(f"materials[{i}].velocity_table: only a rigid (prescribed) body follows a velocity "
                                f"table, not model {m['model']}; use model = \"rigid\" or remove it")
            if "velocity" in data["materials"][i]:
                raise CaseError(f"materials[{i}]: give velocity (constant) or velocity_table, not both")
        for need in MODEL_NEEDS[m["model"]]:
            if need == "bulk_modulus" and data["solver"]["fluid"] == "incompressible":
                continue  # incompressible water has no bulk modulus
            if need not in m:
                raise CaseError(f"materials[{i}] ('{m['name']}', model {m['model']}) needs '{need}' "
                                f"({MATERIAL[need].doc}, {MATERIAL[need].unit or '-'})")
    data["materials"] = mats

    bodies = _validate_list("bodies", BODY, data["bodies"])
    for i, b in enumerate(bodies):
        if b["material"] not in names:
            raise CaseError(f"bodies[{i}].material = '{b['material']}' is not a defined material"
                            f"{_suggest(b['material'], names)}")
        _validate_geometry(f"bodies[{i}].geometry", b["geometry"], grid)
        model = next(m["model"] for m in mats if m["name"] == b["material"])
        if b["omega"] != 0.0 and model == "rigid":
            raise CaseError(f"bodies[{i}].omega: a rigid body moves with its material's prescribed velocity; "
                            "use model = \"rigid_body\" for a free body that spins, or remove omega")
        if b["fill"] == "around" and i == 0:
            raise CaseError(f"bodies[{i}].fill = 'around' needs earlier bodies to fill around; list this body "
                            "after them")
        if "subtract" in b:
            if b["fill"] == "around":
                raise CaseError(f"bodies[{i}]: give fill = 'around' (every earlier body) or subtract (some of "
                                "them), not both")
            earlier = [x["name"] for x in bodies[:i]]
            for name in b["subtract"]:
                if earlier.count(name) != 1 or not name:
                    raise CaseError(f"bodies[{i}].subtract: '{name}' is not the name of exactly one earlier body"
                                    f"{_suggest(name, [e for e in earlier if e]) if any(earlier) else ''}; name "
                                    "the bodies to subtract and list them before this one")
        if solver["shape"] == "gimp" and b["ppc"] < 1:
            raise CaseError(f"bodies[{i}].ppc must be at least 1 for gimp")
    data["bodies"] = bodies

    probes = {}
    for name, spec in (data.get("probes") or {}).items():
        p = _validate_table(f"probes.{name}", PROBE, spec if isinstance(spec, dict) else {"kind": spec})
        p.setdefault("kind", name)
        if p["kind"] not in PROBE["kind"].choices:
            raise CaseError(f"probes.{name}: kind '{p['kind']}' is unknown; use one of "
                            f"{', '.join(PROBE['kind'].choices)}")
        if p["kind"].startswith("displacement") and "point" not in p:
            raise CaseError(f"probes.{name} needs 'point' (initial position of the probed point, m)")
        if "material" in p and p["material"] not in names:
            raise CaseError(f"probes.{name}.material = '{p['material']}' is not a defined material")
        if p["kind"] == "surface_pressure":
            _validate_surface_probe(f"probes.{name}", p, bodies, mats, data["solver"], grid)
        else:
            for k in ("body", "points"):
                if k in p:
                    raise CaseError(f"probes.{name}.{k} applies to kind = \"surface_pressure\" only; remove it")
        probes[name] = p
    data["probes"] = probes
    return data


SURFACE_PROBE_SHAPES = ("rectangle", "disc", "polygon")


def _validate_surface_probe(where: str, p: dict, bodies: list, mats: list, solver: dict, grid: dict) -> None:
    """A surface_pressure probe: a named solid body of the incompressible water, a shape whose outward
    normal the probe can take (rectangle, disc, polygon), points within half a cell of its boundary."""
    if solver["fluid"] != "incompressible":
        raise CaseError(f"{where}: surface_pressure samples the incompressible water's cell pressure; set "
                        "solver.fluid = \"incompressible\" or remove the probe")
    for k, what in (("body", "the name of a solid body"), ("points", "[[x, y], ...] on its surface, m")):
        if k not in p:
            raise CaseError(f"{where} needs '{k}' ({what})")
    named = [b for b in bodies if b["name"] == p["body"]]
    if len(named) != 1:
        known = [b["name"] for b in bodies if b["name"]]
        raise CaseError(f"{where}.body = '{p['body']}' is not the name of exactly one body"
                        f"{_suggest(p['body'], known) if known else ''}; name the body in [[bodies]]")
    body = named[0]
    model = next(m["model"] for m in mats if m["name"] == body["material"])
    if model == "newtonian_fluid":
        raise CaseError(f"{where}.body = '{p['body']}' is water; name a solid body (rigid, rigid_body, hencky, "
                        "neo_hookean)")
    geo = body["geometry"]
    if geo["type"] not in SURFACE_PROBE_SHAPES:
        raise CaseError(f"{where}: the body's geometry is a {geo['type']}; surface_pressure takes a "
                        f"{', '.join(SURFACE_PROBE_SHAPES)}")
    from harness.probes import boundary_normal  # the probe's own geometry (no import cycle at load time)

    for i, pt in enumerate(p["points"]):
        d, _ = boundary_normal(geo, pt)
        if d > 0.5 * grid["cell"]:
            raise CaseError(f"{where}.points[{i}] = {pt} lies {d:.3g} m from the body's surface, more than half a "
                            f"cell ({0.5 * grid['cell']:g} m); give points on its boundary")


# --------------------------------------------------------------------------- loading
@dataclass
class Case:
    """A validated case: ``data`` holds every section with defaults filled in."""

    data: dict[str, Any]
    path: Path | None = None
    overrides: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.data["case"]["name"]

    def __getitem__(self, key: str) -> Any:
        return self.data[key]


def parse_value(text: str) -> Any:
    """Parse the value of a ``--set key=value`` override as TOML, falling back to a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_override(raw: dict[str, Any], assignment: str) -> None:
    """Apply ``section.key=value`` (``materials.0.density=1100`` indexes arrays) to a raw case."""
    if "=" not in assignment:
        raise CaseError(f"--set {assignment!r} must look like section.key=value")
    path, text = assignment.split("=", 1)
    parts = [p for p in path.strip().split(".") if p]
    if len(parts) < 2:
        raise CaseError(f"--set {assignment!r}: name a section and a key, e.g. solver.cfl=0.2")
    node: Any = raw
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise CaseError(f"--set {assignment!r}: '{part}' is not an index of {'.'.join(parts[:i])}")
            node = node[int(part)]
        else:
            if part not in node:
                top = SCHEMA if i == 0 else {}
                if i == 0 and part not in SCHEMA:
                    raise CaseError(f"--set {assignment!r}: unknown section '{part}'{_suggest(part, top)}")
                node[part] = {}
            node = node[part]
    last = parts[-1]
    if isinstance(node, list):
        raise CaseError(f"--set {assignment!r}: index the array, e.g. materials.0.density=1100")
    node[last] = parse_value(text.strip())


def load(path: str | Path, overrides: list[str] | None = None) -> Case:
    """Read, override and validate a case file."""
    p = Path(path)
    if not p.is_file():
        raise CaseError(f"case file {p} does not exist")
    try:
        raw = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(f"{p}: TOML syntax error: {exc}") from None
    except UnicodeDecodeError:
        raise CaseError(f"{p}: not a UTF-8 text file") from None
    for item in overrides or []:
        apply_override(raw, item)
    try:
        data = validate(raw)
    except CaseError as exc:
        raise CaseError(f"{p}: {exc}") from None
    return Case(data=data, path=p, overrides=list(overrides or []))


def from_dict(raw: dict[str, Any]) -> Case:
    """Validate an in-memory case (used by checks that build cases programmatically)."""
    return Case(data=validate(copy.deepcopy(raw)))


def schema_markdown() -> str:
    """The reference table of every key, for cases/README.md."""
    lines = []

    def emit(title: str, schema: dict[str, Key]):
        lines.append(f"\n### {title}\n")
        lines.append("| key | type | unit | default | meaning |")
        lines.append("|---|---|---|---|---|")
        for k, s in schema.items():
            kind = s.kind if s.kind != "choice" else " \\| ".join(s.choices)
            default = "required" if s.required else ("" if s.default is None else repr(s.default))
            lines.append(f"| `{k}` | {kind} | {s.unit} | {default} | {s.doc} |")

    for sec, spec in SCHEMA.items():
        if spec.sub:
            emit(f"[{sec}]", spec.sub)
            if sec == "grid":
                emit("[grid.walls]", spec.sub["walls"].sub)
    emit("[[materials]]", MATERIAL)
    emit("[[bodies]]", BODY)
    emit("[bodies.geometry]", GEOMETRY)
    emit("[probes.NAME]", PROBE)
    return "\n".join(lines) + "\n"
