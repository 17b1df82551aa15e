"""Symplectic (semi-implicit) Euler: v1 = v0 + h a(x0, v0), x1 = x0 + h v1 (Hairer, Lubich & Wanner,
"Geometric Numerical Integration", sec. I.1.2, eq. 1.10). First order, but energy stays bounded on an
undamped oscillator for h < 2/w. One fused kernel per step: forces, update, collisions, ageing check."""

import taichi as ti

from ..runtime import data_oriented
from .base import Integrator


@data_oriented
class IntegratorSymplecticEuler(Integrator):
    """Semi-implicit Euler, the cheapest stable-enough step for particles."""

    name = "symplectic_euler"
    order = 1
    stages = 1

    def advance(self, model, state, xi, vi, xo, vo, ta, t, h, step, finish) -> None:
        self._kernel(model, state, xi, vi, xo, vo, ta, t, h, step, finish)
        self.evaluations += 1

    @ti.kernel
    def _kernel(
        self,
        model: ti.template(),
        state: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        xo: ti.template(),
        vo: ti.template(),
        ta: float,
        t: float,
        h: float,
        step: ti.i32,
        finish: ti.template(),
    ):
        model.spring_pass(xi, vi)  # springs read the whole start state before anything is overwritten
        ti.loop_config(serialize=model.serial)
        for i in range(model.particle_count):
            if model.alive(state, i, ta):
                x0 = xi[i]
                v0 = vi[i]
                v1 = v0 + h * model.accel_total(i, x0, v0, t)
                x1 = x0 + h * v1
                self._write(model, state, xo, vo, i, x0, v0, x1, v1, h, step, finish)
                if ti.static(finish and state.has_lifetimes):
                    model.release_if_dead(state, i, ta + h)  # dies within this step
            elif ti.static(finish and state.has_lifetimes):
                model.release(state, i)
