"""Triangle-mesh colliders: static, moving rigidly (a RigidMotion) or deforming (vertex positions per
frame), with a thickness, restitution and friction, in the collider protocol of colliders.py.

Distance: the closest point on the mesh through the linear BVH over its faces (spatial/mesh_query.py,
spatial/lbvh.py); sdf = distance to the surface minus the thickness. On a closed, consistently oriented
mesh the distance is signed (negative inside) by the angle-weighted pseudo-normal of the closest feature
(Bærentzen & Aanæs, "Signed distance computation using the angle weighted pseudonormal", IEEE TVCG
11(3), 2005, Theorem 1: (p - c) . N >= 0 outside, with N the face normal, the sum of the two face normals
at an edge, or the sum of the face normals weighted by their angles at a vertex). An open mesh is a shell:
the unsigned distance minus the thickness, so particles stay `thickness` away on either side; it stops
particles at thickness 0 too, in both collision modes: the swept test below catches the crossing of a
face (from the side the particle comes from), and the projection mode runs it for open meshes
(response.py, `_cross_shells`).

Continuous test (`sweep`): conservative advancement (Mirtich, "Impulse-based dynamic simulation of rigid
body systems", PhD thesis 1996, ch. 3) of a point moving from x0 to x1 against the mesh grown by
r + thickness: from the distance d(tau) to the mesh, no contact can happen before tau + (d - r - thickness)
/ L, with L the largest relative speed (the point's path length, plus the largest vertex displacement of
a deforming mesh over the step, since every point of a linearly moving triangle moves no faster than its
fastest corner). The advance stops at the first contact from outside, so no triangle is skipped whatever
the speed; a grazing pass that has not decided after MAX_ADVANCE distance queries counts as a contact
(conservative). A rigidly moving mesh is swept in its own frame (start point with the start pose, end
point with the end pose, as for analytic colliders); a deforming mesh is queried with its vertices
interpolated linearly over the step, and the BVH over the swept face boxes (start and end positions) is
refitted before each step (`prepare`, rebuilt when refitting has degraded it, see `BVH.update`).

What is exact and what is not: the vertex–triangle distance and the closest feature are exact up to
round-off; contacts are between the particle (a sphere of its radius) and the triangles grown by the
thickness; mesh edges against cloth edges are not tested (only particles, i.e. cloth vertices, against the
mesh's triangles), so a sharp mesh edge can pass between two cloth vertices.
"""

import warnings

import numpy as np
import taichi as ti
from taichi.lang import impl

from .. import capacity, validate
from ..errors import ParameterError
from ..geometry import load_mesh
from ..runtime import data_oriented, np_float
from ..spatial.bounds import aabb_point_distance_sq, aabb_swept_triangle, fp_epsilon
from ..spatial.distance import point_triangle_closest, point_triangle_feature
from ..spatial.mesh_query import BOX_PAD_EPS, TriangleMesh, check_mesh
from .colliders import GRAZING, NO_HIT, ON_SURFACE, Collider, check_collider
from .motion import RigidMotion, _times, keyframe_segment, quat_rotate, quat_rotate_inverse

MAX_ADVANCE = 32  # distance queries per swept test before a pass that has not decided counts as contact
FAR = 1e15  # an unbounded distance query (its square stays finite in f32)


def mesh_arrays(mesh, name: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, faces (F, 3) int32) of an Open3D TriangleMesh (legacy or tensor), a file
    Open3D reads (PLY keeps vertex order; OBJ renumbers vertices) or a (vertices, faces) pair, checked by
    `spatial.check_mesh` (empty, non-finite, indices out of range, all faces of zero area)."""
    # Looser checks than a cloth's: a collider may have duplicate vertices and some zero-area faces.
    return load_mesh(mesh, name=name, check=check_mesh)


def mesh_topology(vertices, faces) -> tuple[np.ndarray, np.ndarray, bool]:
    """Faces oriented outwards if the mesh is closed, each face's neighbour across its edges (ab, bc,
    ca; -1 on a boundary or non-manifold edge) and whether the mesh is closed (every edge shared by
    exactly two faces that traverse it in opposite directions)."""
    f = np.asarray(faces, dtype=np.int64)
    n = len(f)
    directed = np.stack([f, np.roll(f, -1, axis=1)], axis=-1).reshape(-1, 2)  # edge e of face t: row 3t+e
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    adj = np.full(3 * n, -1, dtype=np.int64)
    pairs = counts[inverse] == 2
    order = np.argsort(inverse, kind="stable")
    grouped = inverse[order]
    starts = np.searchsorted(grouped, np.arange(len(counts)))
    first = order[starts[inverse]]
    second = order[np.minimum(starts[inverse] + 1, len(order) - 1)]
    other = np.where(first == np.arange(3 * n), second, first)
    adj[pairs] = other[pairs] // 3
    opposite = np.all(directed[other] == directed[:, ::-1], axis=1)
    closed = bool(np.all(counts == 2) and np.all(opposite))
    if not closed and np.all(counts == 2):
        warnings.warn(
            "mesh: every edge has two faces but their orientations disagree; the collider is treated as an "
            "open shell (unsigned distance)",
            RuntimeWarning,
            stacklevel=3,
        )
    if closed:
        v = np.asarray(vertices, dtype=np.float64)
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0.0:  # 6 x the signed volume: inward normals
            f = f[:, [0, 2, 1]]
            adj = adj.reshape(n, 3)[:, [2, 1, 0]].reshape(-1)  # edges ab, bc, ca become ac(=ca), cb(=bc), ba
    return f.astype(np.int32), adj.reshape(n, 3).astype(np.int32), closed


@data_oriented
class ColliderMesh(Collider):
    """A triangle mesh as a collider (see the module docstring). vertices (V, 3) [m], faces (F, 3);
    thickness [m] >= 0; restitution in [0, 1]; friction >= 0 (Coulomb); motion: a RigidMotion (the mesh
    is given in its frame) or None; vertex_frames: (times (K,) [s], positions (K, V, 3) [m]) for a
    deforming mesh, linearly interpolated and held outside the range, or None."""

    heavy = True  # large tests: `collide` keeps one copy of them in a run-time loop
    kind = "mesh"

    @property
    def shell(self) -> bool:
        """An open mesh has no inside: a particle can pass through it within a step without ever
        ending inside it (at thickness 0 never), so the projection mode sweeps it too."""
        return not self.closed

    def __init__(self, vertices, faces, *, thickness, restitution, friction, motion=None, vertex_frames=None):
        self.thickness = validate.non_negative("thickness", thickness)
        self.restitution = float(restitution)
        self.friction = float(friction)
        if motion is not None and vertex_frames is not None:
            raise ParameterError("give either motion (rigid) or vertex_frames (deforming), not both")
        self.motion = motion
        self.frames = None
        if vertex_frames is not None:
            self.frames = _vertex_frames(vertex_frames, len(vertices))
            vertices = self.frames[1][0]
        self.faces, adjacency, self.closed = mesh_topology(vertices, faces)
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.adjacency = adjacency
        self.deforming = self.frames is not None
        self.rigid = motion is not None
        self.moving = self.deforming or motion is not None
        self.needs_prepare = self.deforming
        self.vertex_count, self.face_count = len(self.vertices), len(self.faces)
        self._program = None

    def settings(self) -> dict:
        out = {
            "type": "mesh",
            "vertices": self.vertex_count,
            "faces": self.face_count,
            "closed": self.closed,
            "thickness": self.thickness,
            "restitution": self.restitution,
            "friction": self.friction,
        }
        if self.motion is not None:
            out["motion"] = self.motion.settings()
        if self.deforming:
            out["vertex_frames"] = len(self.frames[0])
        return out

    def vertex_positions(self, t: float) -> np.ndarray:
        """(V, 3) vertex positions [m] in the world at time t [s] (NumPy; for drawing and tests)."""
        if self.motion is not None:
            return self.motion.apply(self.vertices, t)
        if not self.deforming:
            return self.vertices.copy()
        times, pos = self.frames
        if len(times) == 1 or t <= times[0]:
            return pos[0].copy()
        if t >= times[-1]:
            return pos[-1].copy()
        k = int(np.searchsorted(times, t, side="right")) - 1
        s = (t - times[k]) / (times[k + 1] - times[k])
        return (1.0 - s) * pos[k] + s * pos[k + 1]

    # -- the collider protocol (colliders.py) -------------------------------------------------------------

    def local_points(self) -> np.ndarray:
        """Its vertices in its own frame (V,3) [m] (a deforming mesh's first frame)."""
        return self.vertices

    def key_times(self) -> np.ndarray:
        """Its motion's or its vertex frames' times [s]; empty when static."""
        if self.deforming:
            return np.asarray(self.frames[0], dtype=np.float64)
        return super().key_times()

    def sample_points(self, t: float) -> np.ndarray:
        """Its vertices in the world at t [s] (V,3) [m]."""
        return self.vertex_positions(t)

    def surface(self, bounds=None):
        """(vertices (V,3) [m] in its own frame, faces (F,3))."""
        return self.vertices, self.faces

    def surface_at(self, t: float, bounds=None) -> np.ndarray:
        """Its vertices in the world at t [s] (V,3) [m]."""
        return self.vertex_positions(t)

    # -- fields and per-step work ------------------------------------------------------------------------

    def allocate(self, reach: float = 0.0, model=None) -> None:
        """Fields, the BVH and the adjacency (once per Taichi program). reach [m]: the largest particle
        radius the mesh is queried with (distances beyond thickness + reach are not needed). model: the
        Model it serves, whose allocator it uses: under capacity buckets (capacity.py) the arrays have
        bucket rows from the model's pool and the loops run to live counts read at run time, so a mesh of
        another size in the same buckets compiles nothing new."""
        check_collider(self)
        program = impl.get_runtime().prog
        if self._program is program:
            return
        self._program = program
        self.reach = float(reach) + self.thickness + 1e-6  # distances farther than this are "far"
        f = np_float()
        self.buckets = bool(model is not None and model.size_buckets)
        make = model.new_field if model is not None else capacity.plain
        rows = capacity.bucket if self.buckets else int
        cv, cf = rows(self.vertex_count), rows(self.face_count)
        self.live = None
        if self.buckets:
            self.live = make(self, "mesh_collider_live", ti.i32, (), (2,))
            self.live[None] = (self.vertex_count, self.face_count)
        vec3 = ti.types.vector(3, float)
        self._hit_type = ti.types.struct(dist2=float, face=ti.i32, w=vec3)
        self.face_adj = make(self, "mesh_collider_face_adj", ti.i32, cf, (3,))
        # Faces around each vertex (compressed rows), for the angle-weighted vertex normal.
        order = np.argsort(self.faces.reshape(-1), kind="stable")
        counts = np.bincount(self.faces.reshape(-1), minlength=self.vertex_count)
        self.vertex_face_start = make(self, "mesh_collider_vertex_face_start", ti.i32, cv + 1)
        starts = np.concatenate([[0], np.cumsum(counts)])
        self.vertex_faces = make(self, "mesh_collider_vertex_faces", ti.i32, 3 * cf)
        own = [  # written with the mesh's arrays: one launch (from_numpy is a kernel per field, bulk.py)
            (self.face_adj, capacity.padded(self.adjacency, cf, np.int32)),
            (self.vertex_face_start, capacity.padded(starts, cv + 1, np.int32)),
            (self.vertex_faces, capacity.padded(order // 3, 3 * cf, np.int32)),
        ]
        self.mesh = TriangleMesh(
            self.vertices, self.faces, vertex_capacity=cv, face_capacity=cf, make=make, fill_also=own
        )
        self.vertex_n = make(self, "mesh_collider_vertex_n", float, cv, (3,))
        self.vertex_n0 = make(self, "mesh_collider_vertex_n0", float, cv, (3,)) if self.deforming else None
        if self.motion is not None:
            self.motion.allocate()
        if not self.deforming:
            self._vertex_normals()
        else:
            times, pos = self.frames
            self.key_count = len(times)
            self.key_t = make(self, "mesh_collider_key_t", float, self.key_count)
            self.key_x = make(self, "mesh_collider_key_x", float, (self.key_count, cv), (3,))
            self.key_t.from_numpy(times.astype(f))
            keys = np.zeros((self.key_count, cv, 3), dtype=f)
            keys[:, : self.vertex_count] = pos
            self.key_x.from_numpy(keys)
            self.vertex_x0 = make(self, "mesh_collider_vertex_x0", float, cv, (3,))  # start of the step
            self.vertex_v = make(self, "mesh_collider_vertex_v", float, cv, (3,))  # over the step [m/s]
            # start time, length of the prepared step, largest displacement
            self.step = make(self, "mesh_collider_step", float, 3)
            self.prepare(0.0, 0.0)

    # The live counts of vertices and faces (capacity.live).
    @ti.func
    def live_vertices(self):
        return capacity.live(self.live, 0, self.vertex_count)

    @ti.func
    def live_faces(self):
        return capacity.live(self.live, 1, self.face_count)

    def prepare(self, t: float, h: float) -> None:
        """Vertices at t and t + h [s], their normals, swept face boxes and the BVH refit (rebuilt if
        degraded)."""
        self._prepare(t, h)
        self._vertex_normals()
        self.mesh.bvh.update()

    @ti.kernel
    def _prepare(self, t: float, h: float):
        for _ in range(1):
            self.step[0] = t
            self.step[1] = h
            self.step[2] = 0.0
        for v in range(self.live_vertices()):
            x0 = self._frame_position(v, t)
            x1 = self._frame_position(v, t + h)
            self.vertex_x0[v] = x0
            self.mesh.vertex_x[v] = x1
            self.vertex_v[v] = (x1 - x0) / ti.max(h, 1e-30)
            ti.atomic_max(self.step[2], (x1 - x0).norm())
        for f in range(self.live_faces()):
            tri = self.mesh.face_vertices[f]
            a0, b0, c0 = self.vertex_x0[tri[0]], self.vertex_x0[tri[1]], self.vertex_x0[tri[2]]
            a1, b1, c1 = self.mesh.corners(f)
            scale = ti.max(ti.abs(a0).max(), ti.abs(b0).max(), ti.abs(c0).max(), ti.abs(a1).max())
            scale = ti.max(scale, ti.abs(b1).max(), ti.abs(c1).max())
            pad = BOX_PAD_EPS * fp_epsilon() * scale + 1e-30
            lo, hi = aabb_swept_triangle(a0, b0, c0, a1, b1, c1, pad)
            self.mesh.bvh.prim_lo[f] = lo
            self.mesh.bvh.prim_hi[f] = hi

    @ti.func
    def _frame_position(self, v, t):
        k, s = keyframe_segment(self.key_t, self.key_count, t)
        x = self.key_x[k, v]
        if ti.static(self.key_count > 1):
            x = (1.0 - s) * x + s * self.key_x[k + 1, v]
        return x

    # -- geometry in the mesh's frame, at fraction s of the prepared step --------------------------------

    @ti.func
    def _corners(self, f, s):
        a, b, c = self.mesh.corners(f)  # the end of the step (or the only positions)
        if ti.static(self.deforming):
            tri = self.mesh.face_vertices[f]
            a = a + (1.0 - s) * (self.vertex_x0[tri[0]] - a)
            b = b + (1.0 - s) * (self.vertex_x0[tri[1]] - b)
            c = c + (1.0 - s) * (self.vertex_x0[tri[2]] - c)
        return a, b, c

    @ti.func
    def _visit(self, ps, f, ret: ti.template()):
        p = ti.Vector([ps[0], ps[1], ps[2]])
        a, b, c = self._corners(f, ps[3])
        w = point_triangle_closest(p, a, b, c)
        d2 = (p - (w[0] * a + w[1] * b + w[2] * c)).norm_sqr()
        if d2 < ret.dist2 or (d2 == ret.dist2 and (ret.face < 0 or f < ret.face)):
            ret.dist2 = d2
            ret.face = f
            ret.w = w

    @ti.func
    def _closest(self, p, s, max_dist):
        """(dist, face, w) of the mesh point nearest to p at fraction s of the step (face -1: none within
        max_dist)."""
        d = ti.cast(max_dist, float)
        face = -1
        w = ti.Vector.zero(float, 3)
        if ti.static(self.deforming):
            ret = self._hit_type(dist2=d * d, face=-1, w=w)
            ps = ti.Vector([p[0], p[1], p[2], s], float)
            self.mesh.bvh.traverse_nearest(
                ps, p, self.mesh.score_closest, self.mesh.bound_closest, self._visit, ret
            )
            d, face, w = ti.sqrt(ret.dist2), ret.face, ret.w
        else:
            d, face, w = self.mesh.closest_point(p, max_dist)
        return d, face, w

    @ti.func
    def _face_normal(self, f, s):
        a, b, c = self._corners(f, s)
        return (b - a).cross(c - a).normalized(1e-30)

    @ti.func
    def _pseudo_normal(self, f, w, s):
        """The angle-weighted pseudo-normal (not normalised) of the feature of face f that w marks."""
        code = point_triangle_feature(w)
        n = self._face_normal(f, s)
        if 1 <= code <= 3:  # an edge: the sum of its two faces' normals
            g = self.face_adj[f][code - 1]
            if g >= 0:
                n += self._face_normal(g, s)
        elif code >= 4:  # a vertex: its faces' normals weighted by their angles there (stored)
            v = self.mesh.face_vertices[f][code - 4]
            n = self.vertex_n[v]
            if ti.static(self.deforming):
                n += (1.0 - s) * (self.vertex_n0[v] - n)  # exact at the step's ends
        return n

    @ti.func
    def _vertex_normal(self, v, s):
        """Angle-weighted normal (Bærentzen & Aanæs 2005, eq. 4) of vertex v at fraction s of the step."""
        n = ti.Vector.zero(float, 3)
        for k in range(self.vertex_face_start[v], self.vertex_face_start[v + 1]):
            g = self.vertex_faces[k]
            tri = self.mesh.face_vertices[g]
            a, b, c = self._corners(g, s)
            x, y, z = a, b, c  # the corner at v first
            if tri[1] == v:
                x, y, z = b, c, a
            elif tri[2] == v:
                x, y, z = c, a, b
            e1 = (y - x).normalized(1e-30)
            e2 = (z - x).normalized(1e-30)
            angle = ti.atan2(e1.cross(e2).norm(), e1.dot(e2))
            n += angle * (b - a).cross(c - a).normalized(1e-30)
        return n

    @ti.kernel
    def _vertex_normals(self):
        """Vertex normals at the end of the step (and its start, for a deforming mesh): a gather per
        vertex over its faces in a fixed order (no atomics)."""
        for v in range(self.live_vertices()):
            self.vertex_n[v] = self._vertex_normal(v, 1.0)
            if ti.static(self.deforming):
                self.vertex_n0[v] = self._vertex_normal(v, 0.0)

    @ti.func
    def _signed(self, p, s):
        """(signed distance to the surface [m], outward normal, face, w) at point p of the mesh's frame;
        (reach, +y, -1, 0) when the surface is farther than `reach` (and p is not inside)."""
        sd = ti.cast(self.reach, float)
        n = ti.Vector([0.0, 1.0, 0.0], float)
        face = -1
        w = ti.Vector.zero(float, 3)
        lo = self.mesh.bvh.root_box[0]
        hi = self.mesh.bvh.root_box[1]
        if aabb_point_distance_sq(lo, hi, p) <= self.reach * self.reach:
            # A closed mesh needs the sign of points deep inside too: no distance bound there.
            bound = ti.cast(self.reach, float)
            if ti.static(self.closed):
                bound = FAR
            d, face, w = self._closest(p, s, bound)
            if face >= 0:
                sd, n = self._side(p, s, d, face, w)
        return sd, n, face, w

    @ti.func
    def _side(self, p, s, d, face, w):
        """(signed distance, outward normal) of p at distance d from the point w of `face`: negative
        inside a closed mesh (pseudo-normal test); the normal points from the surface to p (away from it
        inside), or along the pseudo-normal when p is on the surface."""
        a, b, c = self._corners(face, s)
        delta = p - (w[0] * a + w[1] * b + w[2] * c)
        pn = self._pseudo_normal(face, w, s)
        sign = 1.0
        if ti.static(self.closed):
            if delta.dot(pn) < 0.0:
                sign = -1.0
        n = pn.normalized(1e-30)
        if d > 1e-12 * (1.0 + p.norm()):
            n = sign * delta / d
        return sign * d, n

    @ti.func
    def _surface_velocity(self, face, w):
        v = ti.Vector.zero(float, 3)
        if ti.static(self.deforming):
            if face >= 0:
                tri = self.mesh.face_vertices[face]
                v = w[0] * self.vertex_v[tri[0]] + w[1] * self.vertex_v[tri[1]] + w[2] * self.vertex_v[tri[2]]
        return v

    @ti.func
    def _fraction(self, t):
        """Fraction of the prepared step at time t (deforming meshes; 1 otherwise)."""
        s = ti.cast(1.0, float)
        if ti.static(self.deforming):
            s = ti.min(ti.max((t - self.step[0]) / ti.max(self.step[1], 1e-30), 0.0), 1.0)
        return s

    # -- the collider protocol ---------------------------------------------------------------------------

    @ti.func
    def contact(self, x, t):
        """(sdf, outward normal, surface velocity) at world point x and time t."""
        p = x
        q = ti.Vector([0.0, 0.0, 0.0, 1.0], float)
        tr = ti.Vector.zero(float, 3)
        omega = ti.Vector.zero(float, 3)
        vel = ti.Vector.zero(float, 3)
        if ti.static(self.rigid):
            q, tr, omega, vel = self.motion.motion_at(t)
            p = quat_rotate_inverse(q, x - tr)
        sd, n, face, w = self._signed(p, self._fraction(t))
        vs = self._surface_velocity(face, w)
        if ti.static(self.rigid):
            n = quat_rotate(q, n)
            vs = omega.cross(x - tr) + vel
        return sd - self.thickness, n, vs

    @ti.func
    def sdf(self, x, t):
        d, _, _ = self.contact(x, t)
        return d

    @ti.func
    def normal(self, x, t):
        _, n, _ = self.contact(x, t)
        return n

    @ti.func
    def velocity(self, x, t):
        _, _, v = self.contact(x, t)
        return v

    @ti.func
    def sweep(self, x0, x1, t, h, r):
        p0, p1 = x0, x1
        if ti.static(self.rigid):
            p0 = self.motion.to_local(x0, t)
            p1 = self.motion.to_local(x1, t + h)
        tau, n, vs = self._advance(p0, p1, self._fraction(t), self._fraction(t + h), h, r + self.thickness)
        if ti.static(self.rigid):
            if tau <= 1.0:
                q, tr, omega, vel = self.motion.motion_at(t + tau * h)
                n = quat_rotate(q, n)
                vs = omega.cross(x0 + tau * (x1 - x0) - tr) + vel
        return tau, n, vs

    @ti.func
    def _advance(self, p0, p1, s0, s1, h, rr):
        """Conservative advancement of p0 -> p1 (mesh frame, fractions s0 -> s1 of the prepared step)
        to the first time the point comes within rr of the mesh from outside: (tau, normal, surface
        velocity); tau = NO_HIT if it does not, starts inside or only slides along the surface."""
        tau = ti.cast(NO_HIT, float)
        n = ti.Vector.zero(float, 3)
        vs = ti.Vector.zero(float, 3)
        path = p1 - p0
        speed = path.norm()  # the relative speed bound L, per unit of tau
        if ti.static(self.deforming):
            speed += self.step[2] * (s1 - s0)
        tol = ti.max(ON_SURFACE, 1e-3 * rr)
        tt = ti.cast(0.0, float)
        face = -1
        w = ti.Vector.zero(float, 3)
        if speed > 0.0:
            # One distance query in the code (the walk is large), the first one included: compiling
            # several copies of it took minutes.
            for it in range(MAX_ADVANCE):
                d, face, w = self._closest(p0 + tt * path, s0 + tt * (s1 - s0), rr + (1.0 - tt) * speed + tol)
                if face < 0:
                    break  # nothing within reach of the rest of the path
                if it == 0:
                    # Outside at the start by at least rr (to round-off): not within rr of the surface,
                    # not inside a closed mesh.
                    sd, _ = self._side(p0, s0, d, face, w)
                    if sd < rr - ON_SURFACE:
                        face = -1
                        break
                if d - rr <= tol:
                    break  # contact
                tt += (d - rr) / speed
                if tt > 1.0:
                    face = -1
                    break
            if face >= 0:  # within tol of rr (or undecided after MAX_ADVANCE queries: conservative)
                s = s0 + tt * (s1 - s0)
                p = p0 + tt * path
                a, b, c = self._corners(face, s)
                delta = p - (w[0] * a + w[1] * b + w[2] * c)
                d = delta.norm()
                nc = delta.normalized(1e-30)
                v = self._surface_velocity(face, w)
                rel = path - h * v  # the motion relative to the surface
                if ti.static(not self.closed):
                    if d <= tol:
                        # On the surface itself (a point against a shell of thickness 0): delta is
                        # round-off and may point through it. A two-sided shell is hit from the side the
                        # point comes from: the face's normal against the motion.
                        nc = self._face_normal(face, s)
                        if nc.dot(rel) > 0.0:
                            nc = -nc
                approach = -rel.dot(nc)
                if approach > GRAZING * rel.norm():
                    # Close the last gap (< tol) along the normal: a Newton step on the distance, which
                    # is convex along the path for one feature, so it does not pass the contact (a point
                    # already a hair through a shell stays where it is).
                    if d - rr <= tol:
                        tt = ti.min(tt + ti.max(delta.dot(nc) - rr, 0.0) / approach, 1.0)
                    tau = tt
                    n = nc
                    vs = v
        return tau, n, vs


def _vertex_frames(vertex_frames, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        times, positions = vertex_frames
    except (TypeError, ValueError):
        raise ParameterError("vertex_frames must be (times (K,) [s], positions (K, V, 3) [m])") from None
    t = _times(times)
    x = validate.finite_array("vertex_frames positions", positions)
    want = (len(t), vertex_count, 3)
    if x.shape != want:
        raise ParameterError(
            f"vertex_frames positions must have shape (K, V, 3) = {want} (K times, V mesh vertices), "
            f"got {x.shape}"
        )
    return t, x


def make_collider_mesh(mesh, *, thickness, restitution, friction, motion, vertex_frames) -> ColliderMesh:
    """A ColliderMesh from anything `mesh_arrays` reads (see Builder.add_collider_mesh)."""
    v, f = mesh_arrays(mesh)
    if motion is not None and not isinstance(motion, RigidMotion):
        raise ParameterError(f"motion must be a RigidMotion or None, got {motion!r}")
    return ColliderMesh(
        v,
        f,
        thickness=thickness,
        restitution=validate.in_range("restitution", restitution, 0.0, 1.0),
        friction=validate.non_negative("friction", friction),
        motion=motion,
        vertex_frames=vertex_frames,
    )


__all__ = ["ColliderMesh", "make_collider_mesh", "mesh_arrays", "mesh_topology"]
