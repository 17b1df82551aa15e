"""The particle kind's model part: counts, masses and radii (uniform ones as compile-time constants),
the initial positions and velocities, emitters; the Taichi-scope accessors every kernel reads them
through (`model.mass(i)`, `model.alive(state, i, t)`, `model.live_particles()`, ...). Under capacity
buckets (capacity.py) its arrays hold particle_capacity rows and kernels loop to the live count."""

import numpy as np
import taichi as ti

from ... import bulk, capacity
from ...runtime import data_oriented, np_float


@data_oriented
class ParticleModel:
    """Model methods of the particle kind (the Model inherits them). particle_count includes every
    emitter's slots; particle_mass, particle_inv_mass (N,) [kg], [1/kg] and particle_radius (N,) [m]
    are fields only where the values differ (None otherwise, read as the uniform constant)."""

    def _init_particles(self, *, x, v, mass, radius, emitters, trail_length) -> None:
        """Take the builder's particle arrays: x (N,3) [m], v (N,3) [m/s], mass (N,) [kg] (0: pinned),
        radius (N,) [m], the emitters over their slot ranges, the trail length (0: none)."""
        n = len(x)
        self.particle_count = n
        # Taichi refuses empty fields: a scene without particles keeps one unused row (nothing loops to it)
        self.particle_capacity = capacity.bucket(n) if self.size_buckets else max(n, 1)
        # The live count as a 0-d field, read by kernels at run time (buckets only: else a constant).
        self.particle_live = self.new_field(self, "particle_live", ti.i32, ()) if self.size_buckets else None
        if self.size_buckets:
            self.particle_live[None] = n
        self.emitters = list(emitters)
        self.emitter_count = len(self.emitters)
        self.trail_length = trail_length
        self._x0 = np.asarray(x, dtype=np.float64)
        self._v0 = np.asarray(v, dtype=np.float64)
        masses = np.asarray(mass, dtype=np.float64) if n else np.ones(1)
        # One mass for all: a compile-time constant instead of a field read per particle and step.
        self.uniform_mass = float(masses[0]) if np.all(masses == masses[0]) else None
        self.particle_mass = None
        self.particle_inv_mass = None
        if self.uniform_mass is None:
            self.particle_mass = self.particle_array(self, "particle_mass")
            self.particle_inv_mass = self.particle_array(self, "particle_inv_mass")
            inv = np.divide(1.0, masses, out=np.zeros_like(masses), where=masses > 0)
            bulk.fill([(self.particle_mass, self.padded(masses)), (self.particle_inv_mass, self.padded(inv))])
        self.uniform_inv_mass = 1.0 / self.uniform_mass if self.uniform_mass else 0.0
        self.per_particle_mass = self.uniform_mass is None  # kernels branch on this at compile time
        radii = np.asarray(radius, dtype=np.float64) if n else np.zeros(1)
        # Radii [m]: all zero for point particles (a compile-time 0 then), one value, or one per particle.
        self.max_radius = float(radii.max())
        self.min_radius = float(radii.min())
        self.min_sphere_radius = float(radii[radii > 0].min()) if self.max_radius > 0 else 0.0
        self.uniform_radius = self.max_radius if self.max_radius == self.min_radius else None
        self.particle_radius = None
        self.per_particle_radius = self.uniform_radius is None  # compile-time branch in kernels
        if self.uniform_radius is None:
            self.particle_radius = self.particle_array(self, "particle_radius")
            bulk.fill([(self.particle_radius, self.padded(radii))])
        self._static_count = n - sum(e.capacity for e in self.emitters)

    def particle_array(self, owner, role: str, dtype=float, dims: tuple = (), extra: tuple = ()):
        """A field of particle_capacity rows (by `extra` columns) with elements of `dims`, for `owner`
        (the model or a State or solver of it): pooled under buckets (Model.new_field)."""
        return self.new_field(owner, role, dtype, (self.particle_capacity, *extra), dims)

    def padded(self, a, dtype=None) -> np.ndarray:
        """`a` (particle_count rows) with zero rows up to particle_capacity, as the float fields' dtype
        (or `dtype`): what from_numpy of a particle array takes."""
        return capacity.padded(a, self.particle_capacity, dtype or np_float())

    @ti.func
    def live_particles(self):
        """Particles the kernels loop over: the live count (a 0-d field read at run time under
        buckets, so that another size compiles nothing; a compile-time constant otherwise)."""
        if ti.static(self.size_buckets):
            return self.particle_live[None]
        else:
            return self.particle_count

    def emit(self, state, dt: float) -> None:
        """Run every emitter for a step of dt [s] on `state` (births into free slots)."""
        for e in self.emitters:
            e.emit(state, state.time, dt, self.seed, state.step_count)

    @ti.func
    def mass(self, i):
        """Mass [kg] of particle i (0 for pinned particles); Taichi scope."""
        m = ti.cast(self.uniform_mass or 0.0, float)
        if ti.static(self.per_particle_mass):
            m = self.particle_mass[i]
        return m

    @ti.func
    def inv_mass(self, i):
        """Inverse mass [1/kg] of particle i (0 for pinned particles); Taichi scope."""
        w = ti.cast(self.uniform_inv_mass, float)
        if ti.static(self.per_particle_mass):
            w = self.particle_inv_mass[i]
        return w

    @ti.func
    def radius(self, i):
        """Radius [m] of particle i (0 for points); Taichi scope."""
        r = ti.cast(self.uniform_radius or 0.0, float)
        if ti.static(self.per_particle_radius):
            r = self.particle_radius[i]
        return r

    @ti.func
    def alive(self, state: ti.template(), i, t):
        """Whether particle i of `state` is alive at time t [s]; Taichi scope."""
        ok = True
        if ti.static(state.has_lifetimes):
            ok = state.particle_death[i] > t
        return ok

    @ti.func
    def release(self, state: ti.template(), i):
        """Mark dead slot i free for emitters. Final kernels call it for particles that die within the
        step and again for any found dead at its start (covers f32 rounding of the step's end time)."""
        w = i >> 5
        bit = ti.u32(1) << ti.cast(i & 31, ti.u32)
        if (state.particle_free[w] & bit) == 0:  # plain read first: most dead slots are marked already
            ti.atomic_or(state.particle_free[w], bit)

    @ti.func
    def release_if_dead(self, state: ti.template(), i, t):
        """Free slot i for emitters if its particle is dead by time t (the end of the step)."""
        if state.particle_death[i] <= t:
            self.release(state, i)

    def particle_masses(self) -> np.ndarray:
        """(N,) masses [kg] (0 for pinned particles)."""
        if self.particle_mass is None:
            return np.full(self.particle_count, self.uniform_mass or 0.0)
        return self.particle_mass.to_numpy()[: self.particle_count].astype(np.float64)

    def pinned_indices(self) -> np.ndarray:
        """(P,) int64 indices of the pinned (kinematic) particles: those added with mass 0, and a cloth's
        `pinned=` vertices. They keep their velocity and ignore forces and collisions; attachments move
        them along targets, State.set_positions places them."""
        return np.flatnonzero(self.particle_masses() == 0.0)

    def particle_radii(self, idx: np.ndarray) -> np.ndarray:
        """(N,) radii [m] of particles idx (0 for points)."""
        if self.particle_radius is None:
            return np.full(len(idx), self.max_radius)
        return self.particle_radius.to_numpy()[idx]

    def particle_kinetic_energy(self, v) -> float:
        """Kinetic energy [J] of velocities v (N,3) [m/s]."""
        m = self.particle_masses()
        return float(0.5 * np.sum(m[:, None] * np.asarray(v, dtype=np.float64) ** 2))
