"""Linearised implicit (backward) Euler, Baraff & Witkin, "Large Steps in Cloth Simulation" (1998), eq. 6:
    (M - h df/dv - h^2 df/dx) dv = h (f0 + h df/dx v0),   v1 = v0 + dv,   x1 = x0 + h v1.
For forces linear in (x, v) this is exactly backward Euler. Pointwise terms alone give a block-diagonal
system, solved directly per particle (3x3). With springs the system couples particles and is solved
matrix-free (implicit_system.py) by block Jacobi, CG or block-Jacobi-preconditioned CG (linalg/).
"""

import taichi as ti

from ..linalg import LinearSolver, LinearSolverKind, make_linear_solver
from ..runtime import data_oriented
from .base import Integrator


@data_oriented
class IntegratorImplicitEuler(Integrator):
    """Backward Euler, linearised once per step; unconditionally stable on linear damped oscillators.

    linear_solver: "pcg" (default), "cg" or "jacobi" (or a LinearSolver), used when the model has
    springs; tol: relative residual |b - A dv| / |b|; max_iterations per step; warm_start: start each
    solve from the previous step's dv. `last_solve` holds the last solve's iterations and residual.
    A solve also stops once |b - A dv| <= tol h g |m| (g = 9.81 m/s^2, |m| the 2-norm of the masses):
    tol times the impulse gravity gives the particles in one step, so a cloth at rest, whose b is
    round-off, does not iterate to the cap on it.
    """

    name = "implicit_euler"
    order = 1
    stages = 1

    def __init__(
        self,
        *,
        linear_solver: LinearSolver | LinearSolverKind | str = "pcg",
        tol: float = 1e-4,
        max_iterations: int = 200,
        warm_start: bool = True,
        **options,
    ):
        super().__init__(**options)
        if isinstance(linear_solver, LinearSolver):
            self.linear_solver = linear_solver
        else:
            self.linear_solver = make_linear_solver(
                linear_solver, tol=tol, max_iterations=max_iterations, warm_start=warm_start
            )
        self.system = None
        self.last_solve = None

    def settings(self) -> dict:
        return {**super().settings(), **self.linear_solver.settings()}

    def advance(self, model, state, xi, vi, xo, vo, ta, t, h, step, finish) -> None:
        self.evaluations += 1
        if model.springs is None:
            self._kernel(model, state, xi, vi, xo, vo, ta, t, h, step, finish)
            return
        if self.system is None or self.system.model is not model:
            from .implicit_system import ImplicitSystem

            self.system = ImplicitSystem(model)
        self._assemble(model, state, self.system, xi, vi, ta, t + h, h)
        floor = self.linear_solver.tol * h * 9.81 * self.system.mass_norm
        self.last_solve = self.linear_solver.solve(self.system, atol=floor)
        self._update(model, state, self.system, xi, vi, xo, vo, ta, t, h, step, finish)

    @ti.kernel
    def _assemble(
        self,
        model: ti.template(),
        state: ti.template(),
        system: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        ta: float,
        t: float,
        h: float,
    ):
        system.spring_pass(xi, vi, h)
        ti.loop_config(serialize=model.serial)
        for i in range(model.particle_count):
            system.assemble_row(i, xi, vi, t, h)

    @ti.kernel
    def _update(
        self,
        model: ti.template(),
        state: ti.template(),
        system: ti.template(),
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
                v1 = v0 + system.solution[i]
                x1 = x0 + h * v1
                self._write(model, state, xo, vo, i, x0, v0, x1, v1, h, step, finish)
                if ti.static(finish and state.has_lifetimes):
                    model.release_if_dead(state, i, ta + h)
            elif ti.static(finish and state.has_lifetimes):
                model.release(state, i)

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
