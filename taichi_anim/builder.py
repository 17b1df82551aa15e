"""Builder: collects what a scene has in plain Python and NumPy; `finalize()` allocates every Taichi
field once, exactly sized (Warp's `ModelBuilder.finalize()`). The engine is Y-up, SI units.

Each body kind's builder methods (`add_particles`, `add_particle_emitter`, `add_cloth_grid`, ...) come
from its part in bodies/; this file holds what acts on bodies: force terms, colliders, attachments and
the contact solvers' options."""

from __future__ import annotations

import inspect

import numpy as np

from . import validate
from .bodies import BUILDER_PARTS, KINDS
from .bodies.particles.builder import (
    CLOTH_GRID_BYTES_PER_VERTEX,
    PARTICLE_BYTES,
    TRAIL_SAMPLE_BYTES,
)
from .cloth import Cloth
from .collision import ColliderPlane, ColliderSolidBox, ColliderSphere, RigidMotion
from .collision.colliders import check_collider
from .collision.mesh_collider import make_collider_mesh
from .collision.motion import Attachment
from .collision.self_contact import self_contact_options
from .errors import ParameterError
from .model import Model
from .rng import SEED_LIMIT
from .runtime import ensure_initialized, np_float
from .terms import AnchorSpring, Drag, ElementTerm, Gravity, PointTerm
from .terms.aero import AeroTriangles
from .terms.base import check_protocol
from .terms.bending import BendingDihedral, mesh_hinges
from .terms.membrane import MembraneStVK

__all__ = ["CLOTH_GRID_BYTES_PER_VERTEX", "PARTICLE_BYTES", "TRAIL_SAMPLE_BYTES", "Builder"]

SPRING_BYTES = 250  # peak bytes per spring, measured as PARTICLE_BYTES (bodies/particles/builder.py)


class Builder(*BUILDER_PARTS):
    """Scene description: each body kind's bodies (particles, emitters, cloths, trails), force terms,
    colliders, attachments, contacts."""

    def __init__(self) -> None:
        for kind in KINDS:
            kind.init_builder(self)
        self._contacts: dict | None = None
        self._self_contact: dict | None = None
        self._containers: list[tuple[np.ndarray, np.ndarray]] = []
        self._gravity: tuple | None = None
        self._drag: list[tuple[float, tuple]] = []
        self._anchor_springs: list[tuple] = []
        self._anchored: set[int] = set()
        self._user_point_terms: list = []  # add_force(PointTerm), after the built-in pointwise terms
        self._colliders: list = []
        self._attachments: list[Attachment] = []
        # Element terms other than springs: factories called by finalize() with (particle count, positions).
        self._element_terms: list = []

    def add_force(self, term) -> None:
        """Add a user's force term (a PointTerm or ElementTerm subclass written in Taichi): see the
        guide's custom-forces page. An ElementTerm is made with the scene's final particle count
        (`builder.particle_count` after every add_particles/cloth; emitters' slots count too)."""
        if not isinstance(term, PointTerm | ElementTerm):
            raise ParameterError(f"term must be a PointTerm or ElementTerm instance, got {term!r}")
        check_protocol(term)  # a missing method or declaration fails here, naming it
        if term.coupled:
            self._element_terms.append(lambda n, x: _sized(term, n))
        else:
            self._user_point_terms.append(term)

    def add_collider(self, collider) -> None:
        """Add a user's collider (a `collision.colliders.Collider` subclass, e.g. of `ColliderAnalytic`
        with its `sdf`, `normal`, `velocity` and `sweep` as Taichi functions): checked now against the
        collider protocol (a missing method or attribute is a ParameterError naming it), then used like the
        built-in ones by the step, the watchdog and the USD export."""
        check_collider(collider)
        self._colliders.append(collider)

    def add_springs(self, pairs, *, stiffness, damping=0.0, rest_length=None) -> None:
        """Damped springs between particles (terms/springs.py): pairs (S,2) particle indices;
        stiffness [N/m] and damping [kg/s] scalars or (S,); rest_length [m] (S,), default the current
        distance. Springs count as the stretch family in reports."""
        n = self.particle_count
        p = validate.indices("pairs", pairs, 2, n, "particles").astype(np.int64)
        if np.any(p[:, 0] == p[:, 1]):
            raise ParameterError(
                f"pairs: spring {int(np.argmax(p[:, 0] == p[:, 1]))} joins a particle to itself"
            )
        x = np.concatenate(self._x)
        s = len(p)
        rest = np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=1) if rest_length is None else rest_length
        arrays = []
        for name, value in (("stiffness", stiffness), ("damping", damping), ("rest_length", rest)):
            a = validate.per_element(name, value, s, "spring")
            if not np.all(np.isfinite(a)) or np.any(a < 0):
                raise ParameterError(f"{name} must be finite and >= 0, got {value!r}")
            arrays.append(a)
        k, c, rest = arrays
        self._springs.append((p, rest, k, c, np.zeros(s, np.int8)))

    def add_force_membrane(self, cloth: Cloth, **options) -> None:
        """A StVK triangle membrane on `cloth` (terms/membrane.py), rest shape as added: youngs_modulus
        [N/m] (areal: Young's modulus times thickness), poisson_ratio in [0, 0.5), damping [s] (Rayleigh,
        stiffness-proportional); optional warp/weft anisotropy (youngs_warp, youngs_weft [N/m],
        shear_modulus [N/m], warp_direction)."""
        tri = self._cloth(cloth).triangles
        validate.options("membrane", options, inspect.signature(MembraneStVK).parameters)
        validate.positive("youngs_modulus", options.get("youngs_modulus", 1.0))
        validate.non_negative("damping", options.get("damping", 0.0))
        poisson = validate.non_negative("poisson_ratio", options.get("poisson_ratio", 0.0))
        if poisson >= 0.5:
            raise ParameterError(f"poisson_ratio must lie in [0, 0.5), got {poisson!r}")
        self._element_terms.append(lambda n, x: MembraneStVK(n, tri, x, **options))

    def add_force_bending(self, cloth: Cloth, *, stiffness: float, damping: float = 0.0) -> None:
        """Dihedral-angle bending on every interior edge of `cloth` (terms/bending.py): stiffness [N m]
        (a plate's E t^3 / (12 (1 - nu^2))), damping [s] (Rayleigh); rest angles from the rest shape."""
        validate.non_negative("stiffness", stiffness)
        validate.non_negative("damping", damping)
        hinges = mesh_hinges(self._cloth(cloth).triangles)
        if len(hinges) and stiffness > 0.0:
            self._element_terms.append(
                lambda n, x: BendingDihedral(n, hinges, x, stiffness=stiffness, damping=damping)
            )

    def add_force_aerodynamics(
        self,
        cloth: Cloth,
        *,
        wind=(0.0, 0.0, 0.0),
        density: float = 1.2,
        drag_coefficient: float = 1.0,
        lift_coefficient: float = 0.5,
        **options,
    ) -> None:
        """Per-triangle aerodynamic drag and lift on `cloth` against the air velocity `wind` [m/s]
        (terms/aero.py): air density [kg/m^3], dimensionless coefficients; options: gust_amplitude,
        gust_frequency [Hz]."""
        tri = self._cloth(cloth).triangles
        kw = dict(
            wind=wind,
            density=density,
            drag_coefficient=drag_coefficient,
            lift_coefficient=lift_coefficient,
            **options,
        )
        validate.options("aerodynamics", options, ("gust_amplitude", "gust_frequency"))
        validate.in_range("gust_amplitude", options.get("gust_amplitude", 0.0), 0.0, 1.0)
        validate.non_negative("gust_frequency", options.get("gust_frequency", 0.0))
        validate.vec3("wind", wind)
        validate.positive("density", density)
        validate.non_negative("drag_coefficient", drag_coefficient)
        validate.non_negative("lift_coefficient", lift_coefficient)
        self._element_terms.append(lambda n, x: AeroTriangles(n, tri, **kw))

    def add_force_gravity(self, g=(0.0, -9.81, 0.0)) -> None:
        """Uniform gravity g [m/s^2] (Y-up: the default pulls along -y)."""
        self._gravity = validate.vec3("g", g)

    def add_force_drag(self, coefficient: float) -> None:
        """Linear drag f = -k v, k [kg/s]."""
        self._drag.append((validate.non_negative("coefficient", coefficient), (0.0, 0.0, 0.0)))

    def add_force_wind(self, velocity, coefficient: float) -> None:
        """Wind: linear drag towards the air velocity, f = k (w - v); w [m/s], k [kg/s]."""
        self._drag.append(
            (validate.non_negative("coefficient", coefficient), validate.vec3("velocity", velocity))
        )

    def add_force_anchor_spring(
        self, particle: int, anchor, *, stiffness: float, rest_length: float = 0.0, damping: float = 0.0
    ) -> None:
        """Damped spring from `particle` to a fixed `anchor` [m]: stiffness [N/m], rest_length [m],
        damping [kg/s] along the spring. One spring per particle."""
        particle = int(validate.index_list("particle", [particle], self.particle_count)[0])
        if int(particle) in self._anchored:
            raise ParameterError(f"particle {particle} already has an anchor spring")
        self._anchor_springs.append(
            (
                int(particle),
                validate.vec3("anchor", anchor),
                validate.non_negative("stiffness", stiffness),
                validate.non_negative("rest_length", rest_length),
                validate.non_negative("damping", damping),
            )
        )
        self._anchored.add(int(particle))

    def add_collider_plane(
        self,
        normal=(0.0, 1.0, 0.0),
        offset: float = 0.0,
        *,
        restitution: float = 0.5,
        friction: float = 0.0,
        motion: RigidMotion | None = None,
    ) -> None:
        """Solid half-space {x : n.x < offset}; restitution in [0,1] scales the normal velocity; friction
        is the Coulomb coefficient on the impact impulse; motion: a RigidMotion that moves the plane
        (normal and offset are then in its frame), or None (static)."""
        self._colliders.append(
            ColliderPlane(
                validate.unit3("normal", normal),
                validate.finite("offset", offset),
                validate.in_range("restitution", restitution, 0.0, 1.0),
                validate.non_negative("friction", friction),
                _motion(motion),
            )
        )

    def add_collider_box(
        self,
        lo,
        hi,
        *,
        restitution: float = 0.5,
        friction: float = 0.0,
        solid: bool = False,
        motion: RigidMotion | None = None,
    ) -> None:
        """Axis-aligned box lo..hi [m]. solid=False: a container (six inward-facing planes that keep
        particles inside); solid=True: a solid block (a thin one is a slab) that keeps them out;
        motion: a RigidMotion that moves the box (lo, hi in its frame), or None (static)."""
        motion = _motion(motion)
        lo, hi = validate.box("add_collider_box", lo, hi)
        e = validate.in_range("restitution", restitution, 0.0, 1.0)
        mu = validate.non_negative("friction", friction)
        if validate.flag("solid", solid):
            self._colliders.append(ColliderSolidBox(tuple(lo), tuple(hi), e, mu, motion))
            return
        if motion is None:
            self._containers.append((lo, hi))  # a fixed domain for the sphere contacts' bounded grid
        for axis in range(3):
            n = np.zeros(3)
            n[axis] = 1.0
            self._colliders.append(ColliderPlane(tuple(n), lo[axis], e, mu, motion))
            self._colliders.append(ColliderPlane(tuple(-n), -hi[axis], e, mu, motion))

    def add_collider_sphere(
        self,
        center,
        radius: float,
        *,
        restitution: float = 0.5,
        friction: float = 0.0,
        motion: RigidMotion | None = None,
    ) -> None:
        """Solid ball of `radius` [m] at `center` [m]; restitution and Coulomb friction as for planes;
        motion: a RigidMotion that moves the ball (center in its frame), or None (static)."""
        self._colliders.append(
            ColliderSphere(
                validate.vec3("center", center),
                validate.positive("radius", radius),
                validate.in_range("restitution", restitution, 0.0, 1.0),
                validate.non_negative("friction", friction),
                _motion(motion),
            )
        )

    def add_collider_mesh(
        self,
        mesh,
        *,
        thickness: float = 0.0,
        restitution: float = 0.5,
        friction: float = 0.0,
        motion: RigidMotion | None = None,
        vertex_frames=None,
    ) -> None:
        """A triangle-mesh collider (collision/mesh_collider.py): mesh is an Open3D TriangleMesh (legacy or
        tensor), a file Open3D reads (PLY keeps vertex order, which vertex_frames rely on) or (vertices
        (V, 3) [m], faces (F, 3)). Particles stay thickness [m] + their radius from its triangles, outside
        it if it is closed (every edge shared by two consistently oriented faces), on either side if it is
        open; restitution in [0, 1] and Coulomb friction as for planes. motion: a RigidMotion (the mesh
        given in its frame), or vertex_frames = (times (K,) [s], positions (K, V, 3) [m]) for a deforming
        mesh (linear between frames, held outside them), or neither (static). Bad meshes (empty, non-finite,
        indices out of range, every face of zero area, an unreadable file) raise ParameterError."""
        self._colliders.append(
            make_collider_mesh(
                mesh,
                thickness=thickness,
                restitution=restitution,
                friction=friction,
                motion=motion,
                vertex_frames=vertex_frames,
            )
        )

    def add_attachment(
        self, particles, times=None, positions=None, *, motion: RigidMotion | None = None
    ) -> int:
        """Pinned particles (mass 0) that follow a target a user animates: keyframes `times` (K,) [s]
        strictly increasing and `positions` (K, P, 3) [m] for the P `particles` (model indices), linearly
        interpolated and held outside the range; or a RigidMotion `motion` that carries their positions
        as added rigidly. At the end of each step a particle is put on its target at t + h, with the
        velocity that reaches it, (target(t + h) - x(t)) / h. Returns the attachment's index."""
        idx = np.asarray(particles)
        if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
            raise ParameterError(
                f"particles must be a non-empty 1-D array of particle indices, got {particles!r}"
            )
        n = self.particle_count
        if idx.min() < 0 or idx.max() >= n:
            raise ParameterError(
                f"particles must be indices in [0, {n}), got values in [{idx.min()}, {idx.max()}]"
            )
        if len(np.unique(idx)) != len(idx):
            raise ParameterError("particles: an index appears twice")
        mass = np.concatenate(self._m)[idx]
        if np.any(mass != 0.0):
            k = int(idx[np.argmax(mass != 0.0)])
            raise ParameterError(
                f"particles: particle {k} is not pinned (mass {mass[np.argmax(mass != 0.0)]:g}); only mass-0 "
                f"particles can follow a target (pin them with mass=0 or a cloth's pinned=...)"
            )
        taken = set().union(*(set(a.particles.tolist()) for a in self._attachments))
        if taken & set(idx.tolist()):
            raise ParameterError(f"particles: particle {min(taken & set(idx.tolist()))} is already attached")
        if motion is not None:
            if times is not None or positions is not None:
                raise ParameterError("give either times and positions, or motion, not both")
            attachment = Attachment(idx, motion=_motion(motion), rest=np.concatenate(self._x)[idx])
        else:
            if times is None or positions is None:
                raise ParameterError("an attachment needs times and positions (keyframes), or a motion")
            attachment = Attachment(idx, times=times, positions=positions)
        self._attachments.append(attachment)
        return len(self._attachments) - 1

    def add_sphere_contacts(
        self,
        *,
        restitution: float = 0.5,
        friction: float = 0.0,
        iterations: int = 1,
        relaxation: float = 2.0,
        rest_speed: float = 0.05,
        continuous: bool = False,
        max_substeps: int = 256,
        neighbor_search: str = "auto",
    ) -> None:
        """Hard-sphere contacts between particles with radius > 0 (collision/spheres.py).

        restitution e in [0, 1] (the course's formula is e = 1/2) along the line of centres; friction:
        Coulomb coefficient; iterations: Jacobi sweeps of position projection per step (for piles, more
        substeps beat more iterations: the overlap a sweep leaves scales with dt^2); relaxation omega in
        [1, 2]: each pair's correction is scaled by min(1, omega / the mean of its two spheres' contact
        counts), the same on both sides, so momentum is conserved for any number of sweeps;
        rest_speed [m/s]: slower impacts do not bounce (so piles come to rest); continuous: substeps so
        fast spheres cannot pass through each other or a wall (at most max_substeps); neighbor_search:
        "auto" (brute force for small scenes, a grid over the container box if there is one, else a
        hashed grid), "brute", "grid", "hash_grid".
        """
        validate.choice("neighbor_search", neighbor_search, ["auto", "brute", "grid", "hash_grid"])
        self._contacts = dict(
            restitution=validate.in_range("restitution", restitution, 0.0, 1.0),
            friction=validate.non_negative("friction", friction),
            iterations=validate.count("iterations", iterations, 1),
            relaxation=validate.in_range("relaxation", relaxation, 1.0, 2.0),
            rest_speed=validate.non_negative("rest_speed", rest_speed),
            continuous=validate.flag("continuous", continuous),
            max_substeps=validate.count("max_substeps", max_substeps, 1),
            neighbor_search=neighbor_search,
        )

    def add_cloth_self_contact(
        self,
        *,
        thickness: float | None = None,
        friction: float = 0.0,
        iterations: int = 4,
        relaxation: float = 1.0,
        bound_fraction: float = 0.4,
        pairs_per_vertex: int = 128,
        guard: bool = True,
        broad_phase: str = "auto",
        start_crossings: str = "raise",
    ) -> None:
        """Contact between every cloth's triangles, within one cloth and between cloths
        (collision/self_contact.py): non-adjacent vertex-triangle and edge-edge pairs are kept
        `thickness` [m] apart (default: the largest cloth thickness), with Coulomb `friction`, by
        `iterations` Gauss-Seidel sweeps of proximity constraints (each pair's correction times
        `relaxation`), and per-vertex displacement bounds (a `bound_fraction` < 1/2 of the distance to the
        nearest primitive) let no step end with two triangles crossing. pairs_per_vertex: capacity of the
        candidate lists; guard=False leaves the bounds out (proximity only: cheaper, may cross);
        broad_phase: the box structure over triangles and edges, "auto" (brute force for small cloths, else
        a BVH), "brute", "grid", "octree" or "bvh". start_crossings: "raise" (a ParameterError naming the
        count and the first crossing pair when a State's first step starts with crossing triangles: the
        contact cannot untangle them, it would only keep them crossed) or "warn" (run anyway, with a
        warning and the count in `SelfContact.start_crossing_pairs`)."""
        if thickness is None:
            if not self.cloths:
                raise ParameterError("add_cloth_self_contact needs a cloth: add_cloth_grid/mesh first")
            radii = np.concatenate(self._r)
            thickness = max(float(radii[c.particles].max()) for c in self.cloths)
        self._self_contact = self_contact_options(
            thickness=thickness,
            friction=friction,
            iterations=iterations,
            relaxation=relaxation,
            bound_fraction=bound_fraction,
            pairs_per_vertex=pairs_per_vertex,
            guard=guard,
            broad_phase=broad_phase,
            start_crossings=start_crossings,
        )

    def finalize(self, *, seed: int = 0) -> Model:
        """Allocate the model's fields (initialises Taichi on the CPU if the application has not)."""
        seed = validate.count("seed", seed, 0, SEED_LIMIT - 1)
        if self.particle_count == 0 and not self._emitters and not self.rigid_count:
            raise ParameterError(
                "the scene is empty: add particles, an emitter or a rigid body before finalize()"
            )
        self._check_size()
        ensure_initialized()
        bodies, kind_settings = {}, {}
        for kind in KINDS:
            bodies[kind.name], kind_settings[kind.name] = kind.finalize(self)
        particles = bodies["particles"]  # every term and collider acts on particles
        x_all, v_all, m_all, r_all = (particles[k] for k in ("x", "v", "mass", "radius"))
        contacts = None
        if self._contacts is not None:
            if r_all.max() <= 0.0:
                raise ParameterError(
                    "add_sphere_contacts needs particles with radius > 0 (add_particles(radius=...) or "
                    "add_particle_emitter(particle_radius=...)); every radius is 0"
                )
            domain = self._contact_domain()
            if self._contacts["neighbor_search"] == "grid" and domain is None:
                raise ParameterError(
                    "neighbor_search='grid' needs a container (add_collider_box); use 'hash_grid' or 'auto'"
                )
            contacts = dict(self._contacts, domain=domain)
        terms: list = []
        if self._gravity is not None:
            terms.append(Gravity(self._gravity))
        terms += [Drag(k, w) for k, w in self._drag]
        if self._anchor_springs:
            terms.append(AnchorSpring(len(x_all), self._anchor_springs))
        terms += self._user_point_terms
        springs = None
        if self._springs:
            cols = list(zip(*self._springs, strict=True))
            springs = dict(
                pairs=np.concatenate(cols[0]),
                rest_length=np.concatenate(cols[1]),
                stiffness=np.concatenate(cols[2]),
                damping=np.concatenate(cols[3]),
                family=np.concatenate(cols[4]),
            )
        triangles = np.concatenate(self._triangles) if self._triangles else None
        if self._self_contact is not None and triangles is None:
            raise ParameterError("add_cloth_self_contact needs a cloth: add_cloth_grid or add_cloth_mesh")
        settings = {
            **kind_settings["particles"],
            **(kind_settings["rigid"] if self.rigid_count else {}),
            **kind_settings["fluid"],
            "forces": [t.settings() for t in terms],
            "colliders": [c.settings() for c in self._colliders],
            "attachments": [a.settings() for a in self._attachments],
            "trail_length": self._trail_length,
            "seed": seed,
        }
        element_terms = [make(len(x_all), x_all) for make in self._element_terms]
        # Every float the fields will hold must fit the precision they are allocated in (not become inf).
        validate.fits_float(
            dict(x=x_all, v=v_all, mass=m_all, radius=r_all, springs=springs or {}, forces=terms,
                 anchor_springs=self._anchor_springs, element_terms=element_terms, colliders=self._colliders,
                 emitters=settings["emitters"], attachments=self._attachments),
            np_float(),
        )  # fmt: skip
        validate.mass_fits("mass", m_all, np_float())
        return Model(
            bodies=bodies,
            terms=terms,
            colliders=self._colliders,
            seed=seed,
            settings=settings,
            contacts=contacts,
            springs=springs,
            element_terms=element_terms,
            triangles=triangles,
            self_contact=self._self_contact,
            attachments=self._attachments,
        )

    def _check_size(self) -> None:
        """Refuse, before allocating, a scene whose counts overflow the kernels' 32-bit indices or whose
        fields would not fit in the available memory."""
        n = self.particle_count + sum(es.capacity for es in self._emitters)
        springs = sum(len(s[0]) for s in self._springs)
        trail = self._trail_length
        validate.capacity("particles", n, bytes_each=0, unit="particles and emitter slots")
        validate.capacity("springs", 2 * springs, bytes_each=0, unit="spring ends")
        validate.capacity("trail length", n * trail, bytes_each=0, unit="trail samples (particles x length)")
        need = n * (PARTICLE_BYTES + trail * TRAIL_SAMPLE_BYTES) + springs * SPRING_BYTES
        what = f"{n} particles and emitter slots, {springs} springs and trails of {trail} samples"
        validate.memory_fits("finalize()", need, what)

    def _contact_domain(self):
        """The container box spheres live in (the bounded grid's domain), or None (hashed grid)."""
        if not self._containers:
            return None
        lo = np.min([c[0] for c in self._containers], axis=0)
        hi = np.max([c[1] for c in self._containers], axis=0)
        return lo, hi


def _motion(motion) -> RigidMotion | None:
    if motion is not None and not isinstance(motion, RigidMotion):
        raise ParameterError(f"motion must be a RigidMotion or None, got {motion!r}")
    return motion


def _sized(term, n: int):
    """A user's element term, checked against the scene's final particle count n (its adjacency was
    sized when it was made)."""
    made = getattr(term, "particle_count", n)
    if made != n:
        raise ParameterError(
            f"add_force: {type(term).__name__} was made for {made} particles, the scene has {n} "
            f"(make it after every add_particles / add_cloth_* / add_particle_emitter, with "
            f"builder.particle_count plus the emitters' capacities)"
        )
    return term
