"""Python face of the Fortran solver: numpy arrays in, numpy arrays out.

Every Fortran API routine returns ``(..., ierr, msg)``; a non-zero ``ierr`` becomes a
:class:`CpdiError` carrying the Fortran message, so the interpreter always survives a
bad input or a failed step. Arrays are handed over as Fortran-ordered float64 views:
particle arrays are ``(n, 2)`` / ``(n, 4)`` in Python and ``(2, n)`` / ``(4, n)`` in
Fortran, and the transposes cost nothing.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

WALLS = {"open": 0, "slip": 1, "noslip": 2}
WALL_SIDES = ("left", "right", "bottom", "top")
MODELS = {"hencky": 1, "newtonian_fluid": 2, "rigid": 3, "neo_hookean": 4, "rigid_body": 5}
SLOTS = {"mpm": 4, "gimp": 9, "cpdi": 16}
ERROR_NAMES = {1: "input", 2: "state", 3: "nan", 4: "outside", 5: "jacobian", 6: "domain",
               7: "cfl", 8: "lapack", 9: "handle", 10: "alloc", 11: "solve"}


class CpdiError(RuntimeError):
    """An error reported by the Fortran solver (``ierr != 0``)."""

    def __init__(self, code: int, message: str, routine: str = ""):
        self.code = int(code)
        self.kind = ERROR_NAMES.get(self.code, "unknown")
        self.routine = routine
        super().__init__(message)

    def __reduce__(self):  # pickled as (code, message, routine): pmap returns it from a worker
        return type(self), (self.code, str(self), self.routine)


class Extension:
    """One f2py extension of the Fortran core: `name` (a dotted module path) whose routines live in
    its Fortran module `fortran_module`. The solver's is harness._cpdi (cpdi_api, the production
    API); the tests' tests._cpdi_test and the bench's tools._cpdi_bench are built from the same core
    by make build and never installed (docs/design.md). Loaded on first use."""

    def __init__(self, name: str, fortran_module: str, build_hint: str):
        self.name = name
        self.fortran_module = fortran_module
        self.build_hint = build_hint   # the file make build puts in place, for the error without it
        self._module = None

    def _load(self):
        """Import the extension with the OpenMP defaults in the environment (libgomp reads them as it
        loads), then give the caller's environment back unchanged."""
        from harness import openmp_defaults

        added = openmp_defaults(os.environ)
        os.environ.update(added)
        try:
            return importlib.import_module(self.name)
        except ImportError as exc:  # pragma: no cover - exercised only without a build
            raise ImportError(f"the Fortran extension {self.build_hint} is not built; run `make build` "
                              "(or `make test`)") from exc
        finally:
            for k in added:
                os.environ.pop(k, None)

    def extension(self):
        """The f2py extension module itself."""
        if self._module is None:
            self._module = self._load()
        return self._module

    def api(self):
        """The f2py object of the Fortran module (its routines are its attributes)."""
        return getattr(self.extension(), self.fortran_module)

    def error(self):
        """The exception class f2py raises for failed argument checks (`_<name>_error`)."""
        return getattr(self.extension(), f"_{self.name.rsplit('.', 1)[-1]}_error")

    def call(self, name: str, *args):
        """Call routine `name`; its trailing (ierr, msg) become a CpdiError, f2py's own argument
        checks an input CpdiError; the other outputs are returned (one alone, several as a tuple)."""
        try:
            out = getattr(self.api(), name)(*args)
        except (ValueError, TypeError, OverflowError, self.error()) as exc:  # f2py's own argument checks
            raise CpdiError(1, f"{name}: invalid arguments ({exc}); check shapes, types and counts") from None
        *values, ierr, msg = out
        if ierr != 0:
            text = msg.decode("ascii", "replace").strip() if isinstance(msg, bytes) else str(msg).strip()
            raise CpdiError(ierr, text or f"{name} failed with code {ierr}", name)
        if len(values) == 1:
            return values[0]
        return tuple(values)


SOLVER = Extension("harness._cpdi", "cpdi_api", "harness/_cpdi*.so")


def api_error():
    """The exception class f2py raises for failed argument checks."""
    return SOLVER.error()


def api():
    """The f2py module object (loaded on first use)."""
    return SOLVER.api()


def _call(name: str, *args):
    return SOLVER.call(name, *args)


def _f64(a, shape: tuple[int, ...] | None = None, what: str = "array") -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if shape is not None and arr.shape != shape:
        raise CpdiError(1, f"{what} has shape {arr.shape}, expected {shape}")
    return arr


def _particle_array(a, n: int, width: int, what: str) -> np.ndarray:
    arr = _f64(a, what=what)
    if arr.ndim == 1 and width == 1:
        arr = arr.reshape(n) if arr.size == n else arr
    if arr.shape != ((n,) if width == 1 else (n, width)):
        want = (n,) if width == 1 else (n, width)
        raise CpdiError(1, f"{what} has shape {arr.shape}, expected {want}")
    return np.asfortranarray(arr.T)


# -- the solver's options: read from the Fortran table (cpdi_options) at import ----------
_KINDS = {1: "real", 2: "int", 3: "bool", 4: "enum"}
CASE_NO, CASE_DEFAULT, CASE_OPTIONAL = 0, 1, 2   # Option.in_case (cpdi_options)


@dataclass(frozen=True)
class Option:
    """One row of the solver's option table (fortran/src/cpdi_options.f90)."""

    name: str
    kind: str  # "real", "int", "bool" or "enum"
    ncomp: int  # 1, or 2 for a vector (gravity)
    default: float  # every component's; an enum's: its index
    lo: float | None  # None: unbounded (and for bool / enum)
    hi: float | None
    lo_open: bool
    hi_open: bool
    in_case: int  # CASE_NO, CASE_DEFAULT or CASE_OPTIONAL
    choices: tuple[str, ...]  # an enum's value names, in index order
    unit: str
    help: str

    @property
    def codes(self) -> dict[str, int]:
        """An enum's value names and their codes."""
        return {c: i for i, c in enumerate(self.choices)}

    @property
    def python_default(self):
        """The default as set_options and a case file spell it: a value name, a bool, [x, y]."""
        if self.kind == "enum":
            return self.choices[int(self.default)]
        if self.kind == "bool":
            return bool(self.default)
        if self.kind == "int":
            return int(self.default)
        return [self.default] * self.ncomp if self.ncomp > 1 else self.default

    def encode(self, value) -> np.ndarray:
        """The Fortran values of a Python value (an enum by name, a bool, a number or [x, y])."""
        if self.kind == "enum":
            if value not in self.choices:
                raise CpdiError(1, f"{self.name} = {value!r} is not available; use one of {sorted(self.choices)}")
            return np.array([float(self.codes[value])])
        if self.kind == "bool":
            return np.array([float(bool(value))])
        if self.ncomp > 1:
            return _f64(value, (self.ncomp,), self.name).copy()
        return np.array([float(value)])


def _text(b) -> str:
    return (b.decode("ascii", "replace") if isinstance(b, bytes) else str(b)).strip()


def _read_options() -> dict[str, Option]:
    """The option table, row by row, from the extension."""
    out = {}
    for i in range(1, int(api().cpdi_option_count()) + 1):
        name, kind, ncomp, default, lo, hi, lo_open, hi_open, in_case, choices, unit, help_, ierr, msg = \
            api().cpdi_option_info(i)
        if ierr != 0:  # pragma: no cover - the loop stays inside the table
            raise CpdiError(ierr, _text(msg), "cpdi_option_info")
        k = _KINDS[int(kind)]
        bounded = k in ("real", "int")
        out[_text(name)] = Option(
            name=_text(name), kind=k, ncomp=int(ncomp), default=float(default),
            lo=float(lo) if bounded and abs(lo) < 1e300 else None,
            hi=float(hi) if bounded and abs(hi) < 1e300 else None,
            lo_open=bool(lo_open), hi_open=bool(hi_open), in_case=int(in_case),
            choices=tuple(_text(choices).split("|")) if k == "enum" else (), unit=_text(unit), help=_text(help_))
    return out


OPTIONS: dict[str, Option] = _read_options()
# The enum options' codes, by the names other modules import (derived from the table, not a copy).
SHAPES = OPTIONS["shape"].codes
UPDATES = OPTIONS["update"].codes
KINEMATICS = OPTIONS["kinematics"].codes
PROJECTIONS = OPTIONS["projection"].codes
FLUIDS = OPTIONS["fluid"].codes
TRANSFERS = OPTIONS["transfer"].codes
PRECONDS = OPTIONS["pressure_precond"].codes
SOLID_SUBSTEPS = OPTIONS["solid_substeps"].codes


def _slots(kind: int) -> tuple[tuple[str, int], ...]:
    """Names (and widths) of the Fortran's named slots (cpdi_slots): kind 1 diagnostics, 2 timers,
    3 the full state's particle fields, 4 its leading scalars."""
    out = []
    for i in range(1, int(api().cpdi_slot_count(kind)) + 1):
        name, width, ierr, msg = api().cpdi_slot_info(kind, i)
        if ierr != 0:  # pragma: no cover - the loop stays inside the table
            raise CpdiError(ierr, _text(msg), "cpdi_slot_info")
        out.append((_text(name), int(width)))
    return tuple(out)


DIAG_NAMES = tuple(name for name, _ in _slots(1))
TIMER_NAMES = tuple(name for name, _ in _slots(2))
# Layout of Simulation.get_full_state (cpdi_get_full_state): particle rows and scalars.
FULL_STATE_ROWS = _slots(3)
FULL_STATE_SCALARS = (*(name for name, _ in _slots(4)), *(f"diag.{d}" for d in DIAG_NAMES),
                      *(f"timer.{t}" for t in TIMER_NAMES))



@dataclass(frozen=True)
class GridInfo:
    origin: np.ndarray  # position of node 0 (padding included)
    h: float
    nn: tuple[int, int]
    pad: int

    def node_xy(self, idx: np.ndarray) -> np.ndarray:
        """Positions of 0-based node indices, shape idx.shape + (2,)."""
        idx = np.asarray(idx)
        i = idx % self.nn[0]
        j = idx // self.nn[0]
        return np.stack([self.origin[0] + i * self.h, self.origin[1] + j * self.h], axis=-1)


class Simulation:
    """One solver instance. Build it with the set_* methods, then :meth:`advance`."""

    def __init__(self):
        self._handle = _call("cpdi_new")
        self._n = 0
        self._shape = "cpdi"

    # -- life cycle ---------------------------------------------------------------
    def close(self) -> None:
        if getattr(self, "_handle", 0):
            try:
                _call("cpdi_free", self._handle)
            finally:
                self._handle = 0

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    @property
    def n(self) -> int:
        return self._n

    # -- set-up -------------------------------------------------------------------
    def set_grid(self, origin: Sequence[float], ncell: Sequence[int], h: float,
                 walls: Mapping[str, str] | Sequence[str] = ("slip", "slip", "slip", "slip")) -> None:
        """Background grid: origin [m], cells per direction, cell size h [m], walls by side."""
        if isinstance(walls, Mapping):
            kinds = [walls.get(side, "open") for side in WALL_SIDES]
        else:
            kinds = list(walls)
        try:
            codes = [WALLS[k] for k in kinds]
        except KeyError as exc:
            raise CpdiError(1, f"unknown wall kind {exc.args[0]!r}; use one of {sorted(WALLS)}") from None
        if len(codes) != 4:
            raise CpdiError(1, "walls needs four entries: left, right, bottom, top")
        nc = np.asarray(ncell)
        if nc.shape != (2,) or not np.all(np.isfinite(nc)) or np.any(nc != np.round(nc)):
            raise CpdiError(1, f"ncell must be two whole numbers, got {ncell!r}")
        _call("cpdi_set_grid", self._handle, _f64(origin, (2,), "origin"), nc.astype(np.int32),
              float(h), np.asarray(codes, dtype=np.int32))
        self._ncell = (int(nc[0]), int(nc[1]))

    def set_materials(self, materials: Sequence[Mapping]) -> None:
        """Materials as dicts: model plus density, youngs_modulus, poisson_ratio,
        bulk_modulus, viscosity, velocity, friction (as the model needs), and projection (bool:
        takes part in the volumetric projection; default true for fluids only)."""
        if len(materials) == 0:
            raise CpdiError(1, "at least one material is needed")
        models = np.zeros(len(materials), dtype=np.int32)
        props = np.zeros((8, len(materials)), order="F")
        for m, mat in enumerate(materials):
            try:
                models[m] = MODELS[mat["model"]]
            except KeyError:
                raise CpdiError(1, f"material {m}: unknown model {mat.get('model')!r}; "
                                   f"use one of {sorted(MODELS)}") from None
            vel = mat.get("velocity", (0.0, 0.0))
            # a rigid_body's slot 2 (Young's modulus elsewhere) is its wall friction coefficient
            e_or_mu = mat.get("friction", 0.0) if mat["model"] == "rigid_body" else mat.get("youngs_modulus", 0.0)
            props[:, m] = [mat.get("density", 0.0), e_or_mu,
                           mat.get("poisson_ratio", 0.0), mat.get("bulk_modulus", 0.0),
                           mat.get("viscosity", 0.0), vel[0], vel[1],
                           float(mat.get("projection", mat["model"] == "newtonian_fluid"))]
        _call("cpdi_set_materials", self._handle, models, props)

    def set_particles(self, x, v, mass, vol, r, mat) -> None:
        """Particles: x, v (n,2); mass, vol (n,); domain vectors r (n,4) = [r1x, r1y, r2x, r2y];
        material index mat (n,) 0-based."""
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 2 or x.shape[0] < 1:
            raise CpdiError(1, f"particle positions must have shape (n, 2) with n >= 1, got {x.shape}")
        n = x.shape[0]
        mat = np.asarray(mat)
        if mat.shape != (n,):
            raise CpdiError(1, f"mat has shape {mat.shape}, expected ({n},)")
        if mat.size and (not np.all(np.isfinite(mat)) or np.any(mat != np.round(mat))):
            raise CpdiError(1, "material indices must be whole numbers")
        _call("cpdi_set_particles", self._handle,
              _particle_array(x, n, 2, "x"), _particle_array(v, n, 2, "v"),
              _particle_array(mass, n, 1, "mass"), _particle_array(vol, n, 1, "vol"),
              _particle_array(r, n, 4, "r"), (mat.astype(np.int64) + 1).astype(np.int32))
        self._n = n

    def set_options(self, **options) -> None:
        """Solver options by name, every other option at its default: the names, kinds, defaults
        and ranges are the Fortran table's (:data:`OPTIONS`, fortran/src/cpdi_options.f90; the case
        schema's [solver] keys are the same table, cases/README.md). An enum is given by its value's
        name (``shape="gimp"``), a flag as a bool, ``gravity`` as (gx, gy). ``dt`` given means a
        fixed time step (the table's ``fixed_dt`` is set from it), otherwise ``cfl`` sets it.
        ``fluid`` picks the water model: the paper's explicit ``weakly_compressible`` one, or
        ``incompressible`` (pressure projection on a staggered grid; ``transfer``, the CG settings and
        ``volume_correction`` belong to it; docs/fsi_incompressible.md, docs/incompressible_water.md).
        Each value is checked by the table's row in Fortran, the rules between options by
        ``cpdi_check_options``."""
        unknown = [k for k in options if k not in OPTIONS or k == "fixed_dt"]
        if unknown:
            names = sorted(k for k in OPTIONS if k != "fixed_dt")
            raise CpdiError(1, f"unknown solver option {unknown[0]!r}; use one of {names}")
        dt = options.get("dt")
        values = {name: opt.python_default for name, opt in OPTIONS.items()}
        values.update({k: v for k, v in options.items() if k != "dt"})
        values["fixed_dt"] = dt is not None
        values["dt"] = dt if dt is not None else OPTIONS["dt"].default
        for name, opt in OPTIONS.items():
            _call("cpdi_set_option", self._handle, name, opt.encode(values[name]))
        _call("cpdi_check_options", self._handle)
        self._shape = values["shape"]
        self._fluid = values["fluid"]

    def set_bodies(self, body, contact: bool = False, friction: float = 0.0, fullness: float = 0.9) -> None:
        """Body index (n,) 0-based of every particle; with contact each body gets its own
        velocity field and Bardenhagen frictional contact acts between them, at nodes whose
        support the bodies fill to at least `fullness` (fraction of a cell's area)."""
        b = np.asarray(body)
        if b.shape != (self._n,) or (b.size and (np.any(b < 0) or np.any(b != np.round(b)))):
            raise CpdiError(1, f"body must be ({self._n},) whole numbers >= 0, got shape {b.shape}")
        _call("cpdi_set_bodies", self._handle, (b.astype(np.int64) + 1).astype(np.int32), int(bool(contact)),
              float(friction), float(fullness))

    def set_velocity_table(self, material: int, rows) -> None:
        """Velocity table of rigid material ``material`` (0-based): rows (k, 3) of (t [s], vx, vy [m/s]),
        times strictly increasing; piecewise linear in time, held before the first row and after the
        last. Each step moves the body with the table's mean velocity over the step, so its
        displacement is the table's integral to round-off (fortran/src/cpdi_motion.f90). Call it
        after set_materials (which drops every table)."""
        tab = _f64(rows, what="velocity table")
        if tab.ndim != 2 or tab.shape[1] != 3 or tab.shape[0] < 1:
            raise CpdiError(1, f"velocity table has shape {tab.shape}, expected (k, 3) rows of (t, vx, vy)")
        _call("cpdi_set_velocity_table", self._handle, int(material) + 1, np.asfortranarray(tab.T))

    def set_body_force(self, b) -> None:
        """External body force per unit mass (n,2) [m/s^2], added to gravity until replaced."""
        _call("cpdi_set_body_force", self._handle, _particle_array(b, self._n, 2, "body force"))

    def set_state(self, v, F, t: float) -> None:
        """Overwrite velocities (n,2), deformation gradients (n,4) [F11, F21, F12, F22] and the clock."""
        _call("cpdi_set_state", self._handle, _particle_array(v, self._n, 2, "v"),
              _particle_array(F, self._n, 4, "F"), float(t))

    # -- stepping -----------------------------------------------------------------
    def advance(self, t_end: float, max_steps: int = 2**31 - 1, land: bool = True) -> tuple[int, float]:
        """Step until time t_end (the last step lands on it) or max_steps; returns (steps, t).
        land=False: incompressible water keeps its own step and passes t_end by less than one
        step instead of landing with a short step (the weakly compressible model always lands)."""
        steps, t = _call("cpdi_advance", self._handle, float(t_end), int(max_steps), int(bool(land)))
        return int(steps), float(t)

    def stable_dt(self) -> float:
        """h / max(c + |v|) of the current state, before the CFL factor [s]."""
        return float(_call("cpdi_stable_dt", self._handle))

    # -- queries ------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        """Particle state: x, v (n,2); F, sigma, r (n,4); vol (n,)."""
        if self._n < 1:
            raise CpdiError(2, "no particles set; call set_particles first")
        x, v, F, sig, vol, r = _call("cpdi_get_state", self._handle, self._n)
        return {"x": x.T, "v": v.T, "F": F.T, "sigma": sig.T, "vol": vol, "r": r.T}

    def diagnostics(self) -> dict[str, float]:
        d = _call("cpdi_get_diag", self._handle)
        return dict(zip(DIAG_NAMES, (float(x) for x in d), strict=True))

    def pressure_stats(self) -> dict[str, float]:
        """The last pressure solve of an incompressible run: CG iterations, relative residual,
        closed-water defect (the part of the right-hand side in the null space of closed water
        regions, relative to its norm: round-off for a physical solve), closed water regions
        and the preconditioner."""
        s = _call("cpdi_pressure_stats", self._handle)
        names = {v: k for k, v in PRECONDS.items()}
        return {"iterations": int(s[0]), "residual": float(s[1]), "defect": float(s[2]),
                "closed_regions": int(s[3]), "precond": names[int(s[4])]}

    def timers(self) -> dict[str, float]:
        t = _call("cpdi_get_timers", self._handle)
        return dict(zip(TIMER_NAMES, (float(x) for x in t), strict=True))

    def grid_info(self) -> GridInfo:
        info = _call("cpdi_grid_info", self._handle)
        return GridInfo(origin=np.array(info[:2]), h=float(info[2]), nn=(int(info[3]), int(info[4])),
                        pad=int(info[5]))

    def project(self, values, mode: str = "cell", mask=None) -> np.ndarray:
        """Mass-weighted projection of a particle field (n,) onto cell-wise constant
        (``cell``) or nodal bilinear (``nodal``) functions, using the run's interpolation
        domains; particles with mask False keep their values."""
        val = np.array(values, dtype=np.float64)
        if val.shape != (self._n,):
            raise CpdiError(1, f"values has shape {val.shape}, expected ({self._n},)")
        m = np.ones(self._n, dtype=np.int32) if mask is None else np.asarray(mask).astype(np.int32)
        code = {"cell": 1, "nodal": 2}.get(mode)
        if code is None:
            raise CpdiError(1, f"projection mode {mode!r} is not available; use 'cell' or 'nodal'")
        return _call("cpdi_project", self._handle, code, m, val)

    def grid_pressure(self) -> dict[str, np.ndarray]:
        """Cell fields of an incompressible run after its last step, each (nx, ny) over the
        physical cells: ``pressure`` [Pa] (0 outside the water), ``fill`` (particle volume
        per cell area) and ``water`` (1 where a water particle lies in the cell)."""
        nx, ny = self._ncell
        p, fill, cell = _call("cpdi_grid_pressure", self._handle, nx, ny)
        return {"pressure": p, "fill": fill, "water": cell}

    def solid_force(self) -> np.ndarray:
        """Force [N/m] of incompressible water on the solids coupled to it in the last step (the solid
        particles' momentum change by the projection over dt; zeros otherwise)."""
        return np.asarray(_call("cpdi_solid_force", self._handle), dtype=float)

    def water_loads(self) -> np.ndarray:
        """The incompressible water's load on every particle in the last step, (n, 3): force fx, fy
        [N/m] and a couple c about the particle's centre [N m/m]; the moment about a point O of a
        set of particles is sum (x_p - O) x f_p + c_p. Solids coupled to the water only (deformable,
        prescribed rigid and free rigid bodies: fortran/src/cpdi_loads.f90); zeros elsewhere."""
        if self._n < 1:
            raise CpdiError(2, "no particles set; call set_particles first")
        return _call("cpdi_water_loads", self._handle, self._n).T

    RIGID_BODY_COLUMNS = ("mass", "inertia", "x", "y", "vx", "vy", "omega", "fx", "fy", "torque")

    def rigid_bodies(self) -> list[dict]:
        """The free rigid bodies (rigid_body materials) after the last step, one dict each: mass
        [kg/m], inertia about the centre [kg m^2/m], centre x, y [m], velocity vx, vy [m/s], omega
        [1/s], and the water's force fx, fy [N/m] and torque [N m/m] during the step (the state at
        the step's start for mass, inertia and centre)."""
        nb, state = _call("cpdi_rigid_bodies", self._handle, 64)
        cols = self.RIGID_BODY_COLUMNS
        return [dict(zip(cols, map(float, state[:, b]), strict=True)) for b in range(min(int(nb), 64))]

    def face_velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """Face velocities of an incompressible run after its last step: u (nx + 1, ny) on the
        cells' left faces, v (nx, ny + 1) on their bottom faces."""
        nx, ny = self._ncell
        u, v = _call("cpdi_face_velocity", self._handle, nx, ny)
        return u, v

    def transfer_cycle(self) -> None:
        """Incompressible runs only: particle-to-grid transfer to the face lattices and back,
        nothing else (PIC, or APIC with transfer = 'apic')."""
        _call("cpdi_transfer_cycle", self._handle)

    def shape_functions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Weights of the current configuration: node index (0-based), S, dS/dx, dS/dy,
        each (n, slots)."""
        ns = SLOTS[self._shape]
        idx, w, gx, gy = _call("cpdi_get_shape", self._handle, self._n, ns)
        return idx.T - 1, w.T, gx.T, gy.T

    # -- checkpoint / restart -------------------------------------------------------
    def get_full_state(self) -> dict[str, np.ndarray]:
        """Everything stepping depends on: ``particles`` (rows x n, Fortran layout, rows
        named by FULL_STATE_ROWS) and ``scalars`` (FULL_STATE_SCALARS). A simulation built
        from the same case and given this by :meth:`set_full_state` continues bit for bit."""
        if self._n < 1:
            raise CpdiError(2, "no particles set; call set_particles first")
        nprow, nscal = _call("cpdi_full_state_size")
        particles, scalars = _call("cpdi_get_full_state", self._handle, nprow, self._n, nscal)
        return {"particles": particles, "scalars": scalars}

    def set_full_state(self, particles, scalars) -> None:
        """Restore :meth:`get_full_state`'s output. Call it after every set_* method (they
        mark the stress stale; this restores stress and signal speed as they were)."""
        _call("cpdi_set_full_state", self._handle, np.asfortranarray(particles, dtype=np.float64),
              np.asarray(scalars, dtype=np.float64))


def threads(n: int = 0) -> int:
    """OpenMP threads of the solver in this process: n > 0 sets them, 0 only asks. Results do
    not depend on it (bitwise, see cpdi_schedule.f90)."""
    if not isinstance(n, int) or n < 0:
        raise CpdiError(1, f"threads must be a whole number >= 0 (0 asks), got {n!r}")
    return int(_call("cpdi_threads", n))


def log_strain(F, method: str = "closed") -> np.ndarray:
    """Plane-strain log strain 1/2 log(F F^T) of F (n,4) [F11, F21, F12, F22] -> (n,3) [e11, e22, e12]."""
    F = np.atleast_2d(np.asarray(F, dtype=np.float64))
    if F.ndim != 2 or F.shape[1] != 4:
        raise CpdiError(1, f"F must have shape (n, 4), got {F.shape}")
    m = {"closed": 0, "lapack": 1}[method]
    eps = _call("cpdi_log_strain", np.asfortranarray(F.T), m)
    return eps.T


def pressure(sigma: np.ndarray) -> np.ndarray:
    """Pressure -tr(sigma)/3 of plane-strain stresses (n,4) [sxx, syy, sxy, szz]."""
    s = np.asarray(sigma)
    return -(s[:, 0] + s[:, 1] + s[:, 3]) / 3.0


