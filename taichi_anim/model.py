"""Model: the static description of a scene (every body kind's static arrays — bodies/: the particles'
masses, radii, emitters —, force terms, colliders) and its counts.
Absent parts are empty tuples / None with count 0, and kernels branch on them at compile time, so a scene
compiles and runs only what it has. Nothing here changes during a step: dynamic data is in State, and
every scratch field (element caches, stage states, Krylov vectors) belongs to the solver that writes it."""

from types import MappingProxyType

import numpy as np
import taichi as ti

from . import bulk, capacity
from .bodies import KINDS, MODEL_PARTS
from .collision.motion import attachment_codes
from .runtime import data_oriented, serial_loops
from .state import State
from .terms import Springs


@data_oriented
class Model(*MODEL_PARTS):
    """Built by `Builder.finalize()`. `kinds`: the body kinds it holds (bodies/), each with its arrays
    and accessors (the particles': particle_count, which includes every emitter's slots, masses,
    radii)."""

    def __init__(
        self,
        *,
        bodies,
        terms,
        colliders,
        seed,
        settings,
        contacts=None,
        springs=None,
        element_terms=None,
        triangles=None,
        self_contact=None,
        attachments=(),
    ):
        # Capacity buckets (capacity.py): arrays sized to a power of two, live counts read at run time.
        self.size_buckets = capacity.enabled()
        if self.size_buckets:
            capacity.collect_dropped()  # a dropped scene's fields back in the pool before this one asks
        # Each kind's arrays, from the builder's parts (bodies: {kind name: init_model's arguments}).
        self.kinds = KINDS
        # Every kind's arrays and the forces' in one fill launch (none of them is read here).
        with bulk.batch():
            for kind in KINDS:
                kind.init_model(self, **bodies[kind.name])
            n = self.particle_count
            # Springs (cloth) are one element term among others (membrane, bending, aerodynamics).
            self.springs = None
            if springs is not None and len(springs["pairs"]):
                self.springs = Springs(n, **springs, model=self)
            # A term that keeps arrays or run-time parameters in fields places them now (capacity buckets).
            for t in (*terms, *(element_terms or ())):
                bind = getattr(t, "bind", None)
                if bind is not None:
                    bind(self)
        self.seed = seed
        self.settings = dict(settings)  # a copy: the builder's record is not written to
        self.colliders = list(colliders)
        self.collider_count = len(self.colliders)
        for c in self.colliders:  # moving and mesh colliders write their keyframes / geometry into fields
            c.allocate(reach=max(self.max_radius, self.rigid_reach), model=self)
        self._prepared_colliders = tuple(c for c in self.colliders if c.needs_prepare)
        # Attachments: pinned particles put on animated targets at the end of each step.
        self.attachments = tuple(attachments)
        self.attachment_count = len(self.attachments)
        self.particle_attachment = None
        if self.attachments:
            codes = self.particle_array(self, "particle_attachment", ti.i32)
            self.particle_attachment = attachment_codes(n, self.attachments, codes)
        # Sphere contacts: the options the scene asked for (validated by the Builder), or None. The contact
        # solver (collision/spheres.py) is built from them by the Stepper, which owns its fields.
        self.sphere_contacts = None if contacts is None else MappingProxyType(dict(contacts))
        self.rest_speed = -1.0  # below it impacts do not bounce; < 0: every impact bounces
        if contacts is not None:
            self.rest_speed = float(contacts["rest_speed"])
            self.settings["sphere_contacts"] = {k: v for k, v in contacts.items() if k != "domain"}
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
        # With buckets the choices go by capacity, so that every size of a bucket compiles the same kernels.
        sized = self.particle_capacity if self.size_buckets else n
        if self.size_buckets:  # each term's entries at its element bucket (springs: 2 per spring)
            entries = sum(capacity.bucket(t.count) * (t.entry_count // max(t.count, 1)) for t in elements)
        if self.size_buckets:  # run.json says the arrays were bucketed, and to what
            rows = {"particle_capacity": self.particle_capacity}
            if self.rigid_count:
                rows["rigid_capacity"] = self.rigid_capacity
            if self.fluid_count:
                rows["fluid_capacity"] = self.fluid_capacity
            self.settings["size_buckets"] = rows
        self.work = sized + entries  # the size that decides fused frames (Stepper.frame_mode)
        self.serial = serial_loops(sized + entries // 8)

    def new_field(self, owner, role: str, dtype, shape, dims: tuple = ()):
        """A field for one of this model's parts or solvers (`owner` keeps it): from the pool under
        capacity buckets, so that a later scene of the same kind gets it back (capacity.take), else new."""
        if self.size_buckets:
            return capacity.take(owner, role, dtype, shape, dims)
        return capacity.make(dtype, shape, dims)

    def state(self) -> State:
        """A fresh State at t = 0: every kind's start (the builder's particles in place, every emitter
        slot dead)."""
        s = State(self)
        with bulk.batch():  # every kind's start in one launch (bulk.py)
            for kind in KINDS:
                kind.start_state(s, self)
        return s

    def prepare_colliders(self, t: float, h: float) -> None:
        """Per-step work of colliders that need it (a deforming mesh: its vertices at t and t + h [s] and
        its hierarchy refitted); nothing for the others."""
        for c in self._prepared_colliders:
            c.prepare(t, h)

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
            out["kinetic"] = self.particle_kinetic_energy(v)
        for term in self.terms:
            if term.has_energy:
                key = term.settings()["type"]
                out[key] = out.get(key, 0.0) + term.energy(x, m)
        return out

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


@data_oriented
class _ForceProbe:
    """Total forces from NumPy for tests and reports, with caches of its own (never a solver's)."""

    def __init__(self, model):
        self.model = model
        self.caches = model.make_caches()
        self.fields = tuple(model.particle_array(self, f"probe_{v}", dims=(3,)) for v in "xvf")

    def forces(self, x, v, t: float) -> np.ndarray:
        xf, vf, ff = self.fields
        bulk.fill([(xf, self.model.padded(x)), (vf, self.model.padded(v))])  # one launch (bulk.py)
        self._forces(self.model, xf, vf, ff, t)
        return ff.to_numpy()[: self.model.particle_count].astype(np.float64)

    @ti.kernel
    def _forces(
        self, model: ti.template(), xf: ti.template(), vf: ti.template(), ff: ti.template(), t: float
    ):
        model.element_pass(self.caches, xf, vf, t)
        for i in range(model.live_particles()):
            ff[i] = model.force(i, xf[i], vf[i], t) + model.element_force(self.caches, i)
