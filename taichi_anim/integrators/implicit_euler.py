"""Implicit (backward) Euler for cloth, Baraff & Witkin, "Large Steps in Cloth Simulation" (1998).

Backward Euler is the nonlinear system (ibid., eq. 4)
    g(v1) = M (v1 - v0) - h f(x0 + h v1, v1) = 0,   x1 = x0 + h v1.
The default (newton_iterations=1) is Baraff & Witkin's single linearised step (eq. 6):
    (M - h df/dv - h^2 df/dx) dv = h (f0 + h df/dx v0),   v1 = v0 + dv,
exact for forces linear in (x, v). For stiff springs at large steps the linearisation error shows: a
rotating spring lengthens by ~(h v)^2 / 2L and stores energy, so the step can gain energy.

newton_iterations > 1 solves eq. 4 by Newton's method: iteration k linearises at the iterate v_k
(x_k = x0 + h v_k) and solves A_k d = -g(v_k) with the same matrix-free system and linear solver (the
element terms' Hessians are kept positive semi-definite, so A_k is SPD and d a descent direction).
line_search=True takes v_{k+1} = v_k + alpha d with the largest alpha in 1, 1/2, 1/4, ... that gives
sufficient decrease of the merit function phi(v) = |g(v)|^2_{M^-1} / 2 (Nocedal & Wright, "Numerical
Optimization", 2nd ed., sec. 11.2 and Algorithm 3.1: backtracking with the Armijo condition
|g(v_k + alpha d)| <= (1 - c alpha) |g(v_k)|, c = 1e-4); Gast & Schroeder ("Optimization Integrator for
Large Time Steps", SCA 2014 / TVCG 2015) make the same globalisation of Newton on the backward-Euler
step, with an energy as the merit function. The iteration stops when |g|_{M^-1} <= newton_tol times its
value at v0 (or the absolute floor newton_tol h g sqrt(sum m)); a loop that ends at its cap is reported
to the run's Health as non-convergence, as is every linear solve that ends at max_iterations.
Two limits, measured (benchmarks/results/cloth_newton.md): where springs are compressed their Hessian is
projected (axial part only), so convergence is linear there and a newton_tol much below 1e-3 stalls
(default 1e-2, reached in 2-5 iterations on stiff cloth at dt = 1/60 s); and the merit is the residual,
not an energy, so an energy decrease is observed (stiff cloth at dt = 1/60 s), not guaranteed.

Pointwise terms alone give a block-diagonal system, solved directly per particle (3x3; the pointwise
terms are linear, so one step is exact). With element terms (springs, membrane, bending, aerodynamics) the
system couples particles and is solved matrix-free (implicit_system.py) by block Jacobi, CG or
block-Jacobi-preconditioned CG (linalg/).
"""

import math

import numpy as np
import taichi as ti

from .. import validate
from ..linalg import LinearSolver, LinearSolverKind, make_linear_solver
from ..runtime import compile_with, data_oriented
from ..stability import StabilityRegion
from .base import Integrator
from .implicit_system import ImplicitSystem

GRAVITY = 9.81  # [m/s^2], the scale of the solvers' absolute floors
ARMIJO = 1e-4  # sufficient-decrease constant c of the line search


@data_oriented
class IntegratorImplicitEuler(Integrator):
    """Backward Euler, by default linearised once per step (Baraff & Witkin); unconditionally stable on
    linear damped oscillators.

    linear_solver: "pcg" (default), "cg" or "jacobi" (or a LinearSolver), used when the model has
    springs; tol: relative residual |b - A dv| / |b|; max_iterations per solve; warm_start: start each
    step's first solve from the previous step's dv. `last_solve` holds the last solve's iterations and
    residual. A solve also stops once |b - A dv| <= tol h g |m| (g = 9.81 m/s^2, |m| the 2-norm of the
    masses): tol times the impulse gravity gives the particles in one step, so a cloth at rest, whose b
    is round-off, does not iterate to the cap on it. A solve that ends at max_iterations above both
    bounds is counted ("linear_unconverged") and reported under the policy's `nonconvergence`.

    newton_iterations: Newton iterations per step on the nonlinear backward-Euler system (1: the
    linearised step); newton_tol: relative reduction of the residual |g|_{M^-1} that ends the loop;
    line_search: backtrack on the residual norm (max_backtracks halvings) so no iteration increases it.
    `last_newton` holds (iterations, relative residual, converged) of the last step's loop.
    """

    name = "implicit_euler"
    stability_region = StabilityRegion.unconditional()  # A-stable
    rigid_scheme = "semi_implicit"  # bodies: kick, then drift and turn (no linearised system of theirs)
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
        newton_iterations: int = 1,
        newton_tol: float = 1e-2,
        line_search: bool = False,
        max_backtracks: int = 8,
        **options,
    ):
        super().__init__(**options)
        if isinstance(linear_solver, LinearSolver):
            self.linear_solver = linear_solver
        else:
            self.linear_solver = make_linear_solver(
                linear_solver, tol=tol, max_iterations=max_iterations, warm_start=warm_start
            )
        self.newton_iterations = validate.count("newton_iterations", newton_iterations, 1)
        self.newton_tol = validate.positive("newton_tol", newton_tol)
        self.line_search = bool(line_search)
        self.max_backtracks = validate.count("max_backtracks", max_backtracks, 0)
        self.system = None
        self.last_solve = None
        self.last_newton = None
        self.merit = None  # 0-d: the line search's merit (made by _allocate)
        self._step = None

    @property
    def newton(self) -> bool:
        """Whether steps solve the backward-Euler equations by Newton (newton_iterations > 1)."""
        return self.newton_iterations > 1

    def settings(self) -> dict:
        """The options, the linear solver's settings and, with Newton, its iteration settings."""
        out = {**super().settings(), **self.linear_solver.settings()}
        if self.newton:
            out.update(
                newton_iterations=self.newton_iterations,
                newton_tol=self.newton_tol,
                line_search=self.line_search,
            )
        return out

    def _allocate(self, model) -> None:
        self.merit = model.new_field(self, "newton_merit", float, ())
        self.system = ImplicitSystem(model, self.caches) if model.coupled else None
        if self.system is not None:
            self.linear_solver.bind(self.system.size, self.system.capacity, model.new_field)
            if self.newton:
                vec = model.particle_array
                self.dv = vec(self, "newton_dv", dims=(3,))  # v_k - v0 of the current iterate
                self.xt = vec(self, "newton_xt", dims=(3,))  # the iterate or trial point (x, v)
                self.vt = vec(self, "newton_vt", dims=(3,))
                self.mass_root = math.sqrt(float(np.sum(model.particle_masses())))

    def run_carry(self) -> dict:
        # The last solve's velocity change: where the next solve starts (warm_start).
        return {} if self.system is None else {"warm": self.system.solution.to_numpy()}

    def set_run_carry(self, carry: dict | None) -> None:
        if self.system is None:
            return
        if carry is None:
            self.system.solution.fill(0.0)
        else:
            self.system.solution.from_numpy(carry["warm"])

    def advance(self, model, state, xi, vi, xo, vo, ta, t, h, step, finish) -> None:
        """Integrator.advance, remembering the step number for the solve's reports."""
        self._step = step  # for the reports of prepare()
        super().advance(model, state, xi, vi, xo, vo, ta, t, h, step, finish)

    # ---- the solves

    def prepare(self, model, state, xi, vi, ta, t, h) -> None:
        if self.system is None:
            return
        self._assemble(model, self.system, xi, vi, t + h, h, self.newton)
        self._solve(h)
        if self.newton:
            self._newton(model, xi, vi, t + h, h)

    def _solve(self, h: float, atol: float = 0.0):
        """One linear solve, counted and reported; the solver has already read its result (one sync)."""
        floor = max(self.linear_solver.tol * h * GRAVITY * self.system.mass_norm, atol)
        res = self.last_solve = self.linear_solver.solve(self.system, atol=floor)
        health = self.health
        health.count("linear_solves")
        health.count("linear_iterations", res.iterations)
        if not res.converged:
            health.report(
                "linear_unconverged",
                self._step,
                f"{self.name}: the {self.linear_solver.name} solve stopped at its cap of "
                f"{self.linear_solver.max_iterations} iterations at step {self._step} with relative "
                f"residual {res.residual:.3g} > tol {self.linear_solver.tol:g}; raise max_iterations, "
                "lower dt or the stiffness",
                "nonconvergence",
                iterations=res.iterations,
                residual=res.residual,
            )
        return res

    def _newton(self, model, xi, vi, t: float, h: float) -> None:
        """Iterations 1.. of Newton on eq. 4 after the first (linearised) solve, which left its
        direction in system.solution with dv = 0."""
        system = self.system
        # Inexact Newton (Eisenstat & Walker's forcing terms, in their simplest form): a correction needs
        # no more accuracy than the loop's own goal, a fraction of the first right-hand side.
        atol = 0.5 * self.newton_tol * self.last_solve.rhs_norm
        phi0 = self._merit(model, system, xi, vi, 0.0, t, h)  # |g(v0)|^2 / 2
        floor = self.newton_tol * h * GRAVITY * self.mass_root
        target = max(self.newton_tol * math.sqrt(2.0 * phi0), floor)
        phi = phi0
        iterations = 0
        while True:
            iterations += 1
            alpha, phi = self._search(model, xi, vi, t, h, phi, first=iterations == 1)
            done = math.sqrt(2.0 * phi) <= target
            if done or iterations >= self.newton_iterations or alpha == 0.0:
                break  # alpha = 0: no step along d decreases |g|, and a new d would be the same
            self._newton_assemble(model, system, xi, vi, alpha, t, h)
            self._solve(h, atol)
        self._newton_finish(system, alpha)
        rel = math.sqrt(phi / phi0) if phi0 > 0.0 else 0.0
        self.last_newton = (iterations, rel, done)
        health = self.health
        health.count("newton_solves")
        health.count("newton_iterations", iterations)
        if not done:
            health.report(
                "newton_unconverged",
                self._step,
                f"{self.name}: Newton stopped at its cap of {self.newton_iterations} iterations at step "
                f"{self._step} with residual {rel:.3g} of its start > newton_tol {self.newton_tol:g}",
                "nonconvergence",
                iterations=iterations,
                residual=rel,
            )

    def _search(self, model, xi, vi, t, h, phi, first):
        """The step length along the last solve's direction and the merit there: 1 without line
        search; else the first of 1, 1/2, ... with sufficient decrease, or the best one tried (never 0
        on the first iteration, which must at least take the linearised step's direction)."""
        alpha = 1.0
        trial = self._merit(model, self.system, xi, vi, alpha, t, h)
        if not self.line_search:
            return alpha, trial
        best = (trial, alpha) if first else min((phi, 0.0), (trial, alpha))
        for _ in range(self.max_backtracks):
            if trial <= (1.0 - ARMIJO * alpha) ** 2 * phi:
                return alpha, trial
            alpha *= 0.5
            trial = self._merit(model, self.system, xi, vi, alpha, t, h)
            best = min(best, (trial, alpha))
        if trial <= (1.0 - ARMIJO * alpha) ** 2 * phi:
            return alpha, trial
        self.health.count("line_search_failed")
        return best[1], best[0]

    def _merit(self, model, system, xi, vi, alpha: float, t: float, h: float) -> float:
        self._residual(model, system, xi, vi, alpha, t, h)
        return float(self.merit[None])  # one scalar read per trial point

    # Every term's linearisation loops and the row assembly in one kernel: without Taichi's CFG passes
    # the flag compiles 7.7 s faster cold (19.5 -> 11.8 s). Turning off all advanced passes saved 9.6 s
    # but cost 1.5-2 % per frame on the flag and moving_mesh.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _assemble(
        self,
        model: ti.template(),
        system: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        t: float,
        h: float,
        newton: ti.template(),
    ):
        system.linearize(xi, vi, t, h)
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            system.assemble_row(i, xi, vi, t, h)
            if ti.static(newton):
                self.dv[i] = ti.Vector.zero(float, 3)

    # As _assemble: the same passes cost compile time only.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _newton_assemble(
        self,
        model: ti.template(),
        system: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        alpha: float,
        t: float,
        h: float,
    ):
        # Take the accepted step, then linearise at the new iterate; its increment starts from 0.
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            d = self.dv[i] + alpha * system.solution[i]
            self.dv[i] = d
            self.vt[i] = vi[i] + d
            self.xt[i] = xi[i] + h * (vi[i] + d)
            system.solution[i] = ti.Vector.zero(float, 3)
        system.linearize(self.xt, self.vt, t, h)
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            system.assemble_row_newton(i, self.xt, self.vt, self.dv, t, h)

    @ti.kernel
    def _newton_finish(self, system: ti.template(), alpha: float):
        # The step's total dv where update() reads it (and the next step's first solve starts from it).
        for i in range(system.model.live_particles()):
            system.solution[i] = self.dv[i] + alpha * system.solution[i]

    @ti.kernel
    def _residual(
        self,
        model: ti.template(),
        system: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        alpha: float,
        t: float,
        h: float,
    ):
        """merit = |g(v)|^2_{M^-1} / 2 at v = v0 + dv + alpha d (free particles; pinned ones keep v0)."""
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            v = vi[i] + self.dv[i] + alpha * system.solution[i]
            self.vt[i] = v
            self.xt[i] = xi[i] + h * v
        model.element_pass(self.caches, self.xt, self.vt, t)
        self.merit[None] = 0.0
        ti.loop_config(serialize=True)  # a fixed summation order: the same bits at any thread count
        for i in range(model.live_particles()):
            w = model.inv_mass(i)
            if w > 0.0:
                v = self.vt[i]
                f = model.force(i, self.xt[i], v, t) + model.element_force(self.caches, i)
                g = (v - vi[i]) / w - h * f
                self.merit[None] += 0.5 * w * g.dot(g)

    @ti.func
    def final_pass(self, model: ti.template(), xi: ti.template(), vi: ti.template(), t, h):
        pass  # the linearisation was done in prepare()

    @ti.func
    def update(self, model: ti.template(), i, x0, v0, t, h):
        """(x1, v1) of particle i after the solve: v1 = v0 + dv, x1 = x0 + h v1 (Baraff & Witkin eq. 6)."""
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
