"""Uniform gravity, f = m g (Witkin & Baraff, "Physically Based Modeling" course notes, particle dynamics)."""

import numpy as np
import taichi as ti

from ..runtime import data_oriented
from .base import PointTerm


@data_oriented
class Gravity(PointTerm):
    """Constant gravitational acceleration `g` [m/s^2] (the engine is Y-up)."""

    has_jacobian = False  # constant force: implicit solvers skip its (zero) blocks at compile time
    energy_kind = "potential"  # -sum m g.x (not elastic: Model.energy leaves it out, has_energy False)

    def __init__(self, g):
        self.g = tuple(float(c) for c in g)

    def settings(self) -> dict:
        """The term's settings for run.json: type and g [m/s^2]."""
        return {"type": "gravity", "g": self.g}

    def energy(self, x, masses) -> float:
        """The potential -sum m g.x [J] at positions x (N,3) [m] with masses (N,) [kg]."""
        g = np.asarray(self.g, dtype=np.float64)
        return -float(np.sum(np.asarray(masses, dtype=np.float64) * (np.asarray(x, dtype=np.float64) @ g)))

    def body_acceleration(self) -> tuple:
        """g [m/s^2]: gravity acts on rigid bodies too (at their centres of mass)."""
        return self.g

    def acceleration_bound(self) -> float:
        """|g| [m/s^2]: the watchdog lets bounds grow by free fall and counts M |g| H of release."""
        return float(np.linalg.norm(self.g))

    def stored_energy(self, x, masses) -> float:
        """0: gravity's release within the scene is M |g| H, counted from acceleration_bound."""
        return 0.0

    @ti.func
    def force(self, i, m, x, v, t):
        """m g [N] on particle i of mass m [kg]."""
        return m * ti.Vector(self.g, dt=float)

    @ti.func
    def jacobian(self, i, m, x, v, t):
        """(df/dx, df/dv): both zero (3x3)."""
        return ti.Matrix.zero(float, 3, 3), ti.Matrix.zero(float, 3, 3)
