"""Position-based fluids (Macklin & Müller, "Position Based Fluids", SIGGRAPH 2013): the liquid's other
solver (add_fluid(method="pbf")), on the same neighbourhoods, walls, bodies, viscosity and report as
divergence-free SPH (dfsph.py), whose solver class this one extends.

Each substep of h: the method's velocities v* (with gravity), XSPH, then predicted positions
p_i = x_i + h v*_i, and until the mean density error is below the tolerance (at least min_iterations,
at most max_iterations), a Jacobi pass of the density constraints C_i = rho_i / rho0 - 1 at p (eq. 1):

    rho_i(p) = m W(0) + sum_j m W(p_i - p_j) + sum_b psi_b [W(x_i - x_b) + grad W_ib.(p_i - x_i - h v_b)]
    lambda_i = -max(C_i, 0) / (|grad_i C_i|^2 + sum_j |grad_j C_i|^2)                         (eq. 9-11)
    dp_i = (1 / rho0) [sum_j m (lambda_i + lambda_j) grad W(p_i - p_j) + lambda_i sum_b psi_b grad W_ib]
                                                                                               (eq. 12)

with the fluid pairs' kernels evaluated at p every iteration (the neighbour lists are the substep
start's, as the CFL condition keeps particles within 0.4 spacings) and the boundary samples' terms
linearised about the substep's start (Akinci's samples, as in dfsph.py, moving with their bodies).
Then v = (p - x) / h and x = p, with the colliders' guard. Choices: the constraint only pushes apart
(C clamped at 0, as the DFSPH solves) instead of Macklin's artificial pressure s_corr against the
tensile instability, no relaxation epsilon (the denominator is 0 only for a particle alone, which
then does not move), no vorticity confinement; the pressure reported is -sum lambda_i / h^2 rho_i^2 /
rho0, the position correction's pressure equivalent. A pair's corrections are equal and opposite, and
each boundary sample's goes back to its body as an impulse, so momentum is conserved and exchanged."""

import taichi as ti

from ... import workers
from ...runtime import compile_with, data_oriented
from .dfsph import FluidDynamics
from .pressure import ERROR_SCALE, first_sum_above
from .sph_kernel import cubic_w, cubic_w_grad


@data_oriented
class PositionBasedFluid(FluidDynamics):
    """The liquid's position-based solver (module docstring)."""

    divergence_solve = False
    mirrors_wall_pressure = False  # its walls push with the particle's own lambda (wall_pressure.py)

    def __init__(self, model, **options):
        super().__init__(model, **options)
        n = model.fluid_capacity
        self.px = model.new_field(self, "fluid_px", float, n, (3,))  # predicted positions, by slot
        self.px2 = model.new_field(self, "fluid_px2", float, n, (3,))
        self.lam = model.new_field(self, "fluid_lambda", float, n)
        # The boundary samples' share of each density at the substep's start, with the moving samples'
        # own motion over the step: constant through the solve, so made once (_predict_positions).
        self.rho_b = model.new_field(self, "fluid_rho_boundary", float, n)

    def _divergence_step(self, h: float, state) -> tuple[int, float]:
        return 0, 0.0  # position-based fluids have no divergence solve

    def _density_step(self, h: float, state) -> tuple[int, float, float]:
        """Predict, iterate the constraints to the tolerance, and velocities from the corrections."""
        n = int(self.grid.size[None]) if self.emitted else self.model.fluid_count
        if n == 0:
            return 0, 0.0, 0.0
        if self.coupled:
            self.bodies.move(self.model, state)
        if self.workers:  # the whole step in one launch (worker_solve.py)
            above = first_sum_above(self.tolerance, n)
            out = self._density_by_workers(state, h, above, self.min_iterations, self.max_iterations)
            it, mean = int(out[0]), int(out[1]) / ERROR_SCALE / n
        else:
            self._predict_positions(h)
            mean = self._constraints(h) / ERROR_SCALE / n  # launches return the errors' sum (pressure.py)
            it = 0
            while it < self.max_iterations and (mean > self.tolerance or it < self.min_iterations):
                mean = self._project_and_constrain(h) / ERROR_SCALE / n
                it += 1
            self._velocities(h)
        if self.coupled:
            self._push_bodies(self.model, state, h)
        return it, mean, float(self.err_max[None])

    @ti.kernel
    def _predict_positions(self, h: float):
        self._predict_positions_pass(h)

    @ti.kernel
    def _velocities(self, h: float):
        self._velocities_pass(h)

    @ti.func
    def _density_pass(self, state: ti.template(), h, above, least, most):
        """The density step inside a serial loop of the calling kernel (serial_substep.py; the state is not
        read): prediction, constraints, projections while the errors' sum is at least `above` or fewer
        than `least` were made (at most `most`), velocities; returns the iterations."""
        self._predict_positions_pass(h)
        it = -1  # -1: the constraints at the predicted positions (one copy: pressure.py's _solve_pass)
        while it < 0 or (it < most and (self.err_sum[None] >= above or it < least)):
            if it >= 0:
                self._project(h)
            self._constraint_pass(h)
            it += 1
        self._velocities_pass(h)
        return it

    @ti.func
    def _predict_positions_pass(self, h):
        w0 = cubic_w(0.0, self.support)
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._predict_position_one(k, h, w0)

    @ti.func
    def _predict_position_one(self, k, h, w0):
        """Slot k's predicted position and the boundary's share of its density (rho_b)."""
        self.px[k] = self.grid.sorted_x[k] + h * self.sv[k]
        self.kacc[k] = 0.0
        fluid = w0
        for m in range(self.nn[k]):
            fluid += self.weight[k, m]
        rho = self.rho[k] - self.mass * fluid
        if ti.static(self.coupled):
            for m in range(self.body_n[k]):
                rho -= h * self.body_grad[k, m].dot(self.bodies.v[self.body_nbr[k, m]])
        self.rho_b[k] = rho

    @ti.kernel
    def _constraints(self, h: float) -> ti.i64:
        """The constraints at the predicted positions (_constraint_pass); returns the errors' sum."""
        self._constraint_pass(h)
        return self.err_sum[None]

    @ti.kernel
    def _project_and_constrain(self, h: float) -> ti.i64:
        """One Jacobi projection, then the constraints at the moved positions; returns the errors' sum.
        (Not named _iterate: the DFSPH solves' _iterate takes other arguments.)"""
        self._project(h)
        self._constraint_pass(h)
        return self.err_sum[None]

    @ti.func
    def _constraint_pass(self, h):
        """lambda_k at the predicted positions, and the clamped errors' fixed-point sum and max. The
        pairs' m grad W at p go into the lists (`grad`, the substep start's until now: the DFSPH solves
        and the surface tension are done with them), for _project at the same positions."""
        self.err_sum[None] = 0
        self.err_max[None] = 0.0
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            c = self._constraint_one(k)
            ti.atomic_add(self.err_sum[None], ti.cast(c * ERROR_SCALE + 0.5, ti.i64))
            ti.atomic_max(self.err_max[None], c)

    @ti.func
    def _constraint_one(self, k):
        """Slot k's lambda at the predicted positions (its pairs' m grad W listed); returns its error."""
        p = self.px[k]
        # The boundary's share linearised in the particle's motion.
        rho = self.rho_b[k] + self.wall_grad[k].dot(p - self.grid.sorted_x[k])
        rho += self.mass * cubic_w(0.0, self.support)
        g = self.wall_grad[k]
        sq = ti.cast(0.0, float)
        for m in range(self.nn[k]):
            w, gr = cubic_w_grad(p - self.px[self.nbr[k, m]], self.support)
            rho += self.mass * w
            gr *= self.mass
            self.grad[k, m] = gr
            g += gr
            sq += gr.dot(gr)
        c = ti.max(rho / self.rest_density - 1.0, 0.0)
        den = g.dot(g) + sq
        self.lam[k] = -c * self.rest_density * self.rest_density / den if den > 0.0 else 0.0
        return c

    @ti.func
    def _project(self, h):
        """p_k += dp_k (Jacobi: every correction from the same lambdas, with the gradients _constraints
        listed at these positions); kacc sums the corrections' pressure equivalent for the bodies'
        impulses and the report."""
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._project_one(k, h)
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self.px[k] = self.px2[k]

    @ti.func
    def _project_one(self, k, h):
        """Slot k's projected position into px2, and its pressure equivalent summed."""
        lk = self.lam[k]
        dp = lk * self.wall_grad[k]
        for m in range(self.nn[k]):
            dp += (lk + self.lam[self.nbr[k, m]]) * self.grad[k, m]
        self.px2[k] = self.px[k] + dp / self.rest_density
        # dv = dp / h = -h kappa grad (dfsph.py's form): kappa = -lambda / (rho0 h^2)
        self.kacc[k] -= lk / (self.rest_density * h * h)

    # Passes of the workers' density step (worker_solve.py): predict, constrain (its errors), project,
    # copy the projection, velocities.
    PREDICT, CONSTRAIN, PROJECT, COPY, VELOCITIES = 10, 11, 12, 13, 14
    error_kinds = (CONSTRAIN,)

    @ti.func
    def _slot(self, kind: ti.template(), state: ti.template(), k, h, divergence):
        e = ti.cast(0.0, float)
        if ti.static(kind == self.PREDICT):
            self._predict_position_one(k, h, cubic_w(0.0, self.support))
        elif ti.static(kind == self.CONSTRAIN):
            e = self._constraint_one(k)
        elif ti.static(kind == self.PROJECT):
            self._project_one(k, h)
        elif ti.static(kind == self.COPY):
            self.px[k] = self.px2[k]
        else:
            self._velocity_one(k, h)
        return e

    # Without Taichi's CFG passes, as the DFSPH workers' solve.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _density_by_workers(
        self, state: ti.template(), h: float, above: ti.i64, least: ti.i32, most: ti.i32
    ) -> ti.types.vector(2, ti.i64):
        """_density_step's passes in one launch of workers (worker_solve.py): predict, constrain, then
        project, copy and constrain while the errors' sum is at least `above` or fewer than `least`
        iterations were made (at most `most`), then the velocities. Returns (iterations, the last
        errors' fixed-point sum); err_sum and err_max hold the last constraints'."""
        self._reset_passes()
        n = self._live()
        for task in range(self.worker_items):
            if workers.is_worker(task):
                self._density_in_worker(task, state, h, 0, n, above, least, most)
        self._report_pass()
        return ti.Vector([self.solve_out[0], self.solve_out[1]], dt=ti.i64)

    @ti.func
    def _density_in_worker(self, task, state: ti.template(), h, divergence, n, above, least, most):
        """One worker's part of the density step (the passes' counters from 0, reset before the workers
        start); the first worker writes solve_out. `divergence` is unused (the DFSPH solve's signature,
        worker_substep.py calls either)."""
        self._pass(0, self.PREDICT, state, h, 0, n)
        self._pass(1, self.CONSTRAIN, state, h, 0, n)
        q, it = 1, 0
        s = self.pass_sum[1]
        while it < most and (s >= above or it < least):
            self._pass(q + 1, self.PROJECT, state, h, 0, n)
            self._pass(q + 2, self.COPY, state, h, 0, n)
            self._pass(q + 3, self.CONSTRAIN, state, h, 0, n)
            q += 3
            it += 1
            s = self.pass_sum[q]
        self._pass(q + 1, self.VELOCITIES, state, h, 0, n)
        if task == 0:
            self.solve_out[0] = it
            self.solve_out[1] = s
            self.solve_out[2] = q

    @ti.func
    def _velocities_pass(self, h):
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._velocity_one(k, h)

    @ti.func
    def _velocity_one(self, k, h):
        self.sv[k] = (self.px[k] - self.grid.sorted_x[k]) / h
