"""Divergence-free SPH (Bender & Koschier, "Divergence-Free Smoothed Particle Hydrodynamics", SCA 2015,
and "Divergence-Free SPH for Incompressible and Viscous Fluids", TVCG 2017): the liquid's solver in the
Stepper's list.

Each substep of h, with the neighbourhoods, densities rho_i and factors alpha_i of its start (eq. 8 of
the 2017 paper, with Akinci's boundary samples b: boundary.py)

    alpha_i = 1 / ( |sum_j m_j grad W_ij + sum_b psi_b grad W_ib|^2 + sum_j |m_j grad W_ij|^2 ),

1. before the method moves the particles: the divergence solve (alg. 2) makes the velocities
   divergence-free: Drho_i/Dt = sum_j m_j (v_i - v_j).grad W_ij + sum_b psi_b v_i.grad W_ib, clamped to
   compression, gives kappa^v_i = (Drho_i/Dt) alpha_i / h, and every iteration applies
   v_i -= h [ sum_j m_j (kappa_i + kappa_j) grad W_ij + sum_b psi_b kappa_i grad W_ib ]   (eq. 11, 12;
   a liquid without bodies pushes off the walls' samples with 2 kappa_i: wall_pressure.py)
   until the mean of h Drho/Dt / rho0 is below the divergence tolerance;
2. the method adds the non-pressure forces (gravity, ...) to the velocities (v*), and the solver adds
   XSPH viscosity (Monaghan, "On the problem of penetration in particle methods", JCP 1989, eq. 2.9,
   with the pair's mean density), then surface tension if asked (surface_tension.py);
3. after it: the density solve (alg. 3) corrects v* until the predicted density
   rho*_i = rho_i + h Drho_i/Dt, clamped to compression, is within the tolerance of rho0 on average,
   with kappa_i = (rho*_i - rho0) alpha_i / h^2 and the same velocity update;
4. x = x(start) + h v, then every collider's surface as a last guard against leaks, and the particles
   are written back.

The kappa_i summed over a solve's iterations is p_i / rho_i^2 (the symmetric SPH pressure force of
eq. 12 is -m_i sum_j m_j (p_i/rho_i^2 + p_j/rho_j^2) grad W_ij), so the state reports each particle's
pressure p_i; the next step starts from it (warm start, sec. 4 of the 2015 paper). Pairs act equally and
oppositely (equal masses, antisymmetric gradients), so the solves conserve momentum.

Work runs in the neighbour grid's slot order (cell by cell): each particle's neighbours are listed once
per substep, and the iterations walk the lists over contiguous memory. The convergence test sums
errors as 2^-40 fixed-point integers, whose atomic sum does not depend on thread timing: a run gives the
same iterations and bits at any thread count."""

import math

import numpy as np
import taichi as ti

from ... import bulk, capacity
from ...collision.neighbors import NeighborGrid
from ...runtime import backend_name, compile_with, data_oriented, np_float
from ..rigid.dynamics import body_acceleration
from ..rigid.narrow_phase import body_sdf
from ..rigid.quaternion import quat_matrix, world_inverse_inertia
from . import surface_tension
from .bodies import BodySamples, sphere_particles
from .boundary import boundary_samples
from .pressure import ERROR_SCALE, PressureSolves, first_sum_above
from .report import FluidReport
from .serial_substep import SerialSubstep
from .sph_kernel import cubic_w, cubic_w_grad, lattice_sum
from .wall_pressure import WallPressure
from .worker_solve import WorkerSolve
from .worker_substep import WorkerSubstep
from .xsph import XsphViscosity

FLUID_NEIGHBORS = 64  # listed fluid neighbours per particle (26 at rest; a compressed splash ~45)
BODY_NEIGHBORS = 64  # listed samples of rigid bodies per particle (~13 at a face, ~40 at a corner)
# Fewer liquid particles: the solves' loops run serially (see __init__). The dam_break demo's frames of
# 1/30 s, serial against parallel loops: 33 against 57 ms at 1,024 particles, 77 against 91 at 2,000,
# 137 against 111 at 3,456 (benchmarks/fluid_realtime.py's scene).
FLUID_SERIAL_BELOW = 3000


@data_oriented
class FluidDynamics(
    PressureSolves, SerialSubstep, WorkerSolve, WorkerSubstep, XsphViscosity, WallPressure, FluidReport
):
    """The liquid's pressure solver (module docstring); built by the Stepper from `model.fluid`."""

    name = "fluid"
    # A small liquid's (serial) substep runs in two launches, its solves inside them (serial_substep.py);
    # False: a launch per pass and per iteration (tests compare the two).
    one_launch_solve = True
    divergence_solve = True  # PBF has none

    def __init__(self, model, *, spacing, density, method, tolerance, divergence_tolerance, min_iterations,
                 max_iterations, viscosity, cfl, max_step, max_substeps, domain, mass,
                 surface_tension=0.0):  # fmt: skip
        self.model = model
        self.method = method
        self.tolerance = float(tolerance)
        self.divergence_tolerance = float(divergence_tolerance)
        self.min_iterations, self.max_iterations = int(min_iterations), int(max_iterations)
        self.viscosity, self.cfl, self.max_substeps = float(viscosity), float(cfl), int(max_substeps)
        self.surface_tension = float(surface_tension)
        self.max_step = float(max_step)
        self.spacing, self.rest_density, self.mass = float(spacing), float(density), float(mass)
        self.support = model.fluid_support
        self.domain = (np.asarray(domain[0], dtype=np.float64), np.asarray(domain[1], dtype=np.float64))
        self.gravity = float(np.linalg.norm(body_acceleration(model)))  # |g| of the terms acting on all
        n = model.fluid_capacity  # rows per liquid particle: its count, or its bucket (capacity.py)
        # A small liquid's loops run serially: a parallel loop costs ~0.2 ms to start on this CPU
        # against ~0.03 ms for a serial one, more than a small liquid's work per loop. That includes
        # the neighbourhoods pass, the heaviest: serial, the dam break's step took 0.75 against 0.86 ms
        # at 128 particles, 1.2 against 1.7 at 432, 1.9 against 2.3 at 1,024, the same at 2,000-2,662
        # (2-core Xeon). Under buckets the bucket decides, so that every count in it compiles the same
        # kernels.
        self.serial = backend_name() == "cpu" and n < FLUID_SERIAL_BELOW
        make = model.new_field
        grow = (self.domain[0] - self.support, self.domain[1] + self.support)
        # Cells of half the support, 5^3 of them searched (_near): at rest 125 candidates against 216 in
        # 3^3 cells of the support. On the benchmark's 6,859 particles (benchmarks/fluid_dam_break.py)
        # the neighbourhood pass took 2.1-3.7 ms against 3.3-4.0 (medians of runs that spread by 30 %),
        # the grid's build 0.3 ms more (it clears and scans every cell, serially).
        self.grid = NeighborGrid(n, 0.5 * self.support, domain=grow, make=make)
        # Akinci's psi_b = rho0 V_b makes a flat layer worth 1.43 lattice layers at H = 2 spacings (it
        # stands for the missing deeper layers), which packs a block filled up to a wall 6 % above rest
        # density at its first layer. Scaled by one layer's share of the lattice sum, a flat wall
        # sampled at the liquid's spacing is exactly the lattice continued: the block starts at rest.
        plane = lattice_sum(self.spacing, self.support, 2)
        self.layer_share = plane / lattice_sum(self.spacing, self.support)
        samples = boundary_samples(model.colliders, self.domain, self.spacing, self.support)
        self.boundary_count = len(samples)
        self.walls = self.boundary_count > 0  # compile-time: kernels visit boundary samples only if any
        self.boundary = None
        bx = apart = apart_grid = None
        # The walls' samples and the bodies' arrays in one fill launch, then their grids and volumes in one
        # kernel (_setup): a from_numpy, grid build or volume pass is a kernel of its own to compile.
        with bulk.batch():
            if self.boundary_count:
                # Under buckets the samples' rows are a bucket too: a mesh collider of another size in its
                # buckets (mesh_collider.py) then compiles no kernel of the liquid's either.
                rows = capacity.bucket(self.boundary_count) if model.size_buckets else self.boundary_count
                self.boundary = NeighborGrid(rows, 0.5 * self.support, domain=grow, make=make)
                bx = make(self, "fluid_boundary_x", float, rows, (3,))
                bulk.fill([(bx, capacity.padded(samples, rows, np_float()))])
                self.boundary_psi = make(self, "fluid_boundary_psi", float, rows)
                # Per cell of the walls' grid: whether a sample lies in the 5^3 cells _near scans from it
                # (_volumes_pass marks them), so that a particle away from every wall skips that scan.
                self.wall_near = make(self, "fluid_wall_near", ti.i32, self.boundary.cell_count)
            # Rigid bodies and cloth in the liquid: samples on their surfaces, moving with them, and a grid
            # over them built every substep (bodies.py).
            self.coupled = (
                model.rigid_count > 0 or model.triangle_count > 0 or len(sphere_particles(model)) > 0
            )
            if self.coupled:
                self.bodies = BodySamples(model, self.spacing, make)
                # Each body's samples apart from the others' (its own volumes only), in one grid.
                apart, lo, hi = self.bodies.apart(self.support)
                apart_grid = NeighborGrid(self.bodies.count, 0.5 * self.support, domain=(lo, hi), make=make)
                self.body_grid = NeighborGrid(self.bodies.count, 0.5 * self.support, domain=grow, make=make)
        if self.walls or self.coupled:
            self._setup(bx, self.boundary_count, apart, self.bodies.count if self.coupled else 0, apart_grid)
        f = lambda role, dtype=float, dims=(), shape=n: make(self, role, dtype, shape, dims)  # noqa: E731
        self.cx, self.sv, self.sv2 = (f(f"fluid_{r}", dims=(3,)) for r in ("cx", "sv", "sv2"))
        self.rho, self.alpha, self.kappa, self.kacc = (f(f"fluid_{r}") for r in ("rho", "alpha", "k", "kacc"))
        self.nn, self.bn = f("fluid_nn", ti.i32), f("fluid_bn", ti.i32)
        self.nbr = f("fluid_nbr", ti.i32, shape=(n, FLUID_NEIGHBORS))
        # m grad W_kj of each listed pair, and sum_b psi_b grad W_kb: computed once per substep, read by
        # every iteration (a third fewer operations per iteration than evaluating the kernel there).
        self.grad = f("fluid_grad", dims=(3,), shape=(n, FLUID_NEIGHBORS))
        self.wall_grad = f("fluid_wall_grad", dims=(3,))
        self._make_wall_pressure(f)
        self.weight = f("fluid_weight", shape=(n, FLUID_NEIGHBORS))  # W_kj, for XSPH
        if self.coupled:  # each particle's body samples: index and psi_b grad W
            self.body_n = f("fluid_body_n", ti.i32)
            self.body_nbr = f("fluid_body_nbr", ti.i32, shape=(n, BODY_NEIGHBORS))
            self.body_grad = f("fluid_body_grad", dims=(3,), shape=(n, BODY_NEIGHBORS))
        # Nozzles (add_fluid_emitter) give liquid particles birth times: the solves run over the live ones.
        self.emitted = model.emitter_count > 0
        self._make_worker_substep()
        self._make_worker_solve(make)
        self.err_sum = f("fluid_err_sum", ti.i64, shape=())
        self.err_max = f("fluid_err_max", shape=())
        self.overflow = f("fluid_overflow", ti.i32, shape=())
        # The density error the positions reached: measured by the neighbourhood pass at each substep's
        # start (after the last substep's walls' guard, which the solves' predictions do not see), as
        # the largest mean and largest single error, over the frame (0, 1) and the run (2, 3).
        self.reached_sum = f("fluid_reached_sum", ti.i64, shape=())
        self.reached = f("fluid_reached", dims=(4,), shape=())
        self.speed = f("fluid_speed", shape=())
        if self.surface_tension > 0.0:
            self.normal = f("fluid_normal", dims=(3,))  # surface_tension.py's n_k, by slot
        if self.emitted:
            self.cdeath = f("fluid_cdeath")
        if self.serial and self.emitted:  # the solves' thresholds per live count (serial_substep.py)
            self.sum_above = f("fluid_sum_above", ti.i64, shape=(2, n + 1))
            self._thresholds_for = None
        vec = ti.types.vector(3, float)  # made after ti.init: `float` is the chosen precision
        self._sums = ti.types.struct(
            n=ti.i32, bn=ti.i32, mb=ti.i32, rho=float, g=vec, sq=float, wg=vec, ww=vec, wh=vec, bg=vec
        )
        self._clear_counts(*body_acceleration(model))
        self.totals = dict(steps=0, density_iterations=0, divergence_iterations=0, unconverged_steps=0,
                           mean_error_max=0.0, max_error_max=0.0)  # fmt: skip
        self._frame: list[dict] = []
        self.last = {}

    # --- the protocol -------------------------------------------------------------------------

    def substeps(self, model, state, dt: float) -> int:
        """CFL: the fewest equal substeps h = dt / n in which no particle moves more than cfl spacings,
        h (v_max + g h) <= cfl d (Bender & Koschier 2017, eq. 13, with the speed gravity adds over the
        substep), none longer than max_step."""
        v, reach = float(self._max_speed(state, model)), self.cfl * self.spacing
        n = max(math.ceil(dt / self.max_step - 1e-9), 1)
        while n < self.max_substeps and (dt / n) * (v + self.gravity * dt / n) > reach:
            n += 1
        return n

    def before_substep(self, model, state, h: float) -> None:
        """Neighbourhoods, densities and factors at the substep's start; the divergence solve."""
        if self.worker_substep:  # the whole substep on the CPU's workers (worker_substep.py)
            n = model.fluid_count
            it, total, _ = (int(c) for c in self._begin_by_workers(
                state, model, n, float(state.time), h, first_sum_above(self.divergence_tolerance, n),
                min(self.min_iterations, 1), self.max_iterations,
            ))  # fmt: skip
            self.last = dict(divergence_iterations=it, divergence_error=total / ERROR_SCALE / n if n else 0.0)
            return
        if self._two_launch_substep():  # a small liquid: one launch (serial_substep.py)
            above = self._thresholds(model, self.divergence_tolerance)
            it, total, n = (int(c) for c in self._begin_serially(
                state, model, model.fluid_count, float(state.time), h, above, min(self.min_iterations, 1),
                self.max_iterations,
            ))  # fmt: skip
            mean = total / ERROR_SCALE / n if self.divergence_solve and n else 0.0
            self.last = dict(divergence_iterations=it, divergence_error=mean)
            return
        self._gather_positions(state, model)
        if self.emitted:  # the nozzles' unborn slots stay out of the grid, the solves run over its slots
            self.grid.build(self.cx, model.fluid_count, death=self.cdeath, t=float(state.time))
        else:
            self.grid.build(self.cx, model.fluid_count)
        if self.coupled:
            self.bodies.place(model, state)
            self.body_grid.build(self.bodies.x, self.bodies.count)
        self._neighborhoods(state, model)
        iterations, mean = self._divergence_step(h, state)
        self.last = dict(divergence_iterations=iterations, divergence_error=mean)

    def after_substep(self, model, state, h: float, step: int) -> None:
        """XSPH, the density solve, then positions from the corrected velocities."""
        if self.worker_substep:  # the whole substep on the CPU's workers (worker_substep.py)
            counts, worst = self._end_by_workers(
                state, model, h, float(state.time + h), self.viscosity,
                first_sum_above(self.tolerance, model.fluid_count), self.min_iterations, self.max_iterations,
            )  # fmt: skip
            iterations, total, n = (int(c) for c in counts)
            mean, worst = (total / ERROR_SCALE / n, float(worst)) if n else (0.0, 0.0)
        elif self._two_launch_substep():  # a small liquid: one launch (serial_substep.py)
            counts, worst = self._end_serially(
                state, model, h, float(state.time + h), self.viscosity, self.surface_tension,
                self._thresholds(model, self.tolerance), self.min_iterations, self.max_iterations,
            )  # fmt: skip
            iterations, total, n = (int(c) for c in counts)
            mean = total / ERROR_SCALE / n if n else 0.0
            worst = float(worst)
        else:
            self._gather_velocities(state, model, self.viscosity, h)
            if self.surface_tension > 0.0:
                self._surface_tension(h, self.surface_tension)
            iterations, mean, worst = self._density_step(h, state)
            self._finish(state, model, h, float(state.time + h))
        self.last.update(density_iterations=iterations, mean_density_error=mean, max_density_error=worst)
        t = self.totals
        t["steps"] += 1
        t["density_iterations"] += iterations
        t["divergence_iterations"] += self.last["divergence_iterations"]
        t["unconverged_steps"] += int(mean > self.tolerance)
        t["mean_error_max"] = max(t["mean_error_max"], mean)
        t["max_error_max"] = max(t["max_error_max"], worst)
        self._frame.append(dict(self.last))

    def check(self, state) -> None:
        """Nothing to roll back for: a solve that stops at max_iterations is counted (unconverged_steps)."""

    def settings(self) -> dict:
        """Options, for run.json."""
        return dict(
            method=self.method, tolerance=self.tolerance, divergence_tolerance=self.divergence_tolerance,
            min_iterations=self.min_iterations, max_iterations=self.max_iterations,
            viscosity=self.viscosity, surface_tension=self.surface_tension, cfl=self.cfl,
            max_step=self.max_step, max_substeps=self.max_substeps,
            boundary_particles=self.boundary_count, neighbor_search=self.grid.settings(),
            substep=self._substep_kind(),
        )  # fmt: skip

    def _substep_kind(self) -> str:
        """How a substep runs: "workers" (worker_substep.py), "serial" (two serial launches,
        serial_substep.py) or "launches" (a launch per pass, the solves on workers where they run)."""
        if self.worker_substep:
            return "workers"
        return "serial" if self._two_launch_substep() else "launches"

    @ti.func
    def _live(self):
        """The slots the solves run over: the live particles (the grid's count) with nozzles, else all
        (model.live_fluid(): a compile-time constant with exact sizes)."""
        n = self.model.live_fluid()
        if ti.static(self.emitted):
            n = self.grid.size[None]
        return n

    # --- gathering and scattering ----------------------------------------------------------------

    @ti.kernel
    def _max_speed(self, state: ti.template(), model: ti.template()) -> float:
        self.speed[None] = 0.0
        ti.loop_config(serialize=self.serial)
        for j in range(model.live_fluid()):  # unborn nozzle slots rest: their speed is 0
            ti.atomic_max(self.speed[None], state.particle_v[model.fluid_particle[j]].norm())
        return self.speed[None]

    # One launch: Python-scope writes are a writer kernel per field and per component (eight here), each
    # compiled with an empty cache (about 17 ms). g: the walls' hydrostatic pressure's (wall_pressure.py).
    @ti.kernel
    def _clear_counts(self, gx: float, gy: float, gz: float):
        self.overflow[None] = 0
        self.reached[None] = ti.Vector([0.0, 0.0, 0.0, 0.0], dt=float)
        self.body_g[None] = ti.Vector([gx, gy, gz], dt=float)

    @ti.kernel
    def _gather_positions(self, state: ti.template(), model: ti.template()):
        self._gather_positions_pass(state, model)

    @ti.func
    def _gather_positions_pass(self, state: ti.template(), model: ti.template()):
        ti.loop_config(serialize=self.serial)
        for j in range(model.live_fluid()):
            self._gather_position_one(state, model, j)

    @ti.func
    def _gather_position_one(self, state: ti.template(), model: ti.template(), j):
        p = model.fluid_particle[j]
        self.cx[j] = state.particle_x[p]
        if ti.static(self.emitted):
            self.cdeath[j] = state.particle_death[p]

    @ti.func
    def _near(self, grid: ti.template(), k, p, visit: ti.template(), acc: ti.template()):
        """visit(k, slot, p - x_slot, acc) for every slot of `grid` within the support of p: the 5 x 5
        columns of 5 cells around p's cell (NeighborGrid makes cells at least the half support given)."""
        grid.for_each_near(k, p, self.support, visit, acc)

    @ti.func
    def _list_fluid(self, k, kk, d, acc: ti.template()):
        """A candidate of slot k's scan: written at the list's end, which moves on only if it is a
        neighbour (within the support, not k itself). No branch on that test: about one candidate in
        five is a neighbour, and with the branch (and each neighbour's sums inside it) the scan and sums
        took 1.4x as long (6,859 particles, one thread); the listed neighbours' shares are summed after
        the scan (`_neighborhood_one`). A neighbour beyond the list's room is summed at once and counted
        as an overflow."""
        near = (d.norm_sqr() < self.support * self.support) & (kk != k)
        if acc.n < FLUID_NEIGHBORS:
            self.nbr[k, acc.n] = kk
        elif near:
            self._add_fluid(k, -1, d, acc)
            ti.atomic_add(self.overflow[None], 1)
        acc.n += ti.cast(near, ti.i32)

    @ti.func
    def _add_fluid(self, k, m, d, acc: ti.template()):
        """A fluid neighbour's share of the density and of alpha's sums; listed at m (m >= 0) with
        m grad W and W."""
        w, g = cubic_w_grad(d, self.support)
        g *= self.mass
        acc.rho += self.mass * w
        acc.g += g
        acc.sq += g.dot(g)
        if m >= 0:
            self.grad[k, m] = g
            self.weight[k, m] = w

    @ti.func
    def _add_body(self, k, slot, d, acc: ti.template()):
        """A body's sample: its share of the density and gradient sums, listed with psi_b grad W."""
        s = self.body_grid.sorted_id[slot]
        w, g = cubic_w_grad(d, self.support)
        psi = self.bodies.psi[s]
        acc.rho += psi * w
        acc.wg += psi * g
        if acc.mb < BODY_NEIGHBORS:
            self.body_nbr[k, acc.mb] = s
            self.body_grad[k, acc.mb] = psi * g
            acc.mb += 1
        else:
            ti.atomic_add(self.overflow[None], 1)

    @ti.kernel
    def _push_bodies(self, model: ti.template(), state: ti.template(), h: float):
        """Each pair's pressure correction of a particle, given back to the body at the sample:
        J = m_i h kappa_i psi_b grad W_ib (summed over the solve's iterations), in particle order."""
        self._push_bodies_pass(model, state, h)

    @ti.func
    def _push_bodies_pass(self, model: ti.template(), state: ti.template(), h):
        rigid = ti.static(self.bodies.has_rigid)
        if ti.static(rigid):
            ti.loop_config(serialize=True)
            for b in range(model.live_rigid()):
                self.bodies.impulse[b] = ti.Vector.zero(float, 3)
                self.bodies.moment[b] = ti.Vector.zero(float, 3)
        ti.loop_config(serialize=True)
        for k in range(self._live()):
            for m in range(self.body_n[k]):
                s = self.body_nbr[k, m]
                b = self.bodies.owner[s]
                j = (self.mass * h * self.kacc[k]) * self.body_grad[k, m]
                if b >= 0:
                    if ti.static(rigid):
                        self.bodies.impulse[b] += j
                        self.bodies.moment[b] += (self.bodies.x[s] - state.rigid_x[b]).cross(j)
                else:  # a point sample: to its particles by its weights (a cloth triangle, a sphere)
                    if ti.static(self.bodies.has_points):
                        for c in ti.static(range(3)):
                            i = self.bodies.corners[s][c]
                            state.particle_v[i] += (self.bodies.weights[s][c] * model.inv_mass(i)) * j
        if ti.static(rigid):
            ti.loop_config(serialize=True)
            for b in range(model.live_rigid()):
                if model.rigid_inv_mass[b] > 0.0:
                    r = quat_matrix(state.rigid_q[b])
                    state.rigid_v[b] += self.bodies.impulse[b] * model.rigid_inv_mass[b]
                    inv_inertia = world_inverse_inertia(r, model.rigid_inv_moments[b])
                    state.rigid_w[b] += inv_inertia @ self.bodies.moment[b]

    @ti.kernel
    def _neighborhoods(self, state: ti.template(), model: ti.template()):
        self._neighborhoods_pass(state, model)

    @ti.func
    def _neighborhoods_pass(self, state: ti.template(), model: ti.template()):
        """Each slot's neighbour list, density, factor alpha and velocity, in one pass over the cells;
        the density error these positions reached."""
        ti.loop_config(serialize=True)  # one iteration: a parallel loop would wake the thread pool
        for _ in range(1):
            self.reached_sum[None] = 0
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._neighborhood_one(state, model, k)
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._reached_mean()

    @ti.func
    def _neighborhood_one(self, state: ti.template(), model: ti.template(), k):
        """Slot k's neighbour list, density, factor alpha and velocity; its density error summed."""
        xi = self.grid.sorted_x[k]
        zero = ti.Vector.zero(float, 3)
        rho = self.mass * cubic_w(0.0, self.support)
        acc = self._sums(
            n=0, bn=0, mb=0, rho=rho, g=zero, sq=0.0, wg=zero, ww=zero, wh=zero, bg=self.body_g[None]
        )
        self.grid.for_each_in_columns(k, xi, self._list_fluid, acc)
        for m in range(ti.min(acc.n, FLUID_NEIGHBORS)):
            self._add_fluid(k, m, xi - self.grid.sorted_x[self.nbr[k, m]], acc)
        if ti.static(self.walls):
            if self.wall_near[self.boundary.key(self.boundary.coords(xi))]:
                self._near(self.boundary, k, xi, self._add_boundary, acc)
        if ti.static(self.coupled):
            self._near(self.body_grid, k, xi, self._add_body, acc)
            self.body_n[k] = acc.mb
        self.nn[k] = ti.min(acc.n, FLUID_NEIGHBORS)
        self.bn[k] = acc.bn + acc.mb  # every boundary sample, the walls' and the bodies'
        self.wall_grad[k] = acc.wg
        push = self._keep_wall_sums(k, acc)
        # The density's response to the particle's own stiffness: (G + W).(G + P) + sum |m grad W|^2, G
        # the fluid's gradient sum, W the samples', P the solves' push off them (2 W mirrored); the first
        # term, negative where the sums oppose, is taken as 0 there.
        own = acc.g + acc.wg
        den = ti.max(own.dot(acc.g + push), 0.0) + acc.sq
        self.rho[k] = acc.rho
        self.alpha[k] = 1.0 / den if den > 0.0 else 0.0
        self.sv[k] = state.particle_v[model.fluid_particle[self.grid.sorted_id[k]]]
        e = ti.max(acc.rho / self.rest_density - 1.0, 0.0)
        ti.atomic_add(self.reached_sum[None], ti.cast(e * ERROR_SCALE + 0.5, ti.i64))
        ti.atomic_max(self.reached[None][1], e)

    @ti.func
    def _reached_mean(self):
        """After the neighbourhoods: the mean density error they reached, into the frame's and run's."""
        n = self._live()
        if n > 0:
            mean = ti.cast(self.reached_sum[None], float) / ERROR_SCALE / n
            r = self.reached[None]
            self.reached[None][0] = ti.max(r[0], mean)
            self.reached[None][2] = ti.max(r[2], mean)
            self.reached[None][3] = ti.max(r[3], r[1])

    @ti.kernel
    def _write_velocities(self, state: ti.template(), model: ti.template(), h: float):
        self._write_velocities_pass(state, model, h)

    @ti.func
    def _write_velocities_pass(self, state: ti.template(), model: ti.template(), h):
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._write_velocity_one(state, model, k, h)

    @ti.func
    def _write_velocity_one(self, state: ti.template(), model: ti.template(), k, h):
        j = self.grid.sorted_id[k]
        state.particle_v[model.fluid_particle[j]] = self.sv[k]
        state.fluid_kappa_v[j] = self.kacc[k] * h

    @ti.kernel
    def _surface_tension(self, h: float, gamma: float):
        """Akinci et al. 2013's cohesion and curvature forces on v* (surface_tension.py)."""
        surface_tension.normals(self)
        surface_tension.accelerate(self, h, gamma)

    @ti.func
    def _outside_bodies(self, model: ti.template(), state: ti.template(), x):
        """x moved out to the surface of every body it entered (the bodies' samples push; this only puts
        a particle the pressure let through back outside, where the next solve sees it). Position only,
        so the momentum the liquid and the bodies exchange is the pressure's alone; to the surface only:
        pushed out to half a spacing, without the impact's velocity, a floating plank tipped over
        within 2 s."""
        r = 0.0
        for b in range(model.live_rigid()):
            xb = state.rigid_x[b]
            if (x - xb).norm() < model.rigid_bound[b] + r:
                d, n = body_sdf(model, b, xb, quat_matrix(state.rigid_q[b]), x)
                if d < r:
                    x += (r - d) * n
        return x

    # It inlines every collider's and body's surface query (a mesh collider's tree walk, each body kind's
    # distance): Taichi's CFG passes took 2.3 of its 2.5 s to compile in the pour demo (0.6 s without
    # them), and its frame did not slow (38.2 against 39.2 ms, medians of 3 alternating 40-frame runs).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _finish(self, state: ti.template(), model: ti.template(), h: float, t: float):
        self._finish_pass(state, model, h, t)

    @ti.func
    def _finish_pass(self, state: ti.template(), model: ti.template(), h, t):
        """x = x(start) + h v; colliders' and bodies' surfaces as a last guard (half a spacing away, where
        the liquid's volume ends); write back; record p and rho."""
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._finish_one(state, model, k, h, t)

    @ti.func
    def _finish_one(self, state: ti.template(), model: ti.template(), k, h, t):
        j = self.grid.sorted_id[k]
        p = model.fluid_particle[j]
        v = self.sv[k]
        x = self.grid.sorted_x[k] + h * v
        for c in ti.static(model.colliders):
            d, n, vs = c.contact(x, t)
            if d < 0.5 * self.spacing:
                x += (0.5 * self.spacing - d) * n
                vn = (v - vs).dot(n)
                if vn < 0.0:
                    v -= vn * n
        if ti.static(self.coupled and model.rigid_count > 0):
            x = self._outside_bodies(model, state, x)
        state.particle_x[p] = x
        state.particle_v[p] = v
        state.fluid_kappa[j] = self.kacc[k] * h * h
        state.fluid_density[j] = self.rho[k]
        state.fluid_pressure[j] = self.kacc[k] * self.rho[k] * self.rho[k]

    # Run once per liquid: compiled without Taichi's CFG passes and advanced optimisation (the pour demo's
    # cold start 0.41 -> 0.32 s, medians of 3; its volumes moved by round-off, 2 ulp of f32).
    @compile_with(cfg_optimization=False, advanced_optimization=False)
    @ti.kernel
    def _setup(self, bx: ti.template(), walls: ti.i32, apart: ti.template(), samples: ti.i32,
               apart_grid: ti.template()):  # fmt: skip
        """The walls' grid over their `walls` samples bx and their volumes; the bodies' `samples`, each
        body's apart from the others' (bodies.apart), in apart_grid, and their volumes."""
        if ti.static(self.walls):
            self.boundary.build_pass(bx, walls, None, 0.0, False)
            self._volumes_pass(self.boundary, self.boundary_psi, False)
        if ti.static(self.coupled):
            apart_grid.build_pass(apart, samples, None, 0.0, False)
            self._volumes_pass(apart_grid, self.bodies.psi, True)

    @ti.func
    def _volumes_pass(self, grid: ti.template(), psi: ti.template(), by_sample: ti.template()):
        """psi_b = share rho0 / sum_b' W_bb' over the samples of `grid` (Akinci et al. 2012, eq. 4-5,
        scaled as the walls' comment in __init__ says), into psi by slot (the walls, read by slot) or by
        sample (the bodies, whose grid is rebuilt every substep). For the walls, also wall_near: the
        cells within two cells of a sample on every axis, the block _near scans around a point's cell."""
        if ti.static(not by_sample):
            for c in range(grid.cell_count):
                self.wall_near[c] = 0
            for b in range(grid.size[None]):
                cell = grid.coords(grid.sorted_x[b])
                for q in range(125):
                    c = cell + ti.Vector([q // 25 - 2, (q // 5) % 5 - 2, q % 5 - 2])
                    if (c >= 0).all() and (c < ti.Vector(grid.dims)).all():
                        self.wall_near[grid.key(c)] = 1  # every writer writes 1: no atomic needed
        for b in range(grid.size[None]):
            acc = ti.cast(0.0, float)
            self._near(grid, b, grid.sorted_x[b], self._add_w, acc)
            value = self.layer_share * self.rest_density / (acc + cubic_w(0.0, self.support))
            if ti.static(by_sample):
                psi[grid.sorted_id[b]] = value
            else:
                psi[b] = value

    @ti.func
    def _add_w(self, b, bb, d, acc: ti.template()):
        if bb != b:
            acc += cubic_w(d.norm(), self.support)
