"""Manufactured solutions with body forces (FORMULAS 3.1, 3.2), driven through the API.

Each problem gives the exact motion x(X, t), the velocity, the deformation gradient and
the body force per unit mass b(X, t) = d2x/dt2 - Div_X P / rho0 for the compressible
neo-Hookean law sigma = (lam ln J / J) I + (mu / J)(B - I). The body force is applied to
each particle at its exact reference position X (particles carry it: they are material
points), re-evaluated at the start of every step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.solver import Simulation


@dataclass(frozen=True)
class Vortex:
    """Generalized vortex (Kamojjala et al. 2015): annulus 0.75 <= R <= 1.25, pure rotation
    of each circle by alpha(R, t) = A sin(pi c t) g(R), g = (4R - 3)^2 (4R - 5)^2; J = 1."""

    name: str = "vortex"
    rho0: float = 1000.0
    E: float = 1000.0
    nu: float = 0.3
    A: float = 1.0
    t_end: float = 0.5
    box: tuple = (-1.5, -1.5, 3.0, 3.0)  # grid origin and size
    walls: tuple = ("open",) * 4

    @property
    def mu(self):
        return self.E / (2 * (1 + self.nu))

    @property
    def c(self):
        return np.sqrt(self.E / self.rho0)

    def inside(self, X):
        R = np.hypot(X[:, 0], X[:, 1])
        return (R >= 0.75) & (R <= 1.25)

    @staticmethod
    def g(R):
        return (4 * R - 3) ** 2 * (4 * R - 5) ** 2

    def position(self, X, t):
        R = np.hypot(X[:, 0], X[:, 1])
        th = np.arctan2(X[:, 1], X[:, 0]) + self.A * np.sin(np.pi * self.c * t) * self.g(R)
        return np.column_stack([R * np.cos(th), R * np.sin(th)])

    def velocity(self, X, t):
        R = np.hypot(X[:, 0], X[:, 1])
        x = self.position(X, t)
        w = self.A * np.pi * self.c * np.cos(np.pi * self.c * t) * self.g(R)
        return np.column_stack([-w * x[:, 1], w * x[:, 0]])

    def deformation(self, X, t):
        """F = dx/dX [F11, F21, F12, F22], by the chain rule of the rotation field."""
        R = np.hypot(X[:, 0], X[:, 1])
        a = self.A * np.sin(np.pi * self.c * t)
        dg = 8 * (4 * R - 3) * (4 * R - 5) ** 2 + 8 * (4 * R - 3) ** 2 * (4 * R - 5)
        th = np.arctan2(X[:, 1], X[:, 0]) + a * self.g(R)
        c, s = np.cos(th), np.sin(th)
        # x = R (cos th, sin th); dR/dX = X/R; dth/dX = (-Y, X)/R^2 + a g'(R) X/R
        dth = np.column_stack([-X[:, 1] / R**2 + a * dg * X[:, 0] / R, X[:, 0] / R**2 + a * dg * X[:, 1] / R])
        dR = X / R[:, None]
        F11 = c * dR[:, 0] - R * s * dth[:, 0]
        F12 = c * dR[:, 1] - R * s * dth[:, 1]
        F21 = s * dR[:, 0] + R * c * dth[:, 0]
        F22 = s * dR[:, 1] + R * c * dth[:, 1]
        return np.column_stack([F11, F21, F12, F22])

    def body_force(self, X, t):
        R = np.hypot(X[:, 0], X[:, 1])
        A, c, mu, rho = self.A, self.c, self.mu, self.rho0
        gg = self.g(R)
        br = -R * (A * np.pi * c * np.cos(np.pi * c * t)) ** 2 * gg**2 + (4096 * mu / rho) * A**2 * np.sin(
            np.pi * c * t) ** 2 * R * (R - 1) ** 2 * (4 * R - 3) ** 2 * (4 * R - 5) ** 2
        bt = -A * np.sin(np.pi * c * t) * (R * np.pi**2 * c**2 * gg + (64 * mu / rho) * (96 * R**3 - 240 * R**2
                                                                                        + 188 * R - 45))
        beta = np.arctan2(X[:, 1], X[:, 0]) + A * np.sin(np.pi * c * t) * gg
        cb, sb = np.cos(beta), np.sin(beta)
        return np.column_stack([cb * br - sb * bt, sb * br + cb * bt])


@dataclass(frozen=True)
class AxisAligned:
    """Axis-aligned displacement (Vaango 'AxisAligned') reduced to 2D plane strain (W = 0):
    U = A sin(pi X) sin(pi c t), V = A sin(pi Y) sin(pi (2/3 + c t)) on the unit square with
    slip walls (U = 0 at X = 0, 1 and V = 0 at Y = 0, 1)."""

    name: str = "axis_aligned"
    rho0: float = 1.0
    mu: float = 3846.15
    K: float = 8333.33
    A: float = 0.05
    t_end: float = 0.02
    box: tuple = (0.0, 0.0, 1.0, 1.0)
    walls: tuple = ("slip",) * 4

    @property
    def E(self):
        return 9 * self.K * self.mu / (3 * self.K + self.mu)

    @property
    def nu(self):
        return (3 * self.K - 2 * self.mu) / (2 * (3 * self.K + self.mu))

    @property
    def lam(self):
        return self.K - 2 * self.mu / 3

    @property
    def c(self):
        return np.sqrt(self.E / self.rho0)

    def inside(self, X):
        return np.ones(len(X), bool)

    def _uv(self, X, t):
        ph = np.pi * self.c * t
        return (self.A * np.sin(np.pi * X[:, 0]) * np.sin(ph),
                self.A * np.sin(np.pi * X[:, 1]) * np.sin(np.pi * 2 / 3 + ph))

    def position(self, X, t):
        U, V = self._uv(X, t)
        return X + np.column_stack([U, V])

    def velocity(self, X, t):
        ph = np.pi * self.c * t
        w = self.A * np.pi * self.c
        return np.column_stack([w * np.sin(np.pi * X[:, 0]) * np.cos(ph),
                                w * np.sin(np.pi * X[:, 1]) * np.cos(np.pi * 2 / 3 + ph)])

    def deformation(self, X, t):
        ph = np.pi * self.c * t
        fxx = 1 + self.A * np.pi * np.cos(np.pi * X[:, 0]) * np.sin(ph)
        fyy = 1 + self.A * np.pi * np.cos(np.pi * X[:, 1]) * np.sin(np.pi * 2 / 3 + ph)
        z = np.zeros(len(X))
        return np.column_stack([fxx, z, z, fyy])

    def body_force(self, X, t):
        U, V = self._uv(X, t)
        F = self.deformation(X, t)
        fxx, fyy = F[:, 0], F[:, 3]
        lnJ = np.log(fxx * fyy)
        k = self.mu / self.rho0 - self.c**2
        bx = np.pi**2 * U * (k - (self.lam * (lnJ - 1) - self.mu) / (self.rho0 * fxx**2))
        by = np.pi**2 * V * (k - (self.lam * (lnJ - 1) - self.mu) / (self.rho0 * fyy**2))
        return np.column_stack([bx, by])


PROBLEMS = {"vortex": Vortex(), "axis_aligned": AxisAligned()}


def seed(problem, h: float, ppc: int = 2):
    """Reference positions X and volumes of ppc x ppc particles per cell inside the body."""
    ox, oy, sx, sy = problem.box
    d = h / ppc
    xs = np.arange(ox + d / 2, ox + sx, d)
    ys = np.arange(oy + d / 2, oy + sy, d)
    X = np.array(np.meshgrid(xs, ys, indexing="xy")).reshape(2, -1).T
    X = X[problem.inside(X)]
    return X, np.full(len(X), d * d), d


def run(problem, shape: str, n: int, cfl: float = 0.3, ppc: int = 2, update: str = "musl") -> dict:
    """Run to t_end on a grid of cell size box_width / n; returns displacement errors."""
    ox, oy, sx, sy = problem.box
    h = sx / n
    X, vol, d = seed(problem, h, ppc)
    npart = len(X)
    F0 = problem.deformation(X, 0.0)
    sim = Simulation()
    try:
        sim.set_grid((ox, oy), (n, round(sy / h)), h, problem.walls)
        sim.set_materials([{"model": "neo_hookean", "density": problem.rho0, "youngs_modulus": problem.E,
                            "poisson_ratio": problem.nu}])
        sim.set_particles(problem.position(X, 0.0), problem.velocity(X, 0.0), problem.rho0 * vol, vol,
                          np.tile([d / 2, 0, 0, d / 2], (npart, 1)), np.zeros(npart, dtype=np.int32))
        sim.set_options(shape=shape, update=update, cfl=cfl, gravity=(0.0, 0.0))
        sim.set_state(problem.velocity(X, 0.0), F0, 0.0)
        t, steps = 0.0, 0
        while t < problem.t_end * (1 - 1e-12):
            sim.set_body_force(problem.body_force(X, t))
            k, t = sim.advance(problem.t_end, max_steps=1)
            steps += k
        x = sim.state()["x"]
    finally:
        sim.close()
    err = x - problem.position(X, problem.t_end)
    mag = np.sqrt((err**2).sum(axis=1))
    return {"h": h, "particles": npart, "steps": steps, "l2": float(np.sqrt(np.mean(mag**2))),
            "linf": float(mag.max())}
