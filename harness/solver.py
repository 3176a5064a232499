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

SHAPES = {"mpm": 0, "gimp": 1, "cpdi": 2}
UPDATES = {"usl": 0, "musl": 1}
WALLS = {"open": 0, "slip": 1, "noslip": 2}
WALL_SIDES = ("left", "right", "bottom", "top")
MODELS = {"hencky": 1, "newtonian_fluid": 2, "rigid": 3, "neo_hookean": 4, "rigid_body": 5}
KINEMATICS = {"log": 0, "small": 1}
PROJECTIONS = {"none": 0, "cell": 1, "nodal": 2}
FLUIDS = {"weakly_compressible": 0, "incompressible": 1}
TRANSFERS = {"flip": 0, "apic": 1}
PRECONDS = {"mic0": 0, "multigrid": 1}
SOLID_SUBSTEPS = {"off": 0, "explicit": 1, "implicit": 2, "auto": 3}
SLOTS = {"mpm": 4, "gimp": 9, "cpdi": 16}
DIAG_NAMES = ("t", "dt", "steps", "kinetic_energy", "strain_energy", "momentum_x", "momentum_y",
              "gravity_work", "body_force_work", "mass", "max_signal_speed", "wall_clamps", "friction_work",
              "viscous_dissipation", "cg_iterations", "cg_residual", "cg_iterations_total", "correction_work")
TIMER_NAMES = ("shape", "p2g", "grid", "g2p", "deformation", "stress", "projection", "pressure_solve")
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


def _load_extension():
    """Import the extension with the OpenMP defaults in the environment (libgomp reads them as it
    loads), then give the caller's environment back unchanged."""
    from harness import openmp_defaults

    added = openmp_defaults(os.environ)
    os.environ.update(added)
    try:
        return importlib.import_module("harness._cpdi").cpdi_api
    except ImportError as exc:  # pragma: no cover - exercised only without a build
        raise ImportError(
            "the Fortran extension harness/_cpdi*.so is not built; run `make build` (or `make test`)"
        ) from exc
    finally:
        for k in added:
            os.environ.pop(k, None)


_API = None


def api_error():
    """The exception class f2py raises for failed argument checks."""
    return importlib.import_module("harness._cpdi").__cpdi_error


def api():
    """The f2py module object (loaded on first use)."""
    global _API
    if _API is None:
        _API = _load_extension()
    return _API


def _call(name: str, *args):
    try:
        out = getattr(api(), name)(*args)
    except (ValueError, TypeError, OverflowError, api_error()) as exc:  # f2py's own argument checks
        raise CpdiError(1, f"{name}: invalid arguments ({exc}); check shapes, types and counts") from None
    *values, ierr, msg = out
    if ierr != 0:
        text = msg.decode("ascii", "replace").strip() if isinstance(msg, bytes) else str(msg).strip()
        raise CpdiError(ierr, text or f"{name} failed with code {ierr}", name)
    if len(values) == 1:
        return values[0]
    return tuple(values)


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

    def set_options(self, *, shape: str = "cpdi", update: str = "musl", projection: str = "none",
                    kinematics: str = "log", domain_scaling: bool = False, dt: float | None = None,
                    cfl: float = 0.3, gravity: Sequence[float] = (0.0, 0.0), damping: float = 0.0,
                    flip: float = 1.0, lcrit: float = 0.49999, projection_stabilization: float = 0.0,
                    fluid: str = "weakly_compressible", transfer: str = "flip", cg_tolerance: float = 1e-8,
                    cg_max_iterations: int = 0, volume_correction: float = 0.5,
                    correction_tolerance: float = 1e-4, pressure_precond: str = "mic0",
                    solid_substeps: str = "off") -> None:
        """Solver options; ``dt`` given means a fixed time step, otherwise ``cfl`` sets it.
        ``fluid`` picks the water model: the paper's explicit ``weakly_compressible`` one, or
        ``incompressible`` (pressure projection on a staggered grid; ``transfer``, the CG
        settings and ``volume_correction`` belong to it; how solids join its projection is chosen by
        what they are, docs/fsi_incompressible.md); ``pressure_precond`` the pressure CG's
        preconditioner, ``mic0`` or ``multigrid`` (docs/incompressible_water.md); ``solid_substeps``
        whether deformable solids in that water are subcycled inside its step
        (docs/fsi_incompressible.md)."""
        table = (("shape", shape, SHAPES), ("update", update, UPDATES), ("projection", projection, PROJECTIONS),
                 ("kinematics", kinematics, KINEMATICS))
        codes = []
        for key, value, allowed in table:
            if value not in allowed:
                raise CpdiError(1, f"{key} = {value!r} is not available; use one of {sorted(allowed)}")
            codes.append(allowed[value])
        iopt = np.array(codes + [int(bool(domain_scaling)), int(dt is not None)], dtype=np.int32)
        g = _f64(gravity, (2,), "gravity")
        ropt = np.array([cfl, g[0], g[1], damping, dt if dt is not None else 0.0, flip, lcrit,
                         projection_stabilization], dtype=np.float64)
        _call("cpdi_set_options", self._handle, iopt, ropt)
        for key, value, allowed in (("fluid", fluid, FLUIDS), ("transfer", transfer, TRANSFERS),
                                    ("pressure_precond", pressure_precond, PRECONDS),
                                    ("solid_substeps", solid_substeps, SOLID_SUBSTEPS)):
            if value not in allowed:
                raise CpdiError(1, f"{key} = {value!r} is not available; use one of {sorted(allowed)}")
            _call("cpdi_set_option", self._handle, key, float(allowed[value]))
        if transfer == "apic" and fluid != "incompressible":
            raise CpdiError(1, "transfer = 'apic' is available with fluid = 'incompressible' only; "
                               "use transfer = 'flip' (with flip) for the weakly compressible model")
        for key, value in (("cg_tolerance", cg_tolerance), ("cg_max_iterations", cg_max_iterations),
                           ("volume_correction", volume_correction), ("correction_tolerance", correction_tolerance)):
            _call("cpdi_set_option", self._handle, key, float(value))
        self._shape = shape
        self._fluid = fluid

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


def core_round_trip(iters: int = 20000) -> float:
    """Mean wall time [ns] of one round trip of a cache line between two OpenMP threads of this
    process (over iters trips): what moving data between the team's cores costs now. A control
    of make bench. It always runs on 2 threads, whatever threads() says, and raises CpdiError where
    OpenMP cannot start them (a build without OpenMP, OMP_THREAD_LIMIT=1)."""
    if not isinstance(iters, int) or iters < 1:
        raise CpdiError(1, f"iters must be a whole number >= 1, got {iters!r}")
    return float(_call("cpdi_core_round_trip", iters))


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


# Layout of Simulation.get_full_state (cpdi_get_full_state): particle rows and scalars.
FULL_STATE_ROWS = (("x", 2), ("v", 2), ("F", 4), ("L", 4), ("sigma", 4), ("r", 4), ("body_force", 2), ("vol", 1),
                   ("psi", 1), ("jbar", 1), ("water_accel", 2))
FULL_STATE_SCALARS = ("t", "steps", "smax", "visc_dt", "dt_last", *(f"diag.{d}" for d in DIAG_NAMES),
                      *(f"timer.{t}" for t in TIMER_NAMES))
