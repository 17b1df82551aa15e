"""The fluid kind's model part: which particles are liquid, and the liquid's constants."""

from types import MappingProxyType

import numpy as np
import taichi as ti

from ... import bulk, capacity
from ...runtime import data_oriented
from .builder import SUPPORT_PER_SPACING


@data_oriented
class FluidModel:
    """Model methods of the fluid kind (the Model inherits them).

    fluid_count; fluid_particles (F,) the particle index of each fluid particle (NumPy) and
    fluid_particle (F,) the same as a field for kernels (None without liquid), particle_is_fluid (N,) 1
    for a liquid particle (liquid(i) reads it), all_liquid: whether every particle is; fluid_capacity:
    the rows of every per-liquid-particle field (F, or its power-of-two bucket under capacity buckets,
    whose kernels loop to live_fluid(), read at run time); fluid_spacing [m], fluid_support [m] (the SPH
    support radius), fluid_density [kg/m^3] at rest, fluid_mass [kg] per particle; fluid: the solver's
    options (None without liquid), which the Stepper builds its solver from (solvers.SOLVERS)."""

    def _init_fluid(self, *, particles, options) -> None:
        self.fluid_particles = np.asarray(particles, dtype=np.int64)
        self.fluid_particles.setflags(write=False)
        self.fluid_count = len(self.fluid_particles)
        self.fluid_capacity = 0
        self.fluid = None
        self.fluid_particle = self.fluid_live = None
        self.all_liquid = False  # every particle slot liquid: the particle step then skips colliders
        self.fluid_spacing = self.fluid_support = self.fluid_density = self.fluid_mass = 0.0
        if not self.fluid_count:
            return
        self.fluid = MappingProxyType(dict(options))
        self.fluid_spacing = float(options["spacing"])
        self.fluid_support = SUPPORT_PER_SPACING * self.fluid_spacing
        self.fluid_density = float(options["density"])
        self.fluid_mass = float(options["mass"])
        self.fluid_capacity = capacity.bucket(self.fluid_count) if self.size_buckets else self.fluid_count
        self.all_liquid = self.fluid_count == self.particle_count
        if self.size_buckets:  # the live count, read by kernels at run time (live_fluid)
            self.fluid_live = self.new_field(self, "fluid_live", ti.i32, ())
            self.fluid_live[None] = self.fluid_count
        self.fluid_particle = self.new_field(self, "fluid_particle", ti.i32, self.fluid_capacity)
        mask = np.zeros(self.particle_count, dtype=np.int32)
        mask[self.fluid_particles] = 1
        self.particle_is_fluid = self.particle_array(self, "particle_is_fluid", ti.i32)
        bulk.fill(  # with the other kinds' arrays (Model.__init__'s batch): from_numpy is a kernel each
            [
                (self.fluid_particle, capacity.padded(self.fluid_particles, self.fluid_capacity, np.int32)),
                (self.particle_is_fluid, self.padded(mask, np.int32)),
            ]
        )

    @ti.func
    def live_fluid(self):
        """Liquid particles the kernels loop over: a 0-d field read at run time under capacity buckets
        (so that another count compiles nothing), else a compile-time constant."""
        if ti.static(self.size_buckets):
            return self.fluid_live[None]
        else:
            return self.fluid_count

    @ti.func
    def liquid(self, i):
        """Whether particle i is liquid (Taichi scope; False at compile time without liquid): the liquid
        meets bodies through its pressure solve (bodies/fluid/bodies.py), not particle impacts."""
        out = False
        if ti.static(self.fluid_count > 0):
            out = self.particle_is_fluid[i] != 0
        return out
