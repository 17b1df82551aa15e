"""Model: the static description of a scene (masses, force terms, colliders, emitters) and its counts.
Absent parts are empty tuples / None with count 0, and kernels branch on them at compile time, so a scene
compiles and runs only what it has. Nothing here changes during a step: dynamic data is in State, and
every scratch field (element caches, stage states, Krylov vectors) belongs to the solver that writes it."""

from types import MappingProxyType

import numpy as np
import taichi as ti

from .collision.motion import attachment_codes
from .runtime import data_oriented, np_float, serial_loops
from .state import ALIVE_FOREVER, State
from .terms import Springs


@data_oriented
class Model:
    """Built by `Builder.finalize()`. particle_count includes every emitter's slots."""

    def __init__(
        self,
        *,
        x,
        v,
        mass,
        radius,
        terms,
        colliders,
        emitters,
        trail_length,
        seed,
        settings,
        contacts=None,
        springs=None,
        element_terms=None,
        triangles=None,
        self_contact=None,
        attachments=(),
    ):
        n = len(x)
        self.particle_count = n
        self.settings = dict(settings)  # a copy: the builder's record is not written to
        self.colliders = list(colliders)
        self.emitters = list(emitters)
        self.emitter_count = len(self.emitters)
        self.collider_count = len(self.colliders)
        for c in self.colliders:  # moving and mesh colliders write their keyframes / geometry into fields
            c.allocate(reach=float(np.max(radius)))
        self._prepared_colliders = tuple(c for c in self.colliders if c.needs_prepare)
        # Attachments: pinned particles put on animated targets at the end of each step.
        self.attachments = tuple(attachments)
        self.attachment_count = len(self.attachments)
        self.particle_attachment = attachment_codes(n, self.attachments) if self.attachments else None
        self.trail_length = trail_length
        self.seed = seed
        self._x0 = np.asarray(x, dtype=np.float64)
        self._v0 = np.asarray(v, dtype=np.float64)
        masses = np.asarray(mass, dtype=np.float64)
        # One mass for all: a compile-time constant instead of a field read per particle and step.
        self.uniform_mass = float(masses[0]) if np.all(masses == masses[0]) else None
        self.particle_mass = None
        self.particle_inv_mass = None
        if self.uniform_mass is None:
            self.particle_mass = ti.field(float, n)
            self.particle_inv_mass = ti.field(float, n)
            self.particle_mass.from_numpy(masses.astype(np_float()))
            inv = np.divide(1.0, masses, out=np.zeros_like(masses), where=masses > 0)
            self.particle_inv_mass.from_numpy(inv.astype(np_float()))
        self.uniform_inv_mass = 1.0 / self.uniform_mass if self.uniform_mass else 0.0
        self.per_particle_mass = self.uniform_mass is None  # kernels branch on this at compile time
        radii = np.asarray(radius, dtype=np.float64)
        # Radii [m]: all zero for point particles (a compile-time 0 then), one value, or one per particle.
        self.max_radius = float(radii.max())
        self.min_radius = float(radii.min())
        self.min_sphere_radius = float(radii[radii > 0].min()) if self.max_radius > 0 else 0.0
        self.uniform_radius = self.max_radius if self.max_radius == self.min_radius else None
        self.particle_radius = None
        self.per_particle_radius = self.uniform_radius is None  # compile-time branch in kernels
        if self.uniform_radius is None:
            self.particle_radius = ti.field(float, n)
            self.particle_radius.from_numpy(radii.astype(np_float()))
        self._static_count = n - sum(e.capacity for e in self.emitters)
        # Sphere contacts: the options the scene asked for (validated by the Builder), or None. The contact
        # solver (collision/spheres.py) is built from them by the Stepper, which owns its fields.
        self.sphere_contacts = None if contacts is None else MappingProxyType(dict(contacts))
        self.rest_speed = -1.0  # below it impacts do not bounce; < 0: every impact bounces
        if contacts is not None:
            self.rest_speed = float(contacts["rest_speed"])
            self.settings["sphere_contacts"] = {k: v for k, v in contacts.items() if k != "domain"}
        # Springs (cloth) are one element term among others (membrane, bending, aerodynamics).
        self.springs = None
        if springs is not None and len(springs["pairs"]):
            self.springs = Springs(n, **springs)
        self.spring_count = 0 if self.springs is None else self.springs.count
        elements = ([self.springs] if self.springs is not None else []) + list(element_terms or ())
        # Pointwise terms first: the order in which solvers sum forces (and the settings list).
        self.point_terms = tuple(terms)
        self.element_terms = tuple(elements)
        self.terms = self.point_terms + self.element_terms
        self.settings["forces"] = [t.settings() for t in self.terms]
        self.coupled = bool(self.element_terms)  # integrators branch on it at compile time
        self._probe = None
        # Cloth triangles (F,3) over particle indices, for export and rendering only; None without cloth.
        self.triangles = None if triangles is None or len(triangles) == 0 else np.asarray(triangles)
        self.triangle_count = 0 if self.triangles is None else len(self.triangles)
        # Cloth self-contact: the options the scene asked for, or None (the Stepper builds the solver).
        self.self_contact = None if self_contact is None else MappingProxyType(dict(self_contact))
        if self_contact is not None:
            self.settings["self_contact"] = dict(self_contact)
        # Small scenes are launch-bound on the CPU: their loops run serially (compile-time). A particle's
        # work grows with its element entries (2 per spring), each about an eighth of a particle's update
        # with colliders: parallel loops pay from ~2e4 particles (benchmarks/particles.py) and from ~128^2
        # mass-spring cloth (benchmarks/results/layout.md: 0.59x at 64^2, 1.01x at 128^2, 1.38x at 256^2).
        entries = sum(t.entry_count for t in self.element_terms)
        self.work = n + entries  # the size that decides fused frames (Stepper.frame_mode)
        self.serial = serial_loops(n + entries // 8)

    def state(self) -> State:
        """A fresh State at t = 0: the builder's particles in place, every emitter slot dead."""
        s = State(self)
        f = np_float()
        s.particle_x.from_numpy(self._x0.astype(f))
        s.particle_v.from_numpy(self._v0.astype(f))
        if s.has_lifetimes:
            death = np.full(self.particle_count, -1.0)
            death[: self._static_count] = ALIVE_FOREVER
            s.particle_death.from_numpy(death.astype(f))
            dead = np.zeros(s.particle_free.shape[0] * 32, dtype=np.uint8)
            dead[self._static_count : self.particle_count] = 1
            s.particle_free.from_numpy(np.packbits(dead, bitorder="little").view(np.uint32))
            s.particle_birth.from_numpy(np.zeros(self.particle_count, f))
        if s.trail_length:
            s.trail.from_numpy(np.repeat(self._x0[:, None, :], s.trail_length, axis=1).astype(f))
        return s

    def prepare_colliders(self, t: float, h: float) -> None:
        """Per-step work of colliders that need it (a deforming mesh: its vertices at t and t + h [s] and
        its hierarchy refitted); nothing for the others."""
        for c in self._prepared_colliders:
            c.prepare(t, h)

    def emit(self, state: State, dt: float) -> None:
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

    @ti.func
    def force(self, i, x, v, t):
        """Sum of the pointwise force terms on particle i at (x, v, t)."""
        m = self.mass(i)
        f = ti.Vector.zero(float, 3)
        for term in ti.static(self.point_terms):
            f += term.force(i, m, x, v, t)
        return f

    @ti.func
    def force_jacobian(self, i, x, v, t):
        """(df/dx, df/dv) of particle i, 3x3 each, summed over the pointwise terms."""
        m = self.mass(i)
        kx = ti.Matrix.zero(float, 3, 3)
        kv = ti.Matrix.zero(float, 3, 3)
        for term in ti.static(self.point_terms):
            if ti.static(term.has_jacobian):
                jx, jv = term.jacobian(i, m, x, v, t)
                kx += jx
                kv += jv
        return kx, kv

    @ti.func
    def accel(self, i, x, v, t):
        """Acceleration [m/s^2] of particle i from the pointwise terms at (x, v, t); Taichi scope."""
        return self.force(i, x, v, t) * self.inv_mass(i)

    @ti.func
    def element_pass(self, caches: ti.template(), xf: ti.template(), vf: ti.template(), t):
        """Evaluate every element term at the positions xf and velocities vf (fields) into the solver's
        caches: top-level loops that must come first in the kernel; nothing without element terms."""
        for k in ti.static(range(len(self.element_terms))):
            self.element_terms[k].evaluate(caches[k], xf, vf, t, self.serial)

    @ti.func
    def element_force(self, caches: ti.template(), i):
        """Force on particle i from its elements, after element_pass."""
        f = ti.Vector.zero(float, 3)
        for k in ti.static(range(len(self.element_terms))):
            f += self.element_terms[k].gather(caches[k], i)
        return f

    @ti.func
    def accel_total(self, caches: ti.template(), i, x, v, t):
        """Acceleration of particle i at (x, v, t): the pointwise terms plus, after element_pass, the
        forces of its elements."""
        return (self.force(i, x, v, t) + self.element_force(caches, i)) * self.inv_mass(i)

    def make_caches(self, implicit: bool = False) -> tuple:
        """Scratch for one solver: a cache per element term (in element_terms order)."""
        return tuple(t.make_cache(self.particle_count, implicit) for t in self.element_terms)

    def forces(self, x, v, t: float = 0.0) -> np.ndarray:
        """(N,3) total force [N] on every particle at positions x (N,3) [m] and velocities v (N,3) [m/s]
        (every term; for tests and reports: a probe with its own caches is made on the first call)."""
        if self._probe is None:
            self._probe = _ForceProbe(self)
        return self._probe.forces(x, v, t)

    def energy(self, x, v=None) -> dict:
        """Energies [J] at positions x (N,3) and velocities v (N,3): kinetic (if v is given), and each
        element term's that has one (springs', membrane's, bending's), keyed by type. Gravity's potential
        -sum m g.x is not included: statics and the watchdog add it where they need it."""
        x = np.asarray(x, dtype=np.float64)
        m = self.particle_masses()
        out = {}
        if v is not None:
            out["kinetic"] = float(0.5 * np.sum(m[:, None] * np.asarray(v, dtype=np.float64) ** 2))
        for term in self.terms:
            if term.has_energy:
                key = term.settings()["type"]
                out[key] = out.get(key, 0.0) + term.energy(x, m)
        return out

    def particle_masses(self) -> np.ndarray:
        """(N,) masses [kg] (0 for pinned particles)."""
        if self.particle_mass is None:
            return np.full(self.particle_count, self.uniform_mass or 0.0)
        return self.particle_mass.to_numpy().astype(np.float64)

    def pinned_indices(self) -> np.ndarray:
        """(P,) int64 indices of the pinned (kinematic) particles: those added with mass 0, and a cloth's
        `pinned=` vertices. They keep their velocity and ignore forces and collisions; attachments move
        them along targets, State.set_positions places them."""
        return np.flatnonzero(self.particle_masses() == 0.0)

    def spring_table(self) -> dict:
        """The model's springs as NumPy arrays, in the model's (sorted) spring order: pairs (S,2) int64
        particle indices (lower first), rest_length (S,) [m], stiffness (S,) [N/m], damping (S,) [N s/m],
        family (S,) int8 (a cloth's 0 stretch (structural), 1 shear, 2 bend; 0 for add_springs). Empty
        arrays for a model without springs."""
        s = self.springs
        if s is None:
            empty = np.zeros(0)
            return {
                "pairs": np.zeros((0, 2), np.int64),
                "rest_length": empty,
                "stiffness": empty,
                "damping": empty,
                "family": np.zeros(0, np.int8),
            }
        return {
            "pairs": s.pairs.copy(),
            "rest_length": s.rest_length.copy(),
            "stiffness": np.array(s.stiffness),
            "damping": np.array(s.damping),
            "family": s.family.copy(),
        }

    def particle_radii(self, idx: np.ndarray) -> np.ndarray:
        """(N,) radii [m] of particles idx (0 for points)."""
        if self.particle_radius is None:
            return np.full(len(idx), self.max_radius)
        return self.particle_radius.to_numpy()[idx]


@data_oriented
class _ForceProbe:
    """Total forces from NumPy for tests and reports, with caches of its own (never a solver's)."""

    def __init__(self, model):
        n = model.particle_count
        self.model = model
        self.caches = model.make_caches()
        self.fields = tuple(ti.Vector.field(3, float, n) for _ in range(3))

    def forces(self, x, v, t: float) -> np.ndarray:
        xf, vf, ff = self.fields
        xf.from_numpy(np.asarray(x, dtype=np_float()))
        vf.from_numpy(np.asarray(v, dtype=np_float()))
        self._forces(self.model, xf, vf, ff, t)
        return ff.to_numpy().astype(np.float64)

    @ti.kernel
    def _forces(
        self, model: ti.template(), xf: ti.template(), vf: ti.template(), ff: ti.template(), t: float
    ):
        model.element_pass(self.caches, xf, vf, t)
        for i in range(model.particle_count):
            ff[i] = model.force(i, xf[i], vf[i], t) + model.element_force(self.caches, i)
