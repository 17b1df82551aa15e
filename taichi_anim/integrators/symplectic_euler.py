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

    def __init__(self, **options):
        super().__init__(**options)
        self._copy_x = self._copy_v = None

    def advance(self, model, state, xi, vi, xo, vo, ta, t, h, step, finish) -> None:
        copy = model.coupled and (xi is xo or vi is vo)
        if copy and (self._copy_x is None or self._copy_x.shape[0] != model.particle_count):
            # Springs read neighbours at the start of the step, which this step overwrites: keep a copy.
            self._copy_x = ti.Vector.field(3, float, model.particle_count)
            self._copy_v = ti.Vector.field(3, float, model.particle_count)
        self._kernel(model, state, xi, vi, xo, vo, ta, t, h, step, finish, copy)
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
        copy: ti.template(),
    ):
        if ti.static(copy):
            ti.loop_config(serialize=model.serial)
            for i in range(model.particle_count):
                self._copy_x[i] = xi[i]
                self._copy_v[i] = vi[i]
        ti.loop_config(serialize=model.serial)
        for i in range(model.particle_count):
            if model.alive(state, i, ta):
                x0 = xi[i]
                v0 = vi[i]
                a = ti.Vector.zero(float, 3)
                if ti.static(model.coupled):
                    fx, fv = ti.static((self._copy_x, self._copy_v) if copy else (xi, vi))
                    a = model.accel_from(i, fx, fv, t)
                else:
                    a = model.accel(i, x0, v0, t)
                v1 = v0 + h * a
                x1 = x0 + h * v1
                self._write(model, state, xo, vo, i, x0, v0, x1, v1, h, step, finish)
                if ti.static(finish and state.has_lifetimes):
                    model.release_if_dead(state, i, ta + h)  # dies within this step
            elif ti.static(finish and state.has_lifetimes):
                model.release(state, i)
