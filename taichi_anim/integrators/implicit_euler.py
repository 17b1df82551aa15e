"""Linearised implicit (backward) Euler, Baraff & Witkin, "Large Steps in Cloth Simulation" (1998), eq. 6:
    (M - h df/dv - h^2 df/dx) dv = h (f0 + h df/dx v0),   v1 = v0 + dv,   x1 = x0 + h v1.
For forces linear in (x, v) this is exactly backward Euler. Pointwise terms alone give a block-diagonal
system, solved directly per particle (3x3). With element terms (springs, membrane, bending, aerodynamics)
the system couples particles and is solved matrix-free (implicit_system.py) by block Jacobi, CG or
block-Jacobi-preconditioned CG (linalg/).
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
    implicit = True

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

    def _allocate(self, model) -> None:
        from .implicit_system import ImplicitSystem

        self.system = ImplicitSystem(model, self.caches) if model.coupled else None
        if self.system is not None:
            self.linear_solver.bind(self.system.size)

    def prepare(self, model, state, xi, vi, ta, t, h) -> None:
        if self.system is None:
            return
        self._assemble(model, self.system, xi, vi, t + h, h)
        floor = self.linear_solver.tol * h * 9.81 * self.system.mass_norm
        self.last_solve = self.linear_solver.solve(self.system, atol=floor)

    @ti.kernel
    def _assemble(
        self,
        model: ti.template(),
        system: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        t: float,
        h: float,
    ):
        system.linearize(xi, vi, t, h)
        ti.loop_config(serialize=model.serial)
        for i in range(model.particle_count):
            system.assemble_row(i, xi, vi, t, h)

    @ti.func
    def final_pass(self, model: ti.template(), xi: ti.template(), vi: ti.template(), t, h):
        pass  # the linearisation was done in prepare()

    @ti.func
    def update(self, model: ti.template(), i, x0, v0, t, h):
        v1 = v0
        if ti.static(model.coupled):
            v1 = v0 + self.system.solution[i]
        elif model.inv_mass(i) > 0.0:  # a pinned particle (mass 0) keeps its velocity
            # Pointwise terms only: a 3x3 system per particle, solved directly.
            f = model.force(i, x0, v0, t + h)
            kx, kv = model.force_jacobian(i, x0, v0, t + h)
            a = model.mass(i) * ti.Matrix.identity(float, 3) - h * kv - h * h * kx
            v1 = v0 + a.inverse() @ (h * (f + h * (kx @ v0)))
        return x0 + h * v1, v1
