"""The particle kind's builder part: particles, emitters, cloth vertices (a cloth is particles with
element terms between them) and trails. The Builder composes it (bodies/__init__.py); `finalize()`
takes the arrays from `particle_arrays()`."""

from __future__ import annotations

import math

import numpy as np

from ... import geometry, validate
from ...cloth import Cloth, ClothMaterial, FabricMaterial
from ...errors import ParameterError
from ...particles import Emitter, EmitterShape
from ...particles.emitters import EmitterSettings

# Peak memory [bytes] that finalize() and model.state() add per element (NumPy staging and the Taichi
# fields, f32; f64 needs more), measured as the growth of the peak resident size for 10^6 particles,
# 10^6 emitter slots, 6 x 10^6 springs and cloth grids of 500^2 and 1000^2 vertices. Capacities are
# checked against them before anything is allocated: honest figures, so that real scenes (10^7
# particles need ~1.4 GB) still pass while absurd ones fail at once instead of after minutes of swapping.
PARTICLE_BYTES = 140
TRAIL_SAMPLE_BYTES = 48  # float64 staging, its float32 copy and the field: 4 + 4 + 4 floats per sample
# A grid cloth, all told (NumPy grid, springs and checks, then finalize()): 2.1-2.3 kB measured.
CLOTH_GRID_BYTES_PER_VERTEX = 2000


class ParticleBuilder:
    """Builder methods of the particle kind: add_particles, add_particle, add_particle_emitter,
    add_cloth_grid, add_cloth_mesh, add_particle_trails. The cloth methods add their element terms
    through the Builder's add_force_* methods."""

    def _init_particles(self) -> None:
        self._x: list[np.ndarray] = []
        self._v: list[np.ndarray] = []
        self._m: list[np.ndarray] = []
        self._r: list[np.ndarray] = []
        self._emitters: list[EmitterSettings] = []
        self._trail_length = 0
        self._springs: list[tuple] = []  # (pairs, rest, stiffness, damping, family) per add_springs / cloth
        self._triangles: list[np.ndarray] = []
        self.cloths: list[Cloth] = []

    @property
    def particle_count(self) -> int:
        """Particles added so far (emitter slots not included)."""
        return sum(len(a) for a in self._x)

    def add_particles(self, x, v=None, mass=1.0, *, radius=0.0) -> range:
        """Add particles: x (N,3) [m], v (N,3) [m/s] (default 0), mass [kg] scalar or (N,); mass 0 pins
        a particle; radius [m] scalar or (N,) (0: a point; > 0: a hard sphere for sphere contacts and
        colliders). Returns their indices."""
        x = validate.finite_array("x", np.atleast_2d(x), (3,))
        validate.capacity("x", self.particle_count + len(x), bytes_each=0, unit="particles in the scene")
        v = np.zeros_like(x) if v is None else validate.finite_array("v", np.atleast_2d(v), (3,))
        if v.shape != x.shape:
            raise ParameterError(f"v must have the shape of x {x.shape}, got {v.shape}")
        m = validate.per_element("mass", mass, len(x))
        if not np.all(np.isfinite(m)) or np.any(m < 0):
            raise ParameterError(f"mass must be finite and >= 0 (0 pins a particle), got {mass!r}")
        r = validate.per_element("radius", radius, len(x))
        if not np.all(np.isfinite(r)) or np.any(r < 0):
            raise ParameterError(f"radius must be finite and >= 0, got {radius!r}")
        start = self.particle_count
        self._x.append(x)
        self._v.append(v)
        self._m.append(m)
        self._r.append(r)
        return range(start, start + len(x))

    def add_particle(self, x, v=(0.0, 0.0, 0.0), mass: float = 1.0, *, radius: float = 0.0) -> int:
        """Add one particle and return its index."""
        return self.add_particles([x], [v], mass, radius=radius)[0]

    def add_cloth_grid(
        self,
        *,
        origin=(0.0, 0.0, 0.0),
        size=(1.0, 1.0),
        resolution=(32, 32),
        plane: str = "xz",
        material: ClothMaterial | FabricMaterial | None = None,
        thickness: float = 0.005,
        pinned=(),
        velocity=(0.0, 0.0, 0.0),
    ) -> Cloth:
        """A rectangular cloth: resolution (nx, ny) vertices over size (w, h) [m] from origin [m], in the
        "xz" plane (horizontal; vertex (i, j) at origin + (i w/(nx-1), 0, j h/(ny-1))) or "xy" (vertical);
        vertex (i, j) is particle start + j nx + i. A ClothMaterial gives springs in Provot's grid layout,
        a FabricMaterial a StVK membrane and dihedral bending instead; mass from the
        material's areal density; thickness [m]: collision radius of each vertex; pinned: grid vertex
        indices j nx + i that keep their velocity (kinematic); velocity [m/s] of every vertex at t = 0."""
        res = tuple(validate.count("resolution", r, 2) for r in np.atleast_1d(resolution))
        if len(res) != 2:
            raise ParameterError(f"resolution must be (nx, ny), got {resolution!r}")
        sz = np.asarray(size, dtype=np.float64).reshape(-1)
        if sz.shape != (2,) or not np.all(np.isfinite(sz)) or np.any(sz <= 0):
            raise ParameterError(f"size must be two finite lengths > 0 [m], got {size!r}")
        validate.choice("plane", plane, ["xz", "xy"])
        _check_grid_size(res)  # before NumPy builds anything: 10^4 x 10^4 would take minutes to fail
        vertices, triangles = geometry.cloth_grid(
            origin=validate.vec3("origin", origin), size=tuple(sz), resolution=res, plane=plane
        )
        springs = geometry.grid_springs(res)
        return self._add_cloth(vertices, triangles, springs, material, thickness, pinned, velocity)

    def add_cloth_mesh(
        self,
        mesh,
        *,
        material: ClothMaterial | FabricMaterial | None = None,
        thickness: float = 0.005,
        pinned=(),
        velocity=(0.0, 0.0, 0.0),
    ) -> Cloth:
        """A cloth from a triangle mesh: an Open3D TriangleMesh (legacy or tensor), a file Open3D reads
        (PLY keeps vertex order, so pin indices stay valid), or (vertices (V,3) [m], triangles (F,3)).
        Stretch springs on the edges; across each interior edge a shear spring where the edge is the
        diagonal of a split quad, else a bend spring. Bad meshes (empty, NaN, duplicate vertices,
        zero-area triangles, non-manifold edges, unused vertices) raise ParameterError."""
        vertices, triangles = geometry.load_mesh(mesh)
        used = np.zeros(len(vertices), dtype=bool)
        used[triangles.reshape(-1)] = True
        if not used.all():
            raise ParameterError(
                f"mesh: vertex {int(np.argmin(used))} is in no triangle ({int((~used).sum())} unused "
                f"vertices); a cloth vertex needs a triangle for its mass"
            )
        springs = geometry.mesh_springs(vertices, triangles)
        return self._add_cloth(vertices, triangles, springs, material, thickness, pinned, velocity)

    def _add_cloth(self, vertices, triangles, springs, material, thickness, pinned, velocity) -> Cloth:
        material = ClothMaterial() if material is None else material
        if not isinstance(material, ClothMaterial | FabricMaterial):
            raise ParameterError(f"material must be a ClothMaterial or a FabricMaterial, got {material!r}")
        thickness = validate.positive("thickness", thickness)
        nv = len(vertices)
        pin = np.unique(validate.index_list("pinned", pinned, nv, "cloth vertices"))
        mass = geometry.lumped_masses(vertices, triangles, material.density)
        mass[pin] = 0.0  # inverse mass 0: the vertex is kinematic
        v = np.tile(np.asarray(validate.vec3("velocity", velocity)), (nv, 1))
        idx = self.add_particles(vertices, v, mass, radius=thickness)
        start = idx.start
        pairs = springs.pairs
        rest = np.linalg.norm(vertices[pairs[:, 0]] - vertices[pairs[:, 1]], axis=1)
        tri = triangles.astype(np.int64) + start
        self._triangles.append(tri)
        cloth = Cloth(particles=idx, triangles=tri, pinned=pin + start)
        self.cloths.append(cloth)
        if isinstance(material, FabricMaterial):
            self.add_force_membrane(cloth, **material.membrane_options())
            if material.bending_stiffness > 0.0:
                self.add_force_bending(
                    cloth, stiffness=material.bending_stiffness, damping=material.bending_damping
                )
            return cloth
        pairs = springs.pairs
        rest = np.linalg.norm(vertices[pairs[:, 0]] - vertices[pairs[:, 1]], axis=1)
        k, c = material.family_arrays(springs.family)
        keep = k > 0.0  # a family of stiffness 0 adds nothing: leave its springs out
        self._springs.append((pairs[keep] + start, rest[keep], k[keep], c[keep], springs.family[keep]))
        return cloth

    def _cloth(self, cloth) -> Cloth:
        if not isinstance(cloth, Cloth) or not any(c is cloth for c in self.cloths):
            raise ParameterError(
                f"cloth must be a Cloth returned by this builder's add_cloth_*, got {cloth!r}"
            )
        return cloth

    def add_particle_emitter(
        self,
        *,
        capacity: int,
        rate: float,
        shape: EmitterShape | str = EmitterShape.POINT,
        center=(0.0, 0.0, 0.0),
        radius: float = 0.0,
        half_extents=(0.0, 0.0, 0.0),
        direction=(0.0, 1.0, 0.0),
        speed: float = 1.0,
        speed_jitter: float = 0.0,
        spread: float = 0.0,
        lifetime: float = 1.0,
        lifetime_jitter: float = 0.0,
        mass: float = 1.0,
        particle_radius: float = 0.0,
        color_start=(1.0, 0.9, 0.3),
        color_end=(0.8, 0.1, 0.05),
    ) -> int:
        """Add an emitter with its own pool of `capacity` slots (Reeves 1983).

        rate [particles/s]; shape point/disc/sphere/box; radius [m] (disc, sphere); half_extents [m] (box);
        direction: mean velocity direction (disc normal); speed [m/s] with relative speed_jitter; spread:
        cone half-angle [rad]; lifetime [s] with relative lifetime_jitter; mass [kg]; particle_radius [m]
        (0: points, > 0: hard spheres); colours RGB in [0,1]
        at birth and death. Returns the emitter index.
        """
        try:
            shape = EmitterShape(shape) if isinstance(shape, str) else shape
        except ValueError:
            validate.choice("emitter shape", shape, [s.value for s in EmitterShape])
        capacity = validate.count("capacity", capacity, 1)
        validate.capacity("capacity", capacity, bytes_each=PARTICLE_BYTES, unit="emitter slots")
        size = (validate.non_negative("radius", radius), 0.0, 0.0)
        if shape == EmitterShape.BOX:
            size = validate.vec3("half_extents", half_extents)
            if min(size) < 0:
                raise ParameterError(f"half_extents must be >= 0, got {half_extents!r}")
        settings = EmitterSettings(
            shape=shape,
            center=validate.vec3("center", center),
            size=size,
            direction=validate.unit3("direction", direction),
            rate=validate.non_negative("rate", rate),
            speed=validate.non_negative("speed", speed),
            speed_jitter=validate.in_range("speed_jitter", speed_jitter, 0.0, 1.0),
            spread=validate.in_range("spread", spread, 0.0, math.pi),
            lifetime=validate.positive("lifetime", lifetime),
            lifetime_jitter=validate.in_range("lifetime_jitter", lifetime_jitter, 0.0, 1.0),
            mass=validate.positive("mass", mass),
            particle_radius=validate.non_negative("particle_radius", particle_radius),
            capacity=capacity,
            color_start=tuple(float(c) for c in validate.colors("color_start", [color_start], 1)[0]),
            color_end=tuple(float(c) for c in validate.colors("color_end", [color_end], 1)[0]),
        )
        self._emitters.append(settings)
        return len(self._emitters) - 1

    def add_particle_trails(self, length: int) -> None:
        """Keep the last `length` positions of every particle (exported as line sets)."""
        self._trail_length = validate.count("length", length, 2)

    def particle_arrays(self) -> tuple:
        """Every particle slot for finalize(): positions x (N,3) [m], velocities v (N,3) [m/s], masses
        (N,) [kg], radii (N,) [m] (added particles first, then each emitter's slots, dead at t = 0 at
        its centre), and the emitters made over their slot ranges."""
        # a scene of rigid bodies only has no particles: empty arrays, and the kind allocates nothing
        x, v, m, r = (
            [np.zeros((0, 3)), *self._x],
            [np.zeros((0, 3)), *self._v],
            [np.zeros(0), *self._m],
            [np.zeros(0), *self._r],
        )
        start = self.particle_count
        emitters = []
        for k, es in enumerate(self._emitters):
            emitters.append(Emitter(es, start, k))
            x.append(np.tile(es.center, (es.capacity, 1)))
            v.append(np.zeros((es.capacity, 3)))
            m.append(np.full(es.capacity, es.mass))
            r.append(np.full(es.capacity, es.particle_radius))
            start += es.capacity
        return np.concatenate(x), np.concatenate(v), np.concatenate(m), np.concatenate(r), emitters

    def particle_settings(self, emitters) -> dict:
        """What run.json records of the particle kind."""
        return {
            "particles": self.particle_count,
            "cloths": [
                {"vertices": len(c.particles), "triangles": len(c.triangles), "pinned": len(c.pinned)}
                for c in self.cloths
            ],
            "emitters": [e.settings() for e in emitters],
        }


def _check_grid_size(res: tuple[int, int]) -> None:
    """Refuse a cloth grid of `res` vertices whose springs or triangles overflow 32-bit indices or whose
    construction would not fit in the available memory."""
    nx, ny = res
    springs = (nx - 1) * ny + nx * (ny - 1) + 2 * (nx - 1) * (ny - 1) + (nx - 2) * ny + nx * (ny - 2)
    name = f"resolution {res}"
    validate.capacity(name, 2 * springs, bytes_each=0, unit="spring ends")
    validate.capacity(name, 6 * (nx - 1) * (ny - 1), bytes_each=0, unit="triangle corners")
    validate.capacity(name, nx * ny, bytes_each=CLOTH_GRID_BYTES_PER_VERTEX, unit="cloth vertices")
