"""XSPH viscosity of the liquid (Monaghan, "On the problem of penetration in particle methods", JCP 1989,
eq. 2.9, with the pair's mean density): the velocities v* the method made, each moved toward its
neighbours' by the coefficient c, equally and oppositely in every pair (dfsph.py, step 2 of its
docstring). On FluidDynamics's fields: the neighbour lists and W_kj of the substep's start."""

import taichi as ti

from ...runtime import data_oriented


@data_oriented
class XsphViscosity:
    """Mixin of FluidDynamics: v* gathered from the state and smoothed, into the slot velocities sv."""

    @ti.kernel
    def _gather_velocities(self, state: ti.template(), model: ti.template(), c: float, h: float):
        self._gather_velocities_pass(state, model, c, h)

    @ti.func
    def _gather_velocities_pass(self, state: ti.template(), model: ti.template(), c, h):
        """v* from the method, smoothed by XSPH with the pair's mean density (Monaghan 1989, eq. 2.9):
        v_i += c sum_j (2 m / (rho_i + rho_j)) (v_j - v_i) W_ij, equal and opposite in every pair."""
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._copy_velocity_one(state, model, k)
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._xsph_one(k, c)
            self._wall_push_one(state, k, h)  # the walls' hydrostatic push (wall_pressure.py)

    @ti.func
    def _copy_velocity_one(self, state: ti.template(), model: ti.template(), k):
        self.sv2[k] = state.particle_v[model.fluid_particle[self.grid.sorted_id[k]]]

    @ti.func
    def _xsph_one(self, k, c):
        vi, rho = self.sv2[k], self.rho[k]
        dv = ti.Vector.zero(float, 3)
        for m in range(self.nn[k]):
            kk = self.nbr[k, m]
            dv += (self.sv2[kk] - vi) * (2.0 * self.weight[k, m] / (rho + self.rho[kk]))
        self.sv[k] = vi + c * self.mass * dv
