"""A small liquid's substep in two launches (dfsph.py's before_substep and after_substep).

A liquid under FLUID_SERIAL_BELOW particles runs every loop serially (a parallel loop's start costs more
than its work on this CPU), so nothing is lost by running its passes one after another inside one
serial loop of one kernel, and each launch saved is about 25 us of Taichi's launch path: before the
method moves the particles, the positions' gather, the grid's build, the neighbourhood pass, the
divergence solve and the velocities' write-back; after it, XSPH, surface tension, the density solve and
the last guard. The passes are the ones the launch-per-pass path runs, in the same order, so a step
gives the same iterations (the solves stop where first_sum_above says, pressure.py) and the same
arithmetic. Only a liquid alone takes this path: with bodies (whose samples are placed and pushed
between the passes) or nozzles (whose count is known only after the grid's build) it runs a launch per
pass."""

import taichi as ti

from ...runtime import compile_with, data_oriented
from . import surface_tension


@data_oriented
class SerialSubstep:
    """Mixin of FluidDynamics: _begin_serially and _end_serially."""

    def _two_launch_substep(self) -> bool:
        """Whether this liquid's substeps run in two launches (the module's docstring)."""
        return self.serial and self.one_launch_solve and not self.coupled and not self.emitted

    @ti.kernel
    def _begin_serially(
        self,
        state: ti.template(),
        model: ti.template(),
        n: ti.i32,
        h: float,
        above: ti.i64,
        least: ti.i32,
        most: ti.i32,
    ) -> ti.types.vector(2, ti.i64):
        """Gather, grid, neighbourhoods, the divergence solve (iterating while the errors' sum is at
        least `above` or fewer than `least` were made, at most `most`), write-back; returns (iterations,
        the last errors' fixed-point sum), (0, 0) for a method without a divergence solve."""
        out = ti.Vector([0, 0], dt=ti.i64)
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._gather_positions_pass(state, model)
            self.grid.build_pass(self.cx, n, None, 0.0, False)  # no death times: liquid alone
            self._neighborhoods_pass(state, model)
            if ti.static(self.divergence_solve):
                it = self._solve_pass(state, h, 1, above, least, most)
                self._write_velocities_pass(state, model, h)
                out = ti.Vector([it, self.err_sum[None]], dt=ti.i64)
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
    ) -> ti.types.vector(2, ti.i64):
        """XSPH, surface tension, the density solve (as _begin_serially's), the last guard at time t [s];
        returns (iterations, the last errors' fixed-point sum)."""
        out = ti.Vector([0, 0], dt=ti.i64)
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._gather_velocities_pass(state, model, viscosity)
            if ti.static(self.surface_tension > 0.0):
                surface_tension.normals(self)
                surface_tension.accelerate(self, h, gamma)
            it = self._density_pass(state, h, above, least, most)
            self._finish_pass(state, model, h, t)
            out = ti.Vector([it, self.err_sum[None]], dt=ti.i64)
        return out
