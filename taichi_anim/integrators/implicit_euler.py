"""Linearised implicit (backward) Euler, Baraff & Witkin, "Large Steps in Cloth Simulation" (1998), eq. 6:
    (M - h df/dv - h^2 df/dx) dv = h (f0 + h df/dx v0),   v1 = v0 + dv,   x1 = x0 + h v1.
For forces linear in (x, v) this is exactly backward Euler. The pointwise terms give a block-diagonal
system, solved here directly per particle (3x3); coupled terms (springs) need the iterative solvers.
"""

import taichi as ti

from .base import Integrator


@ti.data_oriented
class IntegratorImplicitEuler(Integrator):
    """Backward Euler, linearised once per step; unconditionally stable on linear damped oscillators."""

    name = "implicit_euler"
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
        ti.loop_config(serialize=model.serial)
        for i in range(model.particle_count):
            if model.alive(state, i, ta):
                x0 = xi[i]
                v0 = vi[i]
                v1 = v0
                if model.inv_mass(i) > 0.0:  # a pinned particle (mass 0) keeps its velocity
                    f = model.force(i, x0, v0, t + h)
                    kx, kv = model.force_jacobian(i, x0, v0, t + h)
                    a = model.mass(i) * ti.Matrix.identity(float, 3) - h * kv - h * h * kx
                    v1 = v0 + a.inverse() @ (h * (f + h * (kx @ v0)))
                x1 = x0 + h * v1
                self._write(model, state, xo, vo, i, x0, v0, x1, v1, h, step, finish)
                if ti.static(finish and state.has_lifetimes):
                    model.release_if_dead(state, i, ta + h)  # dies within this step
            elif ti.static(finish and state.has_lifetimes):
                model.release(state, i)
