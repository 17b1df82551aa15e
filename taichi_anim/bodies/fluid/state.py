"""The fluid kind's state part: what a run of the liquid carries from step to step (the pressure
solves' warm starts) and reports (each particle's density and pressure at its last step)."""

import numpy as np
import taichi as ti

from ... import bulk
from ...runtime import data_oriented


@data_oriented
class FluidState:
    """State methods of the fluid kind (the State inherits them), per fluid particle in the order of
    model.fluid_particles (None without liquid): fluid_density (F,) [kg/m^3] and fluid_pressure (F,)
    [Pa] at the start of the last step; fluid_kappa (F,) and fluid_kappa_v (F,) the density and
    divergence solves' last stiffness times h^2 and h (their warm starts). Each holds
    model.fluid_capacity rows (a bucket's under capacity buckets): the accessors return the first F."""

    def _init_fluid(self, model) -> None:
        self.fluid_density = self.fluid_pressure = self.fluid_kappa = self.fluid_kappa_v = None
        if not model.fluid_count:
            return
        n = model.fluid_capacity
        for name in ("fluid_density", "fluid_pressure", "fluid_kappa", "fluid_kappa_v"):
            setattr(self, name, model.new_field(self, name, float, n))

    def _start_fluid(self, model) -> None:
        if not model.fluid_count:
            return
        n = model.fluid_capacity  # every row: a pooled field holds what its last owner left
        zero = np.zeros(n)
        bulk.fill([(self.fluid_density, np.full(n, model.fluid_density)), (self.fluid_pressure, zero),
                   (self.fluid_kappa, zero), (self.fluid_kappa_v, zero)])  # fmt: skip

    def _save_fluid(self, into, whole_trail: bool) -> None:
        if self.model.fluid_count:
            self._copy_fluid(self.model, self, into)

    @ti.kernel
    def _copy_fluid(self, model: ti.template(), src: ti.template(), dst: ti.template()):
        for j in range(model.live_fluid()):
            dst.fluid_density[j] = src.fluid_density[j]
            dst.fluid_pressure[j] = src.fluid_pressure[j]
            dst.fluid_kappa[j] = src.fluid_kappa[j]
            dst.fluid_kappa_v[j] = src.fluid_kappa_v[j]

    def fluid_densities(self) -> np.ndarray:
        """(F,) [kg/m^3] each fluid particle's density at the start of its last step."""
        return self._fluid_rows(self.fluid_density)

    def fluid_pressures(self) -> np.ndarray:
        """(F,) [Pa] each fluid particle's pressure from its last step's density solve."""
        return self._fluid_rows(self.fluid_pressure)

    def _fluid_rows(self, field) -> np.ndarray:
        if field is None:
            return np.zeros(0)
        return field.to_numpy()[: self.model.fluid_count].astype(np.float64)
