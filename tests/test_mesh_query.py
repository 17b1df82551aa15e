"""Mesh queries through the BVH equal a scan over every face with the same exact per-face tests (same
distances, faces, weights, hit parameters; ties to the lowest face index), on a random triangle soup with
zero-area, needle and very large triangles and negative coordinates, an icosphere and a flat grid, with
query points exactly on faces, edges and vertices; after deforming the mesh (refit and update). The
per-face tests are checked against independent NumPy references (distances, a linear-programming
triangle-box test, winding numbers of a sphere); bad meshes raise ParameterError naming the input."""

import math

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim import ParameterError
from taichi_anim.spatial.distance import point_triangle_closest, point_triangle_distance_np
from taichi_anim.spatial.intersect import ray_triangle
from taichi_anim.spatial.mesh_query import TriangleMesh, triangle_box_overlap, winding_number_np

from .helpers import kernel_eps, ulp_tolerance

MAX_HITS = 256
# Every f64 test builds its mesh with these capacities and its scanner with NQ query rows: the same field
# layout gives the same compiled kernels, which Taichi's offline cache then shares between the tests
# (compiling the BVH queries costs far more than running them).
FACE_CAP, VERTEX_CAP, NQ = 1280, 1800, 300


def icosphere(subdivisions, radius=1.0):
    """Icosahedron subdivided `subdivisions` times, vertices pushed onto the sphere; outward faces."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t)]
    v += [(0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2)]
    f += [(10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5)]
    f += [(2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(subdivisions):
        mid = {}

        def middle(a, b, mid=mid):
            key = (min(a, b), max(a, b))
            if key not in mid:
                p = v[a] + v[b]
                v.append(p / np.linalg.norm(p))
                mid[key] = len(v) - 1
            return mid[key]

        f = [
            tri
            for a, b, c in f
            for tri in (
                (a, middle(a, b), middle(a, c)),
                (b, middle(b, c), middle(a, b)),
                (c, middle(a, c), middle(b, c)),
                (middle(a, b), middle(b, c), middle(a, c)),
            )
        ]
    return radius * np.array(v), np.array(f, np.int32)


def grid(n, h=0.25):
    """Flat n x n grid of squares of side h (exact in binary) at z = 0, two triangles each."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    v = np.stack([i.ravel() * h - 1.0, j.ravel() * h - 1.0, np.zeros(i.size)], 1)
    k = (i[:-1, :-1] * (n + 1) + j[:-1, :-1]).ravel()
    f = np.concatenate([np.stack([k, k + n + 1, k + 1], 1), np.stack([k + 1, k + n + 1, k + n + 2], 1)])
    return v, f.astype(np.int32)


def soup(nf, rng):
    """Random triangles in [-2, 1]^3 with zero-area (repeated and collinear corners), needle and huge
    triangles, and corners shared between triangles."""
    v = rng.uniform(-2.0, 1.0, (3 * nf, 3))
    f = np.arange(3 * nf).reshape(nf, 3)
    v[f[:, 1]] = v[f[:, 0]] + rng.normal(scale=0.2, size=(nf, 3))
    v[f[:, 2]] = v[f[:, 0]] + rng.normal(scale=0.2, size=(nf, 3))
    f[::11, 2] = f[::11, 1]  # repeated corner: a segment
    v[f[5::11, 2]] = 0.5 * (v[f[5::11, 0]] + v[f[5::11, 1]])  # collinear: a segment
    v[f[7::11, 1]] = v[f[7::11, 0]] + 1e-7 * rng.normal(size=(len(f[7::11]), 3))  # needle
    v[f[3]] = [[-50.0, -50.0, 0.3], [60.0, -40.0, 0.2], [0.0, 70.0, 0.4]]  # huge
    f[9::13, 0] = f[8::13, 1][: len(f[9::13])]  # shared corners
    return v, f.astype(np.int32)


@ti.data_oriented
class Brute:
    """Scans every face in index order with the per-face tests the mesh queries use."""

    def __init__(self, mesh, nq):
        self.mesh = mesh
        self.hits = ti.field(ti.i32, (nq, MAX_HITS))
        self.count = ti.field(ti.i32, nq)

    @ti.kernel
    def closest(
        self,
        p: ti.types.ndarray(),
        max_dist: float,
        dist: ti.types.ndarray(),
        face: ti.types.ndarray(),
        w: ti.types.ndarray(),
    ):
        for k in range(p.shape[0]):
            q = ti.Vector([p[k, 0], p[k, 1], p[k, 2]], float)
            best = max_dist * max_dist
            bf = -1
            bw = ti.Vector([0.0, 0.0, 0.0], float)
            for f in range(self.mesh.face_count_field[None]):
                a, b, c = self.mesh.corners(f)
                ww = point_triangle_closest(q, a, b, c)
                d2 = (q - (ww[0] * a + ww[1] * b + ww[2] * c)).norm_sqr()
                if d2 < best or (d2 == best and bf < 0):
                    best, bf, bw = d2, f, ww
            dist[k] = ti.sqrt(best)
            face[k] = bf
            for i in ti.static(range(3)):
                w[k, i] = bw[i]

    @ti.kernel
    def rays(
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
            best = t_max
            bf = -1
            bu = 0.0
            bv = 0.0
            for f in range(self.mesh.face_count_field[None]):
                a, b, c = self.mesh.corners(f)
                hit, tt, u, v = ray_triangle(oo, dd, a, b, c, t_max)
                if hit and (tt < best or (tt == best and bf < 0)):
                    best, bf, bu, bv = tt, f, u, v
            t[k] = best
            face[k] = bf
            uv[k, 0] = bu
            uv[k, 1] = bv

    @ti.func
    def visit(self, i, f, ret: ti.template()):
        if ret < MAX_HITS:
            self.hits[i, ret] = f
        ret += 1

    # The tree queries and the scans are separate kernels: a test that needs only the scan then compiles
    # only the scan.
    @ti.kernel
    def tree_boxes(self, lo: ti.types.ndarray(), hi: ti.types.ndarray()):
        for k in range(lo.shape[0]):
            a = ti.Vector([lo[k, 0], lo[k, 1], lo[k, 2]], float)
            b = ti.Vector([hi[k, 0], hi[k, 1], hi[k, 2]], float)
            acc = 0
            self.mesh.for_each_triangle_in_box(k, a, b, self.visit, acc)
            self.count[k] = acc

    @ti.kernel
    def scan_boxes(self, lo: ti.types.ndarray(), hi: ti.types.ndarray()):
        for k in range(lo.shape[0]):
            a = ti.Vector([lo[k, 0], lo[k, 1], lo[k, 2]], float)
            b = ti.Vector([hi[k, 0], hi[k, 1], hi[k, 2]], float)
            acc = 0
            for f in range(self.mesh.face_count_field[None]):
                p, q, r = self.mesh.corners(f)
                if triangle_box_overlap(p, q, r, a, b):
                    self.visit(k, f, acc)
            self.count[k] = acc

    @ti.kernel
    def tree_spheres(self, c: ti.types.ndarray(), r: ti.types.ndarray()):
        for k in range(c.shape[0]):
            p = ti.Vector([c[k, 0], c[k, 1], c[k, 2]], float)
            acc = 0
            self.mesh.for_each_triangle_in_sphere(k, p, r[k], self.visit, acc)
            self.count[k] = acc

    @ti.kernel
    def scan_spheres(self, c: ti.types.ndarray(), r: ti.types.ndarray()):
        for k in range(c.shape[0]):
            p = ti.Vector([c[k, 0], c[k, 1], c[k, 2]], float)
            acc = 0
            for f in range(self.mesh.face_count_field[None]):
                a, b, cc = self.mesh.corners(f)
                w = point_triangle_closest(p, a, b, cc)
                if (p - (w[0] * a + w[1] * b + w[2] * cc)).norm_sqr() <= r[k] * r[k]:
                    self.visit(k, f, acc)
            self.count[k] = acc

    def lists(self, nq):
        c = self.count.to_numpy()[:nq]
        assert c.max(initial=0) <= MAX_HITS
        h = self.hits.to_numpy()
        out = [h[i, : c[i]].tolist() for i in range(nq)]
        assert all(len(x) == len(set(x)) for x in out)
        return [set(x) for x in out]


def mesh_and_brute(v, f):
    """The mesh with the shared capacities, and its scanner (see FACE_CAP)."""
    mesh = TriangleMesh(v, f, face_capacity=FACE_CAP, vertex_capacity=VERTEX_CAP)
    return mesh, Brute(mesh, NQ)


def probe_points(v, f, nq, rng):
    """Random points around the mesh plus points exactly on vertices, edge midpoints and face centroids
    (exact in binary on the grid), and a few far away."""
    lo, hi = v.min(0), v.max(0)
    p = rng.uniform(lo - 0.3, hi + 0.3, (nq, 3))
    k = rng.integers(0, len(f), nq)
    p[:10] = v[f[k[:10], 0]]
    p[10:20] = 0.5 * (v[f[k[10:20], 0]] + v[f[k[10:20], 1]])
    p[20:30] = (v[f[k[20:30], 0]] + v[f[k[20:30], 1]] + 2.0 * v[f[k[20:30], 2]]) / 4.0
    p[30:35] = hi + 100.0
    return p


def check_closest_and_rays(mesh, v, f, rng, brute, nq=NQ, max_dist=math.inf, rtol=1e-9):
    """The tree's closest points and ray casts against the brute-force scan, and the distances against
    the NumPy reference.

    The tree queries and the scan are different kernels evaluating the same expressions, which LLVM may
    compile differently (fused multiply-adds, vector width): their results are compared within
    `ulp_tolerance` of the kernels' precision at the mesh's size, never bit for bit. Where the two
    report different faces, both must be equally good within that tolerance (a query point on an edge or
    vertex, a ray through a shared edge); where one hits and the other misses, the hit lies on the
    triangle's border."""
    scale = np.abs(v).max()
    tol, rel = ulp_tolerance(scale), ulp_tolerance(1.0)
    # Moller-Trumbore's u, v lose accuracy as 1/det for grazing rays: a border hit is within sqrt(eps).
    border = math.sqrt(kernel_eps())
    p = probe_points(v, f, nq, rng)
    dist, face, w = mesh.closest_points(p, max_dist=max_dist)
    ref = [np.zeros(nq), np.zeros(nq, np.int32), np.zeros((nq, 3))]
    brute.closest(p, max_dist, *ref)
    rdist, rface, rw = ref
    found = face >= 0
    edge_of_range = np.abs(np.where(found, dist, rdist) - max_dist) <= tol
    assert np.all((found == (rface >= 0)) | edge_of_range)
    both = found & (rface >= 0)
    np.testing.assert_allclose(dist[both], rdist[both], rtol=rel, atol=tol)
    # The closest points themselves (the same point when two faces tie at an edge or vertex).
    point = np.einsum("ki,kij->kj", w[both], v[f[face[both]]])
    rpoint = np.einsum("ki,kij->kj", rw[both], v[f[rface[both]]])
    np.testing.assert_allclose(point, rpoint, rtol=0, atol=tol)
    assert (face[both] == rface[both]).mean() > 0.8  # ties are the exception, not the rule
    # the distances themselves against the NumPy reference (independent code)
    tri = v[f[face[found]]]
    nref = point_triangle_distance_np(p[found], tri[:, 0], tri[:, 1], tri[:, 2])
    np.testing.assert_allclose(dist[found], nref, rtol=rtol, atol=rtol * scale)
    d = rng.normal(size=(nq, 3))
    d[:40] = p[:40] - p[40:80]  # rays aimed exactly at vertices, edge midpoints and centroids
    o = p[40:80].copy()
    origins = np.concatenate([o, p[40:]])
    t_max = 4.0
    got = mesh.ray_casts(origins, d, t_max=t_max)
    t, hit_face, uv = got[0], got[1], np.stack(got[2:], 1)
    ref = [np.zeros(nq), np.zeros(nq, np.int32), np.zeros((nq, 2))]
    brute.rays(origins, d, t_max, *ref)
    rt, rhit, ruv = ref
    length = np.linalg.norm(d, axis=1)
    hit, rhit_ = hit_face >= 0, rhit >= 0

    def on_border(uv_, k):
        bary = np.stack([uv_[k, 0], uv_[k, 1], 1.0 - uv_[k, 0] - uv_[k, 1]], 1)
        return np.abs(bary).min(1) <= border

    odd = hit != rhit_
    assert np.all(on_border(uv, odd & hit) | (np.abs(t[odd & hit] - t_max) * length[odd & hit] <= tol))
    assert np.all(
        on_border(ruv, odd & rhit_) | (np.abs(rt[odd & rhit_] - t_max) * length[odd & rhit_] <= tol)
    )
    both = hit & rhit_
    np.testing.assert_allclose(t[both] * length[both], rt[both] * length[both], rtol=rel, atol=tol)
    for tt, ff, bb, k in ((t, hit_face, uv, hit), (rt, rhit, ruv, rhit_)):  # each face holds its hit point
        corners = v[f[ff[k]]]
        on_face = (
            (1.0 - bb[k].sum(1))[:, None] * corners[:, 0]
            + bb[k, :1] * corners[:, 1]
            + bb[k, 1:] * corners[:, 2]
        )
        np.testing.assert_allclose(
            on_face, origins[k] + tt[k, None] * d[k], rtol=0, atol=ulp_tolerance(scale, 1024)
        )
    same = both & (hit_face == rhit)
    np.testing.assert_allclose(uv[same], ruv[same], rtol=0, atol=border)
    assert same.sum() >= 0.8 * both.sum()
    return got


def check_box_and_sphere(mesh, v, f, rng, brute, nq=NQ):
    """Faces overlapping boxes and spheres: the tree query against the scan. A face may be listed by one
    and not the other only where it touches the box or the sphere within `ulp_tolerance` (point boxes on
    vertices and edges, zero radii): the two kernels may round the touching test differently."""
    tol = ulp_tolerance(np.abs(v).max())
    c = probe_points(v, f, nq, rng)
    e = rng.uniform(0.0, 0.3, (nq, 3))
    e[:15] = 0.0  # point boxes on vertices and edges
    lo, hi = c - e, c + e
    brute.tree_boxes(lo, hi)
    got = brute.lists(nq)
    brute.scan_boxes(lo, hi)
    want = brute.lists(nq)
    for k in range(nq):
        for face in got[k] ^ want[k]:
            assert clipped_nonempty(v[f[face]], lo[k] - tol, hi[k] + tol)
            assert not clipped_nonempty(v[f[face]], lo[k] + tol, hi[k] - tol) or np.any(
                hi[k] - lo[k] < 2 * tol
            )
    r = rng.uniform(0.0, 0.3, nq)
    r[:15] = 0.0
    brute.tree_spheres(c, r)
    got_s = brute.lists(nq)
    brute.scan_spheres(c, r)
    want_s = brute.lists(nq)
    for k in range(nq):
        odd = sorted(got_s[k] ^ want_s[k])
        if odd:
            tri = v[f[odd]]
            dk = point_triangle_distance_np(
                np.repeat(c[k : k + 1], len(odd), 0), tri[:, 0], tri[:, 1], tri[:, 2]
            )
            np.testing.assert_allclose(dk, r[k], rtol=0, atol=tol)
    return lo, hi, got


def test_soup_queries_equal_brute_force():
    rng = np.random.default_rng(21)
    v, f = soup(600, rng)
    mesh, brute = mesh_and_brute(v, f)
    check_closest_and_rays(mesh, v, f, rng, brute)
    check_closest_and_rays(mesh, v, f, rng, brute, max_dist=0.05)
    check_box_and_sphere(mesh, v, f, rng, brute)


def test_sphere_and_grid_queries_equal_brute_force():
    rng = np.random.default_rng(22)
    sphere = icosphere(3, radius=0.7)
    mesh, brute = mesh_and_brute(*sphere)
    for v, f in (sphere, grid(24)):
        mesh.set_mesh(v, f)
        t, face, u, w = check_closest_and_rays(mesh, v, f, rng, brute)
        assert (face >= 0).sum() > 20
        check_box_and_sphere(mesh, v, f, rng, brute)


def test_deformed_mesh_refit_and_update():
    rng = np.random.default_rng(23)
    v, f = icosphere(3)
    mesh, brute = mesh_and_brute(v, f)
    for step in range(3):
        v = v * np.array([1.0 + 0.3 * step, 1.0, 1.0 - 0.2 * step]) + 0.05 * rng.normal(size=v.shape)
        if step == 2:
            mesh.vertex_x.from_numpy(np.vstack([v, np.zeros((VERTEX_CAP - len(v), 3))]))
            mesh.refit()
        else:
            mesh.set_vertices(v)
        check_closest_and_rays(mesh, v, f, rng, brute, nq=150)
    # scramble which vertex sits where: the tree's cost soars and update() rebuilds
    builds = mesh.bvh.build_count
    assert mesh.set_vertices(v[rng.permutation(len(v))])
    assert mesh.bvh.build_count == builds + 1


def clipped_nonempty(tri, lo, hi):
    """Whether anything of the (possibly degenerate) triangle survives clipping by the six planes of
    the box (Sutherland-Hodgman): an independent reference for the separating-axis test."""
    poly = [np.asarray(p, float) for p in tri]
    for axis in range(3):
        for bound, sign in ((lo[axis], 1.0), (hi[axis], -1.0)):
            out = []
            for k, p in enumerate(poly):
                q = poly[(k + 1) % len(poly)]
                dp, dq = sign * (p[axis] - bound), sign * (q[axis] - bound)
                if dp >= 0.0:
                    out.append(p)
                if (dp >= 0.0) != (dq >= 0.0):
                    out.append(p + (q - p) * (dp / (dp - dq)))
            poly = out
            if not poly:
                return False
    return True


def test_triangle_box_overlap_against_clipping():
    """The separating-axis test against polygon clipping; pairs within 1e-9 of touching (where the two
    disagree with the box grown or shrunk by 1e-9) are left out."""
    rng = np.random.default_rng(24)
    v, f = soup(200, rng)
    mesh, brute = mesh_and_brute(v, f)
    nq = 40
    lo, hi = (rng.uniform(-2.0, 1.0, (nq, 3)) for _ in range(2))
    lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
    lo[:, 0] = hi[:, 0] - 0.3
    brute.scan_boxes(lo, hi)
    got = brute.lists(nq)
    checked = 0
    tlo, thi = v[f].min(1), v[f].max(1)
    for k in range(nq):
        for t in range(len(f)):
            tri = v[f[t]]
            if np.any(tlo[t] > hi[k] + 1e-6) or np.any(thi[t] < lo[k] - 1e-6):
                want = [False, False]  # the boxes are apart: no need to clip
            else:
                want = [clipped_nonempty(tri, lo[k] - g, hi[k] + g) for g in (-1e-9, 1e-9)]
            if want[0] == want[1]:
                assert (t in got[k]) == want[0], (k, t)
                checked += 1
    assert checked > 0.99 * nq * len(f) and sum(map(len, got)) > 50


def test_winding_number_of_a_closed_sphere():
    rng = np.random.default_rng(25)
    v, f = icosphere(2)
    mesh = TriangleMesh(v, f, face_capacity=FACE_CAP, vertex_capacity=VERTEX_CAP)
    p = rng.uniform(-1.5, 1.5, (400, 3))
    r = np.linalg.norm(p, axis=1)
    p = p[(r < 0.75) | (r > 1.05)]  # clear of the faceted surface (inscribed radius > 0.79)
    w = mesh.winding_numbers(p)
    np.testing.assert_allclose(w, winding_number_np(v, f, p), atol=1e-9)
    inside = np.linalg.norm(p, axis=1) < 0.75
    np.testing.assert_allclose(w, inside.astype(float), atol=1e-9)
    np.testing.assert_array_equal(mesh.inside(p), inside)
    # reversed orientation: -1 inside; an open mesh (one face removed) is fractional near the hole
    assert np.allclose(winding_number_np(v, f[:, ::-1], p[inside]), -1.0)
    hole = winding_number_np(v, f[1:], v[f[0]].mean(0, keepdims=True) * 0.9)
    assert 0.1 < hole[0] < 0.9


def test_inside_closed_mesh_sums_in_numpy_below_the_bound_and_in_a_kernel_above(monkeypatch):
    """A builder's one-off inside test compiles no kernel while points x faces stay under the bound, and
    both ways give the sphere's inside exactly (points clear of the faceted surface)."""
    from taichi_anim.compile_clock import CompileClock
    from taichi_anim.spatial import mesh_query

    rng = np.random.default_rng(27)
    v, f = icosphere(2)
    p = rng.uniform(-1.5, 1.5, (400, 3))
    r = np.linalg.norm(p, axis=1)
    p = p[(r < 0.75) | (r > 1.05)]
    want = np.linalg.norm(p, axis=1) < 0.75
    assert len(p) * len(f) <= mesh_query.NUMPY_WINDING_PAIRS
    for bound, compiles in ((mesh_query.NUMPY_WINDING_PAIRS, False), (0, True)):
        monkeypatch.setattr(mesh_query, "NUMPY_WINDING_PAIRS", bound)
        with CompileClock() as clock:
            got = mesh_query.inside_closed_mesh(v, f, p)
        np.testing.assert_array_equal(got, want)
        assert (clock.kernels > 0) == compiles


def test_f32_parallel_icosphere():
    ta.init("cpu", precision="f32")
    rng = np.random.default_rng(26)
    v, f = icosphere(5)  # 20480 faces: the BVH's loops run in parallel
    mesh = TriangleMesh(v, f)
    v32 = v.astype(np.float32).astype(np.float64)
    check_closest_and_rays(mesh, v32, f, rng, Brute(mesh, 100), nq=100, rtol=1e-5)


def test_bad_meshes_raise():
    v, f = icosphere(0)
    with pytest.raises(ParameterError, match="vertices is empty"):
        TriangleMesh(np.zeros((0, 3)), f)
    with pytest.raises(ParameterError, match="faces is empty"):
        TriangleMesh(v, np.zeros((0, 3), int))
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ParameterError, match="non-finite"):
        TriangleMesh(bad, f)
    with pytest.raises(ParameterError, match=r"faces\[2\]"):
        TriangleMesh(v, np.vstack([f[:2], [[0, 1, 12]], f[3:]]))
    with pytest.raises(ParameterError, match="index outside"):
        TriangleMesh(v, -f)
    with pytest.raises(ParameterError, match="integers"):
        TriangleMesh(v, f.astype(float))
    with pytest.raises(ParameterError, match="degenerate mesh"):
        TriangleMesh(np.zeros((3, 3)), [[0, 1, 2]])
    mesh = TriangleMesh(v, f, face_capacity=FACE_CAP, vertex_capacity=VERTEX_CAP)
    with pytest.raises(ParameterError, match="vertex_capacity"):
        mesh.set_mesh(np.vstack([v + 3.0 * k for k in range(VERTEX_CAP // len(v) + 1)]), f)
    with pytest.raises(ParameterError, match="expected 12 rows"):
        mesh.set_vertices(v[:5])
