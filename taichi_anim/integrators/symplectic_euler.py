"""Symplectic (semi-implicit) Euler: v1 = v0 + h a(x0, v0), x1 = x0 + h v1 (Hairer, Lubich & Wanner,
"Geometric Numerical Integration", sec. I.1.2, eq. 1.10). First order, but energy stays bounded on an
undamped oscillator for h < 2/w. One fused kernel per step: element passes, update, collisions, checks."""

import taichi as ti

from ..runtime import data_oriented
from ..stability import StabilityRegion
from .base import Integrator


@data_oriented
class IntegratorSymplecticEuler(Integrator):
    """Semi-implicit Euler, the cheapest stable-enough step for particles."""

    name = "symplectic_euler"
    order = 1
    stages = 1
    fusable = True
    stability_region = StabilityRegion.symplectic_euler()
    rigid_scheme = "semi_implicit"  # kick, then drift and turn with the new velocities

    @ti.func
    def update(self, model: ti.template(), i, x0, v0, t, h):
        """(x1 [m], v1 [m/s]) of particle i after a step h [s]: v1 = v0 + h a(x0, v0, t), x1 = x0 + h v1."""
        v1 = v0 + h * model.accel_total(self.caches, i, x0, v0, t)
        return x0 + h * v1, v1
