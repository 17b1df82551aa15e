"""A small liquid's substep in two launches (dfsph.py's before_substep and after_substep).

A liquid under FLUID_SERIAL_BELOW particles runs every loop serially (a parallel loop's start costs more
than its work on this CPU), so nothing is lost by running its passes one after another inside one
serial loop of one kernel, and each launch saved is about 25 us of Taichi's launch path: before the
method moves the particles, the positions' gather, the grid's build, the bodies' samples placed and
their grid built, the neighbourhood pass, the divergence solve and the velocities' write-back; after it,
XSPH, surface tension, the density solve and the last guard. The passes are the ones the launch-per-pass
path runs, in the same order (a solve's bodies' samples moved before it and its impulses given back
after it), so a step gives the same iterations (the solves stop where first_sum_above says, pressure.py)
and the same arithmetic. A liquid fed by nozzles knows how many of its particles live only once the
grid is built, inside the launch: its solves read their thresholds from a table over every count
(first_sums_above), rewritten when a tolerance changes; the others get theirs as arguments.

The pour demo's liquid (a nozzle, a floating box) ran 11 kernels and read four fields per substep
before: 26.8 -> 19.3 ms a frame (60 frames, 3 alternating runs each). Its compile, with an empty cache
or a warm one, stayed about what it was: the passes' code is the same."""

import numpy as np
import taichi as ti

from ...runtime import compile_with, data_oriented
from . import surface_tension
from .pressure import first_sum_above, first_sums_above


@data_oriented
class SerialSubstep:
    """Mixin of FluidDynamics: _begin_serially and _end_serially."""

    def _two_launch_substep(self) -> bool:
        """Whether this liquid's substeps run in two launches (the module's docstring)."""
        return self.serial and self.one_launch_solve

    def _thresholds(self, model, tolerance: float) -> int:
        """The solve's threshold for the liquid's count (first_sum_above). A liquid fed by nozzles, whose
        live count only the launch knows, gets 0 (unread): its solves read the table of both solves'
        thresholds over every count (row 0 the density solve's, row 1 the divergence solve's), written
        here when a tolerance changed since it was."""
        if not self.emitted:
            return first_sum_above(tolerance, model.fluid_count)
        key = (self.tolerance, self.divergence_tolerance)
        if self._thresholds_for != key:
            n = model.fluid_count
            table = np.zeros(self.sum_above.shape, dtype=np.int64)  # count 0: no solve runs
            counts = np.arange(1, n + 1)
            table[0, 1 : n + 1] = first_sums_above(self.tolerance, counts)
            table[1, 1 : n + 1] = first_sums_above(self.divergence_tolerance, counts)
            self.sum_above.from_numpy(table)
            self._thresholds_for = key
        return 0

    @ti.func
    def _solve_with_bodies(self, state: ti.template(), model: ti.template(), h, divergence: ti.template(), n,
                           above, least, most):  # fmt: skip
        """pressure.py's _solve inside the launch: the bodies' samples moved, the divergence or the density
        solve (to the threshold `above`, or the table's for n live particles), their impulses given back;
        nothing when no particle lives. Returns the iterations."""
        it = 0
        if n > 0:
            if ti.static(self.coupled):
                self.bodies.move_pass(model, state)
            if ti.static(self.emitted):
                above = self.sum_above[int(divergence), n]
            if ti.static(divergence):
                it = self._solve_pass(state, h, 1, above, least, most)
            else:
                it = self._density_pass(state, h, above, least, most)
            if ti.static(self.coupled):
                self._push_bodies_pass(model, state, h)
        return it

    def _death(self):
        """The birth-and-death times the grid reads (a liquid fed by nozzles), else None."""
        return self.cdeath if self.emitted else None

    # Without Taichi's CFG passes: with them it took 1.9 s of the pour demo's cold start (0.65 s without),
    # and the dam break's frame did not slow (19.1 / 19.4 ms against 19.9 / 20.8 before).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _begin_serially(
        self,
        state: ti.template(),
        model: ti.template(),
        count: ti.i32,
        t: float,
        h: float,
        above: ti.i64,
        least: ti.i32,
        most: ti.i32,
    ) -> ti.types.vector(3, ti.i64):
        """Gather, grid (of the particles alive at time t [s] among the first `count`), the bodies'
        samples and their grid, neighbourhoods, the divergence solve (iterating while the errors' sum is
        at least its threshold or fewer than `least` were made, at most `most`), write-back; returns
        (iterations, the last errors' fixed-point sum, live particles); (0, 0, n) without a divergence
        solve."""
        out = ti.Vector([0, 0, 0], dt=ti.i64)
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._gather_positions_pass(state, model)
            self.grid.build_pass(self.cx, count, ti.static(self._death()), t, ti.static(self.emitted))
            if ti.static(self.coupled):
                self.bodies.place_pass(model, state)
                self.body_grid.build_pass(self.bodies.x, self.bodies.count, None, 0.0, False)
            self._neighborhoods_pass(state, model)
            n = self._live()
            if ti.static(self.divergence_solve):
                it = self._solve_with_bodies(state, model, h, True, n, above, least, most)
                self._write_velocities_pass(state, model, h)
                out = ti.Vector([it, self.err_sum[None], n], dt=ti.i64)
            else:
                out = ti.Vector([0, 0, n], dt=ti.i64)
        return out

    # Without Taichi's CFG passes, as the last guard it holds (dfsph.py's _finish says why).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _end_serially(
        self,
        state: ti.template(),
        model: ti.template(),
        h: float,
        t: float,
        viscosity: float,
        gamma: float,
        above: ti.i64,
        least: ti.i32,
        most: ti.i32,
    ) -> (ti.types.vector(3, ti.i64), float):
        """XSPH, surface tension, the density solve (as _begin_serially's), the last guard at time t [s];
        returns ((iterations, the last errors' fixed-point sum, live particles), the largest error)."""
        out = ti.Vector([0, 0, 0], dt=ti.i64)
        worst = ti.cast(0.0, float)
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._gather_velocities_pass(state, model, viscosity, h)
            if ti.static(self.surface_tension > 0.0):
                surface_tension.normals(self)
                surface_tension.accelerate(self, h, gamma)
            n = self._live()
            it = self._solve_with_bodies(state, model, h, False, n, above, least, most)
            self._finish_pass(state, model, h, t)
            out = ti.Vector([it, self.err_sum[None], n], dt=ti.i64)
            if n > 0:  # else no solve ran: its error is 0, not the last substep's
                worst = self.err_max[None]
        return out, worst
