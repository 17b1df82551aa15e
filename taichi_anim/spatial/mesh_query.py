"""Queries on a triangle mesh through a linear BVH over its faces: closest point, triangles meeting a box
or a ball, nearest ray hit, and the generalized winding number (inside / outside of a closed mesh).

Closest point: best-first descent of the BVH (`BVH.traverse`), pruning boxes farther than the best
distance so far; per face, Ericson's point–triangle closest point (`distance.point_triangle_closest`).
Ray cast: nearest-first descent pruning boxes entered beyond the nearest hit; per face Möller & Trumbore
1997 (`intersect.ray_triangle`). Triangle–box: the separating axis test of Akenine-Möller, "Fast 3D
triangle-box overlap testing" (JGT 6(1), 2001): the box's 3 face normals, the triangle's normal and the
9 cross products of triangle edges with box axes; a degenerate triangle (a segment, a point) is tested
by the same axes, which stay a complete set for it. Ties (equal distance, equal t) go to the lowest face
index, so every query returns what a scan over all faces in index order returns.

Generalized winding number: Jacobson, Kavan & Sorkine-Hornung, "Robust Inside-Outside Segmentation
using Generalized Winding Numbers", SIGGRAPH 2013, eq. 3: w(p) = sum over faces of Omega_f(p) / (4 pi),
each solid angle by Van Oosterom & Strackee (IEEE TBME 1983): tan(Omega / 2) = a . (b x c) /
(|a||b||c| + (a.b)|c| + (b.c)|a| + (c.a)|b|), with a, b, c the corners relative to p. For a closed,
consistently oriented mesh (outward normals) w is 1 inside, 0 outside (up to round-off), and undefined
on the surface; `inside` thresholds it at 1/2. It sums over all faces (O(F) per point; a hierarchical
evaluation, Barill et al. 2018, is not implemented).
"""

import math
from types import SimpleNamespace

import numpy as np
import taichi as ti

from .. import bulk, validate
from ..capacity import plain
from ..errors import ParameterError
from ..runtime import data_oriented, float_dtype, np_float
from .bounds import aabb_point_distance_sq, aabb_ray, aabb_triangle, fp_epsilon
from .distance import point_triangle_closest
from .intersect import ray_triangle
from .lbvh import BVH, float_bytes
from .lbvh_query import ray_inv_dir


def _query_types():
    """Struct types of the query records, in the float type of the running Taichi (made per mesh: a
    module-level `float` would freeze the precision at import)."""
    f = float_dtype()
    vec3 = ti.types.vector(3, f)
    return SimpleNamespace(
        ClosestHit=ti.types.struct(dist2=f, face=ti.i32, w=vec3),
        RayHit=ti.types.struct(t=f, face=ti.i32, u=f, v=f),
        RayQuery=ti.types.struct(o=vec3, d=vec3, inv_d=vec3, t_max=f),
        BoxQuery=ti.types.struct(i=ti.i32, lo=vec3, hi=vec3),
        SphereQuery=ti.types.struct(i=ti.i32, c=vec3, r2=f),
    )


# Face boxes grow by this many epsilons of the corners' largest coordinate: box tests then never reject
# a face that the exact per-face test, with its own round-off, accepts.
BOX_PAD_EPS = 16.0


@ti.func
def triangle_box_overlap(a, b, c, lo, hi):
    """Whether the closed triangle abc and the closed box [lo, hi] share a point (separating axes,
    Akenine-Möller 2001; touching counts)."""
    centre = 0.5 * (lo + hi)
    h = 0.5 * (hi - lo)
    v0 = a - centre
    v1 = b - centre
    v2 = c - centre
    apart = False
    # box face normals: the boxes of the triangle and of the box
    for k in ti.static(range(3)):
        if ti.min(v0[k], v1[k], v2[k]) > h[k] or ti.max(v0[k], v1[k], v2[k]) < -h[k]:
            apart = True
    # triangle normal: the plane against the box
    n = (v1 - v0).cross(v2 - v0)
    if ti.abs(n.dot(v0)) > ti.abs(n).dot(h):
        apart = True
    # edge x box axis
    edges = ti.Matrix.rows([v1 - v0, v2 - v1, v0 - v2])
    for e in ti.static(range(3)):
        for k in ti.static(range(3)):
            u = ti.Vector([0.0, 0.0, 0.0], float)
            u[k] = 1.0
            axis = ti.Vector([edges[e, 0], edges[e, 1], edges[e, 2]]).cross(u)
            p0 = axis.dot(v0)
            p1 = axis.dot(v1)
            p2 = axis.dot(v2)
            r = ti.abs(axis).dot(h)
            if ti.min(p0, p1, p2) > r or ti.max(p0, p1, p2) < -r:
                apart = True
    return not apart


@ti.func
def triangle_solid_angle(p, a, b, c):
    """Signed solid angle [sr] of triangle abc seen from p (Van Oosterom & Strackee 1983); positive when
    p is on the side its normal (b - a) x (c - a) points away from."""
    x = a - p
    y = b - p
    z = c - p
    lx = x.norm()
    ly = y.norm()
    lz = z.norm()
    num = x.dot(y.cross(z))
    den = lx * ly * lz + x.dot(y) * lz + y.dot(z) * lx + z.dot(x) * ly
    return 2.0 * ti.atan2(num, den)


def winding_number_np(vertices, faces, points) -> np.ndarray:
    """Generalized winding numbers (P,) of points (P, 3) [m] for the mesh (V, 3) [m], (F, 3) int: the
    NumPy (float64) reference of `TriangleMesh.winding_numbers`."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(p))
    for start in range(0, len(p), 256):  # bounded memory: (256, F, 3) at a time
        q = p[start : start + 256, None, :]
        x, y, z = v[f[:, 0]] - q, v[f[:, 1]] - q, v[f[:, 2]] - q
        lx, ly, lz = (np.linalg.norm(t, axis=-1) for t in (x, y, z))
        num = np.einsum("pfk,pfk->pf", x, np.cross(y, z))
        den = (
            lx * ly * lz
            + np.einsum("pfk,pfk->pf", x, y) * lz
            + np.einsum("pfk,pfk->pf", y, z) * lx
            + np.einsum("pfk,pfk->pf", z, x) * ly
        )
        out[start : start + 256] = (2.0 * np.arctan2(num, den)).sum(-1) / (4.0 * math.pi)
    return out


# Up to this many point-face pairs, `inside_closed_mesh` sums in NumPy (160-190 ns a pair on the 2-core
# Xeon: 0.19 s at the bound); past it, TriangleMesh's kernel (about 10 ns a pair, after compiling its
# kernels: 0.65 s with an empty offline cache, 0.21 s warm, for 8.6e5 pairs). A builder's one-off fill
# is usually far below it: the pour demo's glass, 4.7e4 pairs, 13 ms.
NUMPY_WINDING_PAIRS = 1_000_000


def inside_closed_mesh(vertices, faces, points) -> np.ndarray:
    """Whether each point (P, 3) [m] is inside the closed mesh (V, 3) [m], (F, 3) int (generalized winding
    number >= 1/2), (P,) bool: in NumPy up to NUMPY_WINDING_PAIRS point-face pairs, so that a one-off
    query compiles no kernel, else with TriangleMesh's kernel."""
    v, f = check_mesh(vertices, faces)
    p = _points("points", points)
    if len(p) * len(f) <= NUMPY_WINDING_PAIRS:
        return winding_number_np(v, f, p) >= 0.5
    return TriangleMesh(v, f).inside(p)


def check_mesh(vertices, faces, *, name: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Checked copies (V, 3) float64 [m] and (F, 3) int32 of a triangle mesh for queries; single
    degenerate (zero-area, needle) triangles are allowed, a mesh of nothing else is not.

    Raises ParameterError naming `vertices` or `faces` for: empty arrays, wrong shapes, non-finite
    coordinates, non-integer or out-of-range indices, and a mesh whose every triangle has zero area."""
    try:
        v = np.array(vertices, dtype=np.float64)
        f = np.array(faces)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name}: vertices and faces must be numeric arrays ({exc})") from None
    if v.size == 0:
        raise ParameterError(f"{name}: vertices is empty")
    if f.size == 0:
        raise ParameterError(f"{name}: faces is empty")
    v = validate.finite_array(f"{name} vertices", v, (3,))
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ParameterError(f"{name}: faces must be integers of shape (F, 3), got {f.dtype} {f.shape}")
    bad = (f < 0) | (f >= len(v))
    if bad.any():
        t = int(np.argwhere(bad)[0][0])
        raise ParameterError(
            f"{name}: faces[{t}] = {f[t].tolist()} has an index outside [0, {len(v)}) (vertices)"
        )
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    if not np.any(area2 > 0.0):
        raise ParameterError(f"{name}: degenerate mesh, every one of the {len(f)} faces has zero area")
    return v, f.astype(np.int32)


@data_oriented
class TriangleMesh:
    """A triangle mesh with a BVH over its faces, for queries from Taichi scope and batches from NumPy.

    vertices (V, 3) [m], faces (F, 3) int (see `check_mesh`); vertex_capacity / face_capacity (>= V, F)
    size the fields for later `set_mesh` calls with larger meshes. Deforming meshes: write `vertex_x`
    (Vector field (vertex_capacity, 3) [m]) in a kernel or with `set_vertices`, then `refit()` (keeps
    the tree) or `update()` (refits, rebuilds when the tree's quality has degraded, see `BVH.update`).
    """

    def __init__(
        self,
        vertices,
        faces,
        *,
        vertex_capacity: int | None = None,
        face_capacity: int | None = None,
        make=plain,
        fill_also=(),
    ):
        """make(owner, role, dtype, shape, dims): the allocator of its fields (a model's pool under capacity
        buckets, capacity.py; default: new fields). fill_also: the owner's own (field, array) pairs, written
        in the same launch as the mesh's arrays (bulk.fill)."""
        v, f = check_mesh(vertices, faces)
        self.vertex_capacity = validate.count("vertex_capacity", vertex_capacity or len(v), 1)
        self.face_capacity = validate.count("face_capacity", face_capacity or len(f), 1)
        fb = float_bytes()
        validate.capacity("vertex_capacity", self.vertex_capacity, bytes_each=3 * fb, unit="vertices")
        validate.capacity("face_capacity", self.face_capacity, bytes_each=12 + 19 * fb + 46, unit="faces")
        self.vertex_x = make(self, "mesh_vertex_x", float, self.vertex_capacity, (3,))
        self.face_vertices = make(self, "mesh_face_vertices", ti.i32, self.face_capacity, (3,))
        self.bvh = BVH(self.face_capacity, make=make)
        self.face_count_field = make(self, "mesh_face_count", ti.i32, ())
        self._types = _query_types()
        self.vertex_count = 0
        self.face_count = 0
        self.set_mesh(v, f, fill_also)

    def set_mesh(self, vertices, faces, fill_also=()) -> None:
        """Replace the mesh (within the capacities) and rebuild the tree (fill_also: as the constructor's)."""
        v, f = check_mesh(vertices, faces)
        if len(v) > self.vertex_capacity:
            raise ParameterError(f"vertices: {len(v)} exceed vertex_capacity {self.vertex_capacity}")
        if len(f) > self.face_capacity:
            raise ParameterError(f"faces: {len(f)} exceed face_capacity {self.face_capacity}")
        self.vertex_count, self.face_count = len(v), len(f)
        # one launch: from_numpy is a kernel per field (bulk.py)
        bulk.fill(
            [
                (self.vertex_x, _pad(v, self.vertex_capacity)),
                (self.face_vertices, _pad(f, self.face_capacity)),
                *fill_also,
            ]
        )
        self._boxes(self.face_count)
        self.bvh.build(self.face_count)

    def set_vertices(self, vertices) -> bool:
        """New positions (V, 3) [m] for the same faces; `update()`s the tree, returns whether it rebuilt."""
        v = validate.finite_array("vertices", vertices, (3,))
        if len(v) != self.vertex_count:
            raise ParameterError(f"vertices: expected {self.vertex_count} rows, got {len(v)}")
        self.vertex_x.from_numpy(_pad(v.astype(np_float()), self.vertex_capacity))
        return self.update()

    def refit(self) -> None:
        """Face boxes from `vertex_x`, then the BVH's node boxes (one launch, topology kept)."""
        self._boxes_refit(self.face_count)

    def update(self) -> bool:
        """Refit, and rebuild if the tree's surface-area cost passed its threshold (see `BVH.update`)."""
        self._boxes(self.face_count)
        return self.bvh.update()

    @ti.kernel
    def _boxes(self, n: ti.i32):
        """The faces' boxes, after a new mesh of n faces (whose count it records: a Python-scope write
        would be a writer kernel of its own, compiled with an empty cache)."""
        self.face_count_field[None] = n
        self._face_boxes(n)

    @ti.kernel
    def _boxes_refit(self, n: ti.i32):
        self._face_boxes(n)
        self.bvh._refit(n)

    @ti.func
    def _face_boxes(self, n):
        ti.loop_config(serialize=self.bvh._serial)
        for f in range(n):
            a, b, c = self.corners(f)
            scale = ti.max(ti.abs(a).max(), ti.abs(b).max(), ti.abs(c).max())
            pad = BOX_PAD_EPS * fp_epsilon() * scale + 1e-30
            self.bvh.prim_lo[f], self.bvh.prim_hi[f] = aabb_triangle(a, b, c, pad)

    @ti.func
    def corners(self, f):
        """The three corner positions [m] of face f."""
        t = self.face_vertices[f]
        return self.vertex_x[t[0]], self.vertex_x[t[1]], self.vertex_x[t[2]]

    # ---------------------------------------------------------------------------------------------
    # Taichi scope

    @ti.func
    def score_closest(self, p, lo, hi, ret: ti.template()):
        """Nearest-first order for closest-point searches: a box's squared distance to p, < 0 past the
        best found (ret.dist2)."""
        d2 = aabb_point_distance_sq(lo, hi, p)
        out = -1.0
        if d2 <= ret.dist2:
            out = d2
        return out

    @ti.func
    def bound_closest(self, ret: ti.template()):
        """The pruning bound of a closest-point search: the squared distance [m^2] of the best face so far."""
        return ret.dist2

    @ti.func
    def _bound_ray(self, ret: ti.template()):
        return ret.t

    @ti.func
    def _visit_closest(self, p, f, ret: ti.template()):
        a, b, c = self.corners(f)
        w = point_triangle_closest(p, a, b, c)
        d2 = (p - (w[0] * a + w[1] * b + w[2] * c)).norm_sqr()
        if d2 < ret.dist2 or (d2 == ret.dist2 and (ret.face < 0 or f < ret.face)):
            ret.dist2 = d2
            ret.face = f
            ret.w = w

    @ti.func
    def closest_point(self, p, max_dist):
        """(dist [m], face, w): the point of the mesh nearest to p, w0 a + w1 b + w2 c on face `face`,
        among points within max_dist [m] (face -1, dist max_dist if there is none); ties go to the
        lowest face index."""
        p_ = ti.cast(p, float)
        ret = self._types.ClosestHit(
            dist2=ti.cast(max_dist, float) ** 2, face=-1, w=ti.Vector([0.0, 0.0, 0.0], float)
        )
        self.bvh.traverse_nearest(p_, p_, self.score_closest, self.bound_closest, self._visit_closest, ret)
        return ti.sqrt(ret.dist2), ret.face, ret.w

    @ti.func
    def _score_ray(self, q, lo, hi, ret: ti.template()):
        hit, t = aabb_ray(lo, hi, q.o, q.inv_d, ret.t)
        out = -1.0
        if hit:
            out = t
        return out

    @ti.func
    def _visit_ray(self, q, f, ret: ti.template()):
        a, b, c = self.corners(f)
        # the caller's t_max, not the best t so far: which faces hit must not depend on visit order
        hit, t, u, v = ray_triangle(q.o, q.d, a, b, c, q.t_max)
        if hit and (t < ret.t or (t == ret.t and (ret.face < 0 or f < ret.face))):
            ret.t = t
            ret.face = f
            ret.u = u
            ret.v = v

    @ti.func
    def ray_cast(self, o, d, t_max):
        """(t, face, u, v): the nearest hit o + t d, t in [0, t_max], at (1 - u - v) a + u b + v c of face
        `face`; face -1 and t = t_max if the ray misses. Ties go to the lowest face index."""
        d_ = ti.cast(d, float)
        q = self._types.RayQuery(
            o=ti.cast(o, float), d=d_, inv_d=ray_inv_dir(d_), t_max=ti.cast(t_max, float)
        )
        ret = self._types.RayHit(t=q.t_max, face=-1, u=0.0, v=0.0)
        self.bvh.traverse_nearest(q, q, self._score_ray, self._bound_ray, self._visit_ray, ret)
        return ret.t, ret.face, ret.u, ret.v

    @ti.func
    def for_each_triangle_in_box(self, i, lo, hi, visit: ti.template(), ret: ti.template()):
        """visit(i, face, ret) for every face that meets the closed box [lo, hi] [m] (exact test
        `triangle_box_overlap` on the faces whose boxes overlap it); i is an integer passed through."""
        lo_ = ti.cast(lo, float)
        hi_ = ti.cast(hi, float)
        q = self._types.BoxQuery(i=i, lo=lo_, hi=hi_)
        self.bvh.traverse(
            q, ti.Matrix.rows([lo_, hi_]), self.bvh._score_box, ti.static(_in_box(self, visit)), ret
        )

    @ti.func
    def for_each_triangle_in_sphere(self, i, c, r, visit: ti.template(), ret: ti.template()):
        """visit(i, face, ret) for every face within distance r [m] of c (closed ball); i is an integer
        passed through."""
        c_ = ti.cast(c, float)
        q = self._types.SphereQuery(i=i, c=c_, r2=ti.cast(r, float) ** 2)
        box = ti.Vector([c_[0], c_[1], c_[2], q.r2], float)
        self.bvh.traverse(q, box, self.bvh._score_sphere, ti.static(_in_sphere(self, visit)), ret)

    @ti.func
    def winding_number(self, p):
        """Generalized winding number of the mesh at p (1 inside a closed outward-oriented mesh, 0
        outside); a sum over all faces."""
        p_ = ti.cast(p, float)
        total = 0.0
        for f in range(self.face_count_field[None]):
            a, b, c = self.corners(f)
            total += triangle_solid_angle(p_, a, b, c)
        return total / (4.0 * math.pi)

    # ---------------------------------------------------------------------------------------------
    # batches from NumPy

    def closest_points(self, points, *, max_dist: float = math.inf):
        """For points (P, 3) [m]: dist (P,) [m], face (P,) int (-1: none within max_dist [m]) and
        barycentric weights w (P, 3) of the nearest mesh points."""
        p = _points("points", points)
        dist = np.zeros(len(p), np_float())
        face = np.zeros(len(p), np.int32)
        w = np.zeros((len(p), 3), np_float())
        if len(p):
            self._closest_batch(p, float(max_dist), dist, face, w)
        return dist, face, w

    def ray_casts(self, origins, directions, *, t_max: float = math.inf):
        """Nearest hits of rays o + t d (P, 3 each) [m], t in [0, t_max]: t (P,), face (P,) int (-1: miss,
        t = t_max), u, v (P,) with the hit at (1 - u - v) a + u b + v c."""
        o = _points("origins", origins)
        d = _points("directions", directions)
        if d.shape != o.shape:
            raise ParameterError(f"directions: shape {d.shape} differs from origins {o.shape}")
        t = np.zeros(len(o), np_float())
        face = np.zeros(len(o), np.int32)
        uv = np.zeros((len(o), 2), np_float())
        if len(o):
            self._ray_batch(o, d, float(t_max), t, face, uv)
        return t, face, uv[:, 0], uv[:, 1]

    def winding_numbers(self, points) -> np.ndarray:
        """Generalized winding numbers (P,) at points (P, 3) [m]."""
        p = _points("points", points)
        out = np.zeros(len(p), np_float())
        if len(p):
            self._winding_batch(p, out)
        return out

    def inside(self, points) -> np.ndarray:
        """Whether each point (P, 3) [m] is inside the closed mesh (winding number >= 1/2), (P,) bool."""
        return self.winding_numbers(points) >= 0.5

    @ti.kernel
    def _closest_batch(
        self,
        p: ti.types.ndarray(),
        max_dist: float,
        dist: ti.types.ndarray(),
        face: ti.types.ndarray(),
        w: ti.types.ndarray(),
    ):
        for k in range(p.shape[0]):
            d, f, ww = self.closest_point(ti.Vector([p[k, 0], p[k, 1], p[k, 2]], float), max_dist)
            dist[k] = d
            face[k] = f
            for a in ti.static(range(3)):
                w[k, a] = ww[a]

    @ti.kernel
    def _ray_batch(
        self,
        o: ti.types.ndarray(),
        d: ti.types.ndarray(),
        t_max: float,
        t: ti.types.ndarray(),
        face: ti.types.ndarray(),
        uv: ti.types.ndarray(),
    ):
        for k in range(o.shape[0]):
            oo = ti.Vector([o[k, 0], o[k, 1], o[k, 2]], float)
            dd = ti.Vector([d[k, 0], d[k, 1], d[k, 2]], float)
            tt, f, u, v = self.ray_cast(oo, dd, t_max)
            t[k] = tt
            face[k] = f
            uv[k, 0] = u
            uv[k, 1] = v

    @ti.kernel
    def _winding_batch(self, p: ti.types.ndarray(), out: ti.types.ndarray()):
        for k in range(p.shape[0]):
            out[k] = self.winding_number(ti.Vector([p[k, 0], p[k, 1], p[k, 2]], float))


def _in_box(mesh, visit):
    """A BVH visitor that passes the faces meeting the query box on to `visit` (built at compile time:
    Taichi functions cannot close over run-time values, so those travel in the query struct)."""

    @ti.func
    def adapter(q, f, ret: ti.template()):
        a, b, c = mesh.corners(f)
        if triangle_box_overlap(a, b, c, q.lo, q.hi):
            visit(q.i, f, ret)

    return adapter


def _in_sphere(mesh, visit):
    """A BVH visitor that passes the faces within the query ball on to `visit`."""

    @ti.func
    def adapter(q, f, ret: ti.template()):
        a, b, c = mesh.corners(f)
        w = point_triangle_closest(q.c, a, b, c)
        if (q.c - (w[0] * a + w[1] * b + w[2] * c)).norm_sqr() <= q.r2:
            visit(q.i, f, ret)

    return adapter


def _pad(a: np.ndarray, rows: int) -> np.ndarray:
    out = np.zeros((rows,) + a.shape[1:], a.dtype)
    out[: len(a)] = a
    return out


def _points(name: str, value) -> np.ndarray:
    return np.ascontiguousarray(
        validate.finite_array(name, np.asarray(value, dtype=np.float64).reshape(-1, 3), (3,)),
        dtype=np_float(),
    )
