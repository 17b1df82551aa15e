"""Uniform gravity, f = m g (Witkin & Baraff, "Physically Based Modeling" course notes, particle dynamics)."""

import taichi as ti

from ..runtime import data_oriented
from .base import PointTerm


@data_oriented
class Gravity(PointTerm):
    """Constant gravitational acceleration `g` [m/s^2] (the engine is Y-up)."""

    has_jacobian = False  # constant force: implicit solvers skip its (zero) blocks at compile time

    def __init__(self, g):
        self.g = tuple(float(c) for c in g)

    def settings(self) -> dict:
        """The term's settings for run.json: type and g [m/s^2]."""
        return {"type": "gravity", "g": self.g}

    @ti.func
    def force(self, i, m, x, v, t):
        """m g [N] on particle i of mass m [kg]."""
        return m * ti.Vector(self.g, dt=float)

    @ti.func
    def jacobian(self, i, m, x, v, t):
        """(df/dx, df/dv): both zero (3x3)."""
        return ti.Matrix.zero(float, 3, 3), ti.Matrix.zero(float, 3, 3)
