"""Rigid-body shapes and their exact mass properties (`ta.shapes`).

Every shape is given in its own frame (the frame `Builder.add_rigid_body(position=, orientation=)`
places) and answers `mass_properties(density)`: the mass, the centre of mass in that frame and the
inertia tensor about the centre of mass, in closed form:
- sphere, box: the textbook integrals;
- capsule (a cylinder along the shape's y axis with two hemispherical caps): the cylinder plus the two
  caps moved by the parallel-axis theorem (each cap's centre of mass is 3r/8 from its flat face);
- compound: the sum of its parts, each turned and moved (R I R^T, then the parallel-axis theorem);
- convex hull and closed triangle mesh: the volume integrals of 1, x, y, z, x^2, ..., zx turned into
  sums over the surface triangles by the divergence theorem (Mirtich, "Fast and Accurate Computation of
  Polyhedral Mass Properties", JGT 1996; in the per-triangle form of Eberly, "Polyhedral Mass
  Properties (Revisited)", 2002/2009).
`triangles()` gives a triangle mesh of the shape (what output draws; exact for hulls and meshes)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import validate
from .errors import ParameterError
from .rotations import quat_to_matrix


@dataclass(frozen=True)
class MassProperties:
    """mass [kg], com (3,) [m] in the shape's frame, inertia (3,3) [kg m^2] about the com, axes of the
    shape's frame."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray


class Shape:
    """A rigid body's geometry in its own frame."""

    kind = "shape"

    def mass_properties(self, density: float) -> MassProperties:
        """Mass, centre of mass and inertia of the shape filled at `density` [kg/m^3]."""
        raise NotImplementedError

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (V,3) [m], faces (F,3) int, counter-clockwise seen from outside)."""
        raise NotImplementedError

    def settings(self) -> dict:
        """The shape's parameters, for run.json."""
        raise NotImplementedError

    def contact_parts(self):
        """The convex parts the shape collides as, [(convex shape, position (3,), rotation (3,3))] in its
        frame, or None when it collides as itself (its convex hull)."""
        return None

    def contact_prisms(self):
        """The triangle prisms the shape collides as, (T,6,3) in its frame (each surface triangle, then
        the same triangle moved inwards), or None."""
        return None


def _positive(name: str, value) -> float:
    return validate.positive(name, value)


@dataclass(frozen=True, init=False)
class Sphere(Shape):
    """A ball of `radius` [m] centred on the origin."""

    radius: float
    kind = "sphere"

    def __init__(self, radius: float):
        object.__setattr__(self, "radius", _positive("radius", radius))

    def mass_properties(self, density: float) -> MassProperties:
        r = self.radius
        m = _positive("density", density) * 4.0 / 3.0 * np.pi * r**3
        return MassProperties(m, np.zeros(3), np.eye(3) * 0.4 * m * r * r)

    def triangles(self):
        return uv_sphere(np.zeros(3), self.radius, rings=12, segments=24)

    def settings(self) -> dict:
        return {"shape": "sphere", "radius": self.radius}


@dataclass(frozen=True, init=False)
class Box(Shape):
    """A box of `half_extents` (3,) [m] centred on the origin, edges along the axes."""

    half_extents: tuple
    kind = "box"

    def __init__(self, half_extents):
        h = validate.vec3("half_extents", half_extents)
        for c in h:
            _positive("half_extents", c)
        object.__setattr__(self, "half_extents", tuple(float(c) for c in h))

    def mass_properties(self, density: float) -> MassProperties:
        a, b, c = self.half_extents
        m = _positive("density", density) * 8.0 * a * b * c
        inertia = np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 3.0
        return MassProperties(m, np.zeros(3), inertia)

    def triangles(self):
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        faces = np.array(
            [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
        )  # fmt: skip
        return corners * np.asarray(self.half_extents), faces

    def settings(self) -> dict:
        return {"shape": "box", "half_extents": list(self.half_extents)}


@dataclass(frozen=True, init=False)
class Capsule(Shape):
    """A cylinder of `radius` [m] from y = -half_length to y = +half_length [m], capped by hemispheres
    (Y up, as Jolt's and Bullet's default capsules)."""

    radius: float
    half_length: float
    kind = "capsule"

    def __init__(self, radius: float, half_length: float):
        object.__setattr__(self, "radius", _positive("radius", radius))
        object.__setattr__(self, "half_length", _positive("half_length", half_length))

    def mass_properties(self, density: float) -> MassProperties:
        rho, r, h = _positive("density", density), self.radius, self.half_length
        m_cyl = rho * np.pi * r * r * 2.0 * h
        m_caps = rho * 4.0 / 3.0 * np.pi * r**3
        axial = 0.5 * m_cyl * r * r + 0.4 * m_caps * r * r
        # A cap about its own centre of mass (3r/8 from the flat face), moved to the capsule's centre:
        # (2/5 r^2 - (3r/8)^2) + (h + 3r/8)^2 = 2/5 r^2 + h^2 + 3 h r / 4, per unit mass.
        side = m_cyl * (r * r / 4.0 + (2.0 * h) ** 2 / 12.0) + m_caps * (0.4 * r * r + h * h + 0.75 * h * r)
        return MassProperties(m_cyl + m_caps, np.zeros(3), np.diag([side, axial, side]))

    def triangles(self):
        v, f = uv_sphere(np.zeros(3), self.radius, rings=12, segments=24)
        v = v.copy()
        v[:, 1] += np.where(v[:, 1] >= 0.0, self.half_length, -self.half_length)  # split at the equator
        return v, f

    def settings(self) -> dict:
        return {"shape": "capsule", "radius": self.radius, "half_length": self.half_length}


MESH_CONTACTS = ("hull", "parts", "triangles")
# Triangles a mesh may collide as (contact="triangles"): its tree of prisms stays 20 levels deep at most.
MAX_CONTACT_TRIANGLES = 1 << 20


class Mesh(Shape):
    """A closed triangle mesh: vertices (V,3) [m] and faces (F,3), counter-clockwise seen from outside
    (a watertight, consistently oriented surface: its mass properties are those of the volume inside).

    contact: what it collides as. "hull" (default, as MuJoCo's mesh geoms): its convex hull. "parts":
    convex parts from an approximate convex decomposition, CoACD (Wei et al., "Approximate Convex
    Decomposition for 3D Meshes with Collision-Aware Concavity and Tree Search", SIGGRAPH 2022; what
    Genesis's convexify and MuJoCo's model tools use), so that a bowl holds what falls in it and a ring
    fits on a peg; `threshold` is CoACD's concavity bound (a fraction of the mesh's size: smaller, more
    parts, closer to the surface), `max_parts` caps the parts (None: no cap) and `part_vertices` the
    vertices of each (CoACD's decimation; None: up to 256). The exact test between two parts costs about
    the product of their edge counts: a chain of 20 interlocked rings found its contacts in 39 ms with
    the parts' own 34-59 vertices, 24.5 ms with 32 and 7.8 ms with 16, the default
    (benchmarks/rigid_cascade.py). It takes seconds, once, when the shape is made (a 576-triangle torus:
    12 parts in about 2 s). "triangles" (as Bullet's and Jolt's mesh shapes): its own surface, each
    triangle a prism reaching `thickness` [m] inwards from it (None: per triangle, half the way to the
    surface opposite it along its normal, and no deeper than its longest edge), so that what sinks into
    the surface is pushed back out the way it came; the prisms sit in a tree of oriented bounding boxes
    (bodies/rigid/obb_tree.py). Its mass properties are the mesh's own in every case."""

    kind = "mesh"

    def __init__(
        self,
        vertices,
        faces,
        *,
        contact: str = "hull",
        threshold: float = 0.05,
        max_parts=None,
        part_vertices=16,
        thickness=None,
    ):
        v = np.array(vertices, dtype=np.float64)
        f = np.array(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise ParameterError(f"vertices must be (V,3) with V >= 4, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4:
            raise ParameterError(f"faces must be (F,3) with F >= 4, got shape {f.shape}")
        if not np.all(np.isfinite(v)):
            raise ParameterError("vertices must be finite")
        if f.min() < 0 or f.max() >= len(v):
            raise ParameterError(f"faces index vertices 0..{len(v) - 1}, got {f.min()}..{f.max()}")
        _check_closed(f)
        self.vertices, self.faces = v, f
        self.vertices.setflags(write=False)
        self.faces.setflags(write=False)
        if polyhedron_integrals(v, f)[0] <= 0.0:
            raise ParameterError(
                "the mesh encloses no volume or its faces wind clockwise seen from outside (reverse them)"
            )
        self.contact = validate.choice("contact", contact, MESH_CONTACTS)
        self.threshold = validate.in_range("threshold", threshold, 0.01, 1.0)  # CoACD's documented range
        if max_parts is not None:
            max_parts = validate.count("max_parts", max_parts, 1, MAX_COMPOUND_PARTS)
        self.max_parts = max_parts
        if part_vertices is not None:
            part_vertices = validate.count("part_vertices", part_vertices, 4, 256)
        self.part_vertices = part_vertices
        if thickness is not None:
            thickness = validate.positive("thickness", thickness)
        self.thickness = thickness
        if self.contact == "triangles" and len(f) > MAX_CONTACT_TRIANGLES:
            raise ParameterError(
                f"contact='triangles': {len(f)} faces exceed {MAX_CONTACT_TRIANGLES} (decimate the mesh)"
            )
        # computed here, once: a decomposition that fails says so when the shape is made
        self._parts = self._convex_parts() if self.contact == "parts" else None

    def mass_properties(self, density: float) -> MassProperties:
        return polyhedron_mass_properties(self.vertices, self.faces, _positive("density", density))

    def triangles(self):
        return self.vertices, self.faces

    def contact_parts(self):
        """Its convex parts (contact="parts": CoACD's decomposition), else None."""
        return self._parts

    def contact_prisms(self):
        """Its triangles as prisms (contact="triangles"), else None: (T,6,3), each triangle's corners
        then the same corners moved `thickness` inwards along its normal; degenerate triangles have
        none."""
        if self.contact != "triangles":
            return None
        keep, n, edges = self._triangles_kept()
        tri, n, edges = self.vertices[self.faces[keep]], n[keep], edges[keep]
        if self.thickness is not None:
            depth = np.full(len(tri), float(self.thickness))
        else:
            depth = self._inner_depth(tri, n, edges, np.flatnonzero(keep))
        return np.concatenate([tri, tri - depth[:, None, None] * n[:, None, :]], axis=1)

    def contact_active_edges(self):
        """Per triangle of contact_prisms() (T,3) bool: whether its edge k (corner k to corner k + 1)
        is a convex crease, the neighbour across it turned away by more than 1 degree (Bullet's and
        Jolt's active edges); None unless contact="triangles". A contact normal may point out of a
        triangle's side only across an active edge: a flat or concave neighbour lies there."""
        if self.contact != "triangles":
            return None
        keep, n, _ = self._triangles_kept()
        v, f = self.vertices, self.faces
        # each directed edge (a, b) of a closed, consistently wound mesh has its twin (b, a) in the neighbour
        twin = {}
        for t, face in enumerate(f):
            for k in range(3):
                twin[(int(face[k]), int(face[(k + 1) % 3]))] = t
        active = np.zeros((len(f), 3), dtype=bool)
        for t, face in enumerate(f):
            for k in range(3):
                a, b = int(face[k]), int(face[(k + 1) % 3])
                other = twin.get((b, a), -1)
                if other < 0:
                    active[t, k] = True
                    continue
                far = [x for x in f[other] if x not in (a, b)][0]
                below = n[t] @ (v[far] - v[a]) < 0.0  # the neighbour bends away: convex
                active[t, k] = bool(below and n[t] @ n[other] < np.cos(np.radians(1.0)))
        return active[keep]

    def _triangles_kept(self):
        """(which faces are no sliver (F,) bool, their unit normals (F,3), their longest edges (F,))."""
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area2 = np.linalg.norm(n, axis=1)
        edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
        return area2 > 1e-12 * edges**2, n / np.maximum(area2, 1e-300)[:, None], edges

    def _inner_depth(self, tri, n, edges, faces) -> np.ndarray:
        """Per triangle (face index `faces`), half the distance to the surface opposite it (rays cast
        inwards along -n from its centroid and from points near its corners; the least hit), at most its
        longest edge: a prism that stays inside the mesh, and compact. Open3D casts in float32: the rays
        start a few float32 steps inside, and a hit on the triangle itself does not count."""
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor(self.vertices.astype(np.float32)), o3d.core.Tensor(self.faces.astype(np.uint32))
        )
        centroid = tri.mean(axis=1)
        starts = [centroid] + [0.9 * tri[:, k] + 0.1 * centroid for k in range(3)]
        size = float(np.abs(self.vertices).max())
        offset = (1e-6 * edges + 64 * np.finfo(np.float32).eps * size)[:, None]
        hits = []
        for s in starts:
            rays = np.concatenate([s - offset * n, -n], axis=1).astype(np.float32)
            cast = scene.cast_rays(o3d.core.Tensor(rays))
            t = cast["t_hit"].numpy().astype(np.float64)
            own = cast["primitive_ids"].numpy().astype(np.int64) == faces
            hits.append(np.where(np.isfinite(t) & ~own, t + offset[:, 0], np.inf))
        return np.minimum(0.5 * np.min(hits, axis=0), edges)

    def _convex_parts(self) -> tuple:
        hulls = []
        for v in self._decompose():
            try:
                hulls.append((ConvexHull(v), np.zeros(3), np.eye(3)))
            except ParameterError:  # a flat sliver of the decomposition holds no volume: no part
                pass
        if not hulls:
            raise ParameterError("the convex decomposition of the mesh found no part with a volume")
        return tuple(hulls)

    def _decompose(self) -> list:
        """The vertices of each convex part CoACD finds (deterministic: a fixed seed)."""
        # Open3D first: imported after coacd's libraries are loaded, it fails (std::bad_cast).
        import open3d  # noqa: F401, I001
        import coacd

        coacd.set_log_level("error")
        parts = coacd.run_coacd(
            coacd.Mesh(self.vertices, self.faces),
            threshold=self.threshold,
            max_convex_hull=-1 if self.max_parts is None else self.max_parts,
            decimate=self.part_vertices is not None,
            max_ch_vertex=256 if self.part_vertices is None else self.part_vertices,
            seed=0,
        )
        return [np.asarray(v, dtype=np.float64) for v, _ in parts]

    def settings(self) -> dict:
        out = {"shape": self.kind, "vertices": len(self.vertices), "faces": len(self.faces)}
        if self.contact == "parts":
            out.update(contact="parts", threshold=self.threshold, max_parts=self.max_parts)
            out["part_vertices"] = self.part_vertices
            out["parts"] = len(self.contact_parts())
        if self.contact == "triangles":
            out.update(contact="triangles", thickness=self.thickness)
        return out


class ConvexHull(Mesh):
    """The convex hull of `points` (N,3) [m] (Qhull, through Open3D)."""

    kind = "convex_hull"

    def __init__(self, points):
        p = np.array(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 4 or not np.all(np.isfinite(p)):
            raise ParameterError(f"points must be finite (N,3) with N >= 4, got shape {p.shape}")
        import open3d as o3d

        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
        try:
            hull, _ = cloud.compute_convex_hull()
        except RuntimeError as e:  # Qhull refuses flat or degenerate sets
            raise ParameterError(f"points span no volume: {e}") from None
        v, f = np.asarray(hull.vertices), np.asarray(hull.triangles)
        if polyhedron_integrals(v, f)[0] < 0.0:
            f = f[:, ::-1]
        super().__init__(v, f)


MAX_COMPOUND_PARTS = 4096


class Compound(Shape):
    """Several convex shapes (Sphere, Box, Capsule, ConvexHull) held rigidly together: `parts` is a list
    of (shape, position (3,) [m], orientation (x, y, z, w)) placing each part in the compound's frame, as
    Bullet's compound shape and MuJoCo's geoms of one body. Each part collides as itself (a non-convex
    body made of convex parts); the parts may overlap, and their overlap counts twice in the mass (as in
    Bullet, PhysX and MuJoCo, which sum their parts)."""

    kind = "compound"

    def __init__(self, parts):
        if isinstance(parts, (str, bytes)) or not hasattr(parts, "__len__"):
            raise ParameterError(f"parts must be a list of (shape, position, orientation), got {parts!r}")
        if not 1 <= len(parts) <= MAX_COMPOUND_PARTS:
            raise ParameterError(f"parts must hold 1..{MAX_COMPOUND_PARTS} parts, got {len(parts)}")
        placed = []
        for k, part in enumerate(parts):
            if not isinstance(part, (tuple, list)) or len(part) != 3:
                raise ParameterError(f"parts[{k}] must be (shape, position, orientation), got {part!r}")
            shape, position, orientation = part
            if not isinstance(shape, (Sphere, Box, Capsule, ConvexHull)):
                raise ParameterError(
                    f"parts[{k}] must be a Sphere, Box, Capsule or ConvexHull (a convex part), got {shape!r}"
                )
            q = validate.finite_array(f"parts[{k}] orientation", np.asarray(orientation, dtype=np.float64))
            if q.shape != (4,) or not 0.9 < np.linalg.norm(q) < 1.1:
                raise ParameterError(f"parts[{k}] orientation must be a unit quaternion (x, y, z, w): {q}")
            t = np.asarray(validate.vec3(f"parts[{k}] position", position), dtype=np.float64)
            placed.append((shape, t, quat_to_matrix(q / np.linalg.norm(q))))
        self.parts = tuple(placed)

    def mass_properties(self, density: float) -> MassProperties:
        props = [(shape.mass_properties(density), t, r) for shape, t, r in self.parts]
        m = sum(p.mass for p, _, _ in props)
        c = sum(p.mass * (t + r @ p.com) for p, t, r in props) / m
        inertia = np.zeros((3, 3))
        for p, t, r in props:
            d = t + r @ p.com - c
            # each part's inertia turned into the compound's axes, then moved to its centre of mass
            inertia += r @ p.inertia @ r.T + p.mass * (d @ d * np.eye(3) - np.outer(d, d))
        return MassProperties(float(m), c, inertia)

    def triangles(self):
        vertices, faces, start = [], [], 0
        for shape, t, r in self.parts:
            v, f = shape.triangles()
            vertices.append(np.asarray(v) @ r.T + t)
            faces.append(np.asarray(f) + start)
            start += len(v)
        return np.vstack(vertices), np.vstack(faces)

    def settings(self) -> dict:
        parts = [{**p.settings(), "position": t.tolist(), "rotation": r.tolist()} for p, t, r in self.parts]
        return {"shape": "compound", "parts": parts}

    def contact_parts(self):
        return self.parts


def _check_closed(faces: np.ndarray) -> None:
    """Each undirected edge in exactly two faces, once in each direction (closed and oriented)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    directed = np.unique(e, axis=0, return_counts=True)[1]
    undirected = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)[1]
    if directed.max() > 1 or np.any(undirected != 2):
        raise ParameterError(
            "the mesh must be closed and consistently oriented: every edge shared by exactly two faces, "
            "in opposite directions"
        )


def polyhedron_integrals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The volume integrals of (1, x, y, z, x^2, y^2, z^2, xy, yz, zx) over a closed, outward-wound
    triangle mesh (Eberly 2002, "Polyhedral Mass Properties (Revisited)": per triangle, the divergence
    theorem with the subexpressions f1, f2, f3, g0, g1, g2 of each coordinate)."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]  # (F, 3 corners, 3 coords)
    w0, w1, w2 = p[:, 0], p[:, 1], p[:, 2]
    d = np.cross(w1 - w0, w2 - w0)  # (F,3): twice the area times the normal
    t0 = w0 + w1
    f1 = t0 + w2
    t1 = w0 * w0
    t2 = t1 + w1 * t0
    f2 = t2 + w2 * f1
    f3 = w0 * t1 + w1 * t2 + w2 * f2
    g0, g1, g2 = f2 + w0 * (f1 + w0), f2 + w1 * (f1 + w1), f2 + w2 * (f1 + w2)
    x, y, z = 0, 1, 2
    out = np.empty(10)
    out[0] = np.sum(d[:, x] * f1[:, x]) / 6.0
    out[1:4] = np.sum(d * f2, axis=0) / 24.0
    out[4:7] = np.sum(d * f3, axis=0) / 60.0
    # the products: xy from the x components, yz from y, zx from z
    out[7] = np.sum(d[:, x] * (w0[:, y] * g0[:, x] + w1[:, y] * g1[:, x] + w2[:, y] * g2[:, x])) / 120.0
    out[8] = np.sum(d[:, y] * (w0[:, z] * g0[:, y] + w1[:, z] * g1[:, y] + w2[:, z] * g2[:, y])) / 120.0
    out[9] = np.sum(d[:, z] * (w0[:, x] * g0[:, z] + w1[:, x] * g1[:, z] + w2[:, x] * g2[:, z])) / 120.0
    return out


def polyhedron_mass_properties(vertices, faces, density: float) -> MassProperties:
    """Mass properties of the solid a closed, outward-wound triangle mesh encloses, at `density`."""
    i = polyhedron_integrals(vertices, faces) * density
    m = i[0]
    c = i[1:4] / m
    xx, yy, zz, xy, yz, zx = i[4], i[5], i[6], i[7], i[8], i[9]
    inertia = np.array(
        [[yy + zz, -xy, -zx],
         [-xy, xx + zz, -yz],
         [-zx, -yz, xx + yy]]
    )  # fmt: skip
    # about the centre of mass (parallel-axis theorem)
    inertia -= m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
    return MassProperties(float(m), c, inertia)


def uv_sphere(center, radius: float, *, rings: int = 24, segments: int = 48):
    """A UV sphere for drawing: (vertices (V,3) [m], triangles (F,3) int, counter-clockwise outside)."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), -np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    v = np.vstack([[0.0, 1.0, 0.0], ring, [0.0, -1.0, 0.0]]) * radius + np.asarray(center)
    s = np.arange(segments)
    s1 = (s + 1) % segments
    top = np.stack([np.zeros(segments, int), 1 + s, 1 + s1], axis=1)
    bottom_pole = len(v) - 1
    last = 1 + (rings - 2) * segments
    bottom = np.stack([np.full(segments, bottom_pole), last + s1, last + s], axis=1)
    quads = []
    for r in range(rings - 2):
        a, b = 1 + r * segments + s, 1 + r * segments + s1
        c, d = a + segments, b + segments
        quads += [np.stack([a, c, b], axis=1), np.stack([b, c, d], axis=1)]
    return v, np.vstack([top, *quads, bottom])


__all__ = ["Box", "Capsule", "Compound", "ConvexHull", "MassProperties", "Mesh", "Shape", "Sphere"]
