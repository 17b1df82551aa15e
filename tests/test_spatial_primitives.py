"""Bounding volumes, closest points and intersection tests (taichi_anim.spatial) against references that
do not share their code.

- Boxes against NumPy min/max; the slab ray test against NumPy and dense sampling of the ray.
- Minimal enclosing spheres against the optimality certificate of the smallest ball (it holds every
  vertex, and its centre lies in the convex hull of the vertices on its boundary).
- Closest points (point–triangle, segment–segment) against the first-order optimality conditions of the
  convex problem, (p - q) . (v - q) <= 0 for every vertex v, which hold only at the minimiser, and against
  dense sampling and scipy; on random, degenerate (zero-area, needle, coincident), very large and
  negative-coordinate input.

Triangle–triangle and segment/ray–triangle tests against an exact reference: tests/test_spatial_exact.py.
"""

import itertools

import numpy as np
import taichi as ti

import taichi_anim as ta
from taichi_anim.spatial import (
    aabb_contains,
    aabb_edge,
    aabb_merge,
    aabb_overlap,
    aabb_point,
    aabb_point_distance_sq,
    aabb_ray,
    aabb_sphere_overlap,
    aabb_surface_area,
    aabb_swept_edge,
    aabb_swept_point,
    aabb_swept_triangle,
    aabb_triangle,
    point_triangle_closest,
    point_triangle_feature,
    segment_segment_closest,
    sphere_edge,
    sphere_overlap,
    sphere_triangle,
)
from taichi_anim.spatial.bounds import aabb_ray_np, sphere_triangle_np
from taichi_anim.spatial.distance import (
    point_triangle_closest_np,
    point_triangle_feature_np,
    segment_segment_closest_np,
)

from .helpers import row_vec3 as _v


@ti.func
def _put(out: ti.template(), i, col: ti.template(), v: ti.template()):
    for j in ti.static(range(3)):
        out[i, col + j] = v[j]


def _dot(x, y):
    return (x * y).sum(-1)


# ------------------------------------------------------------------------------------------------ boxes


@ti.kernel
def _boxes(x: ti.types.ndarray(ndim=2), pad: float, out: ti.types.ndarray(ndim=2)):
    # x rows: 6 points a0 b0 c0 a1 b1 c1; out: lo/hi of point, edge, tri, swept point/edge/tri (36 cols).
    for i in range(x.shape[0]):
        a0, b0, c0, a1, b1, c1 = _v(x, i, 0), _v(x, i, 1), _v(x, i, 2), _v(x, i, 3), _v(x, i, 4), _v(x, i, 5)
        boxes = (
            aabb_point(a0, pad),
            aabb_edge(a0, b0, pad),
            aabb_triangle(a0, b0, c0, pad),
            aabb_swept_point(a0, a1, pad),
            aabb_swept_edge(a0, b0, a1, b1, pad),
            aabb_swept_triangle(a0, b0, c0, a1, b1, c1, pad),
        )
        for k in ti.static(range(6)):
            _put(out, i, 6 * k, boxes[k][0])
            _put(out, i, 6 * k + 3, boxes[k][1])


@ti.kernel
def _box_pairs(x: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=2)):
    # x rows: lo0 hi0 lo1 hi1 c (sphere centre) p (point) r; out: overlap, sphere overlap, contains,
    # distance^2, area0, merged lo, merged hi.
    for i in range(x.shape[0]):
        lo0, hi0, lo1, hi1, c, p = (
            _v(x, i, 0),
            _v(x, i, 1),
            _v(x, i, 2),
            _v(x, i, 3),
            _v(x, i, 4),
            _v(x, i, 5),
        )
        r = x[i, 18]
        out[i, 0] = aabb_overlap(lo0, hi0, lo1, hi1)
        out[i, 1] = aabb_sphere_overlap(lo0, hi0, c, r)
        out[i, 2] = aabb_contains(lo0, hi0, p)
        out[i, 3] = aabb_point_distance_sq(lo0, hi0, p)
        out[i, 4] = aabb_surface_area(lo0, hi0)
        lo, hi = aabb_merge(lo0, hi0, lo1, hi1)
        _put(out, i, 5, lo)
        _put(out, i, 8, hi)


def test_boxes_of_primitives_and_swept_primitives():
    rng = np.random.default_rng(1)
    x = rng.uniform(-50.0, 50.0, size=(500, 18))
    pad = 0.25
    out = np.zeros((500, 36))
    _boxes(x, pad, out)
    pts = x.reshape(500, 6, 3)
    for k, idx in enumerate([[0], [0, 1], [0, 1, 2], [0, 3], [0, 1, 3, 4], [0, 1, 2, 3, 4, 5]]):
        np.testing.assert_array_equal(out[:, 6 * k : 6 * k + 3], pts[:, idx].min(1) - pad)
        np.testing.assert_array_equal(out[:, 6 * k + 3 : 6 * k + 6], pts[:, idx].max(1) + pad)
    # A swept box holds the linearly moving primitive at every time.
    for t in np.linspace(0.0, 1.0, 11):
        xt = (1 - t) * pts[:, :3] + t * pts[:, 3:]
        assert np.all(xt >= out[:, None, 30:33]) and np.all(xt <= out[:, None, 33:36])


def test_box_overlaps_touching_counts():
    """Integer boxes so that touching (equal faces, a ball at exactly distance r) is represented exactly."""
    rng = np.random.default_rng(2)
    n = 4000
    lo0 = rng.integers(-3, 3, size=(n, 3)).astype(float)
    hi0 = lo0 + rng.integers(0, 4, size=(n, 3))  # zero-thickness boxes included
    lo1 = rng.integers(-3, 3, size=(n, 3)).astype(float)
    hi1 = lo1 + rng.integers(0, 4, size=(n, 3))
    hi0[:5] = lo0[:5] - 1.0  # empty boxes: zero surface area
    c = rng.integers(-9, 9, size=(n, 3)).astype(float)
    p = rng.integers(-7, 7, size=(n, 3)).astype(float)
    r = rng.integers(0, 6, size=n).astype(float)
    # Balls that touch a box at its corner: a 3-4-5 triangle puts the centre at distance exactly r.
    c[10:20] = hi0[10:20] + np.array([3.0, 4.0, 0.0])
    r[10:20] = 5.0
    x = np.concatenate([lo0, hi0, lo1, hi1, c, p, r[:, None]], axis=1)
    out = np.zeros((n, 11))
    _box_pairs(x, out)
    overlap = np.all(lo0 <= hi1, axis=1) & np.all(lo1 <= hi0, axis=1)
    d = np.maximum(lo0 - c, 0.0) + np.maximum(c - hi0, 0.0)
    dp = np.maximum(lo0 - p, 0.0) + np.maximum(p - hi0, 0.0)
    e = np.maximum(hi0 - lo0, 0.0)
    np.testing.assert_array_equal(out[:, 0], overlap)
    assert overlap.mean() > 0.1 and (~overlap).mean() > 0.1
    touching = overlap & (np.any(lo0 == hi1, axis=1) | np.any(lo1 == hi0, axis=1))
    assert touching.sum() > 100
    np.testing.assert_array_equal(out[:, 1], _dot(d, d) <= r * r)
    assert np.all(out[10:20, 1] == 1)
    np.testing.assert_array_equal(out[:, 2], np.all((lo0 <= p) & (p <= hi0), axis=1))
    np.testing.assert_array_equal(out[:, 3], _dot(dp, dp))
    np.testing.assert_array_equal(out[:, 4], 2 * (e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]))
    assert np.all(out[:5, 4] == 0.0)
    np.testing.assert_array_equal(out[:, 5:8], np.minimum(lo0, lo1))
    np.testing.assert_array_equal(out[:, 8:11], np.maximum(hi0, hi1))


@ti.kernel
def _rays(x: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=2)):
    # x rows: lo hi o d t_max; the kernel forms 1/d itself, so zero components give ±inf.
    for i in range(x.shape[0]):
        inv_d = 1.0 / _v(x, i, 3)
        hit, t = aabb_ray(_v(x, i, 0), _v(x, i, 1), _v(x, i, 2), inv_d, x[i, 12])
        out[i, 0] = hit
        out[i, 1] = t


def test_aabb_ray_slab_test_with_zero_direction_components():
    rng = np.random.default_rng(3)
    n = 3000
    lo = rng.integers(-4, 4, size=(n, 3)).astype(float)
    hi = lo + rng.integers(0, 4, size=(n, 3))
    o = rng.integers(-8, 8, size=(n, 3)).astype(float)
    d = rng.integers(-3, 4, size=(n, 3)).astype(float)  # many zero components
    aim = np.minimum(lo + rng.integers(0, 4, size=(n, 3)), hi)  # half the rays aim at a point of the box
    d[n // 2 :] = (aim - o)[n // 2 :]
    d[:50] = [1.0, 0.0, 0.0]
    o[:50, 1:] = lo[:50, 1:]  # origin on slab planes, direction parallel to them
    d[50:60] = -0.0
    d[np.all(d == 0.0, axis=1)] = [0.0, 0.0, 1.0]
    t_max = rng.choice([0.5, 1.0, 3.0, 1e6], size=n)
    x = np.concatenate([lo, hi, o, d, t_max[:, None]], axis=1)
    out = np.zeros((n, 2))
    _rays(x, out)
    hit_ref, t_ref = aabb_ray_np(lo, hi, o, d, t_max)
    np.testing.assert_array_equal(out[:, 0], hit_ref)
    np.testing.assert_allclose(out[hit_ref, 1], t_ref[hit_ref], rtol=1e-15, atol=0.0)
    assert hit_ref.mean() > 0.1 and (~hit_ref).mean() > 0.1
    # The reference itself against the ray sampled densely: at t_enter the point is in the box, before
    # it never is (strictly); a miss never enters the box's interior.
    ts = np.linspace(0.0, 1.0, 1001)[None, :] * np.minimum(t_max, 20.0)[:, None]
    pts = o[:, None, :] + ts[..., None] * d[:, None, :]
    pe = o + t_ref[:, None] * d
    assert np.all(np.all((pe >= lo - 1e-9) & (pe <= hi + 1e-9), axis=1)[hit_ref])
    strictly_before = ts < t_ref[:, None] - 1e-6
    strict_in = np.all((pts > lo[:, None] + 1e-6) & (pts < hi[:, None] - 1e-6), axis=-1)
    assert not np.any(strict_in & strictly_before & hit_ref[:, None])
    assert not np.any(strict_in[~hit_ref & (t_max <= 20.0)])


# ---------------------------------------------------------------------------------------------- spheres


@ti.kernel
def _spheres(x: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=2)):
    for i in range(x.shape[0]):
        c, r = sphere_triangle(_v(x, i, 0), _v(x, i, 1), _v(x, i, 2))
        _put(out, i, 0, c)
        out[i, 3] = r
        ce, re = sphere_edge(_v(x, i, 0), _v(x, i, 1))
        _put(out, i, 4, ce)
        out[i, 7] = re
        out[i, 8] = sphere_overlap(c, r, ce + _v(x, i, 3), re)


def _triangle_zoo(rng, n):
    """(n, 3, 3) triangles: random, obtuse, needle, zero-area (collinear, coincident), huge, negative."""
    t = rng.normal(size=(n, 3, 3))
    k = n // 8
    t[k : 2 * k, 2] = 0.5 * (t[k : 2 * k, 0] + t[k : 2 * k, 1]) + 0.05 * rng.normal(size=(k, 3))  # obtuse
    t[2 * k : 3 * k, 1] = t[2 * k : 3 * k, 0] + 1e-7 * rng.normal(size=(k, 3))  # needle
    s = rng.uniform(-1.0, 2.0, size=(k, 1))
    t[3 * k : 4 * k, 2] = t[3 * k : 4 * k, 0] + s * (t[3 * k : 4 * k, 1] - t[3 * k : 4 * k, 0])  # collinear
    t[4 * k : 4 * k + k // 2, 1] = t[4 * k : 4 * k + k // 2, 0]  # two coincident
    t[4 * k + k // 2 : 5 * k] = t[4 * k + k // 2 : 5 * k, :1]  # a point
    t[5 * k : 6 * k] *= 1e6  # very large
    t[6 * k : 7 * k] -= 1e3  # far in negative coordinates
    return t


def test_sphere_triangle_is_the_minimal_enclosing_ball():
    rng = np.random.default_rng(4)
    n = 2000
    tri = _triangle_zoo(rng, n)
    shift = rng.normal(size=(n, 3))
    x = np.concatenate([tri.reshape(n, 9), shift], axis=1)
    out = np.zeros((n, 9))
    _spheres(x, out)
    c, r = out[:, :3], out[:, 3]
    assert np.all(np.isfinite(out))
    scale = np.abs(tri).max(axis=(1, 2)) + 1.0
    dist = np.linalg.norm(tri - c[:, None, :], axis=-1)  # (n, 3)
    assert np.all(dist <= r[:, None] + 1e-12 * scale[:, None]), "the sphere must hold the triangle"
    # Optimality: the centre is in the convex hull of the vertices on the sphere.
    on = dist >= r[:, None] - 1e-7 * scale[:, None]
    for i in range(n):
        pts = tri[i][on[i]]
        if len(pts) == 1:
            assert np.linalg.norm(pts[0] - c[i]) <= 1e-9 * scale[i] or r[i] <= 1e-9 * scale[i]
        elif (
            len(pts) == 2 or np.linalg.norm(np.cross(pts[1] - pts[0], pts[2] - pts[0])) < 1e-9 * scale[i] ** 2
        ):
            far = max(itertools.combinations(pts, 2), key=lambda ab: np.linalg.norm(ab[1] - ab[0]))
            np.testing.assert_allclose(c[i], 0.5 * (far[0] + far[1]), atol=1e-7 * scale[i])
        else:
            lam = np.linalg.lstsq(np.vstack([pts.T, np.ones((1, 3))]), np.r_[c[i], 1.0], rcond=None)[0]
            assert lam.min() >= -1e-6, (i, lam)
    cn, rn = sphere_triangle_np(tri[:, 0], tri[:, 1], tri[:, 2])
    np.testing.assert_allclose(r, rn, rtol=1e-9, atol=1e-12 * scale.max())
    np.testing.assert_allclose(out[:, 4:7], 0.5 * (tri[:, 0] + tri[:, 1]), rtol=1e-15)
    np.testing.assert_allclose(out[:, 7], 0.5 * np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1), rtol=1e-15)
    np.testing.assert_array_equal(out[:, 8], np.linalg.norm(out[:, 4:7] + shift - c, axis=1) <= r + out[:, 7])


# ------------------------------------------------------------------------------------- closest points


@ti.kernel
def _closest(x: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=2)):
    # x rows: p a b c (point-triangle) and p0 p1 q0 q1 (segments) share the 12 columns.
    for i in range(x.shape[0]):
        w = point_triangle_closest(_v(x, i, 0), _v(x, i, 1), _v(x, i, 2), _v(x, i, 3))
        _put(out, i, 0, w)
        out[i, 3] = point_triangle_feature(w)
        s, t = segment_segment_closest(_v(x, i, 0), _v(x, i, 1), _v(x, i, 2), _v(x, i, 3))
        out[i, 4] = s
        out[i, 5] = t


def _run_closest(x, dtype=np.float64):
    out = np.zeros((len(x), 6), dtype=dtype)
    _closest(np.ascontiguousarray(x, dtype=dtype), out)
    return out.astype(np.float64)


def _point_triangle_cases(rng):
    """Rows (p, a, b, c): triangles of the zoo with points near them, on them, and far off."""
    tri = _triangle_zoo(rng, 2400)
    n = len(tri)
    scale = np.abs(tri).max(axis=(1, 2))[:, None] + 1.0
    w = rng.dirichlet([1.0, 1.0, 1.0], size=n)
    on = np.einsum("nk,nkd->nd", w, tri)
    p = on + rng.normal(size=(n, 3)) * np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1)[:, None] * rng.choice(
        [0.0, 0.1, 1.0, 10.0], size=(n, 1)
    )
    p[::7] = tri[::7, 1]  # exactly on a vertex
    p[1::7] = 0.5 * (tri[1::7, 1] + tri[1::7, 2])  # exactly on an edge
    p[2::7] = rng.normal(size=(len(p[2::7]), 3)) * scale[2::7] * 3.0  # anywhere
    return np.concatenate([p[:, None, :], tri], axis=1).reshape(n, 12)


def test_point_triangle_closest_is_optimal_and_matches_sampling():
    rng = np.random.default_rng(5)
    x = _point_triangle_cases(rng)
    out = _run_closest(x)
    p, a, b, c = (x[:, 3 * k : 3 * k + 3] for k in range(4))
    w = out[:, :3]
    assert np.all(np.isfinite(w)) and w.min() >= 0.0
    np.testing.assert_allclose(w.sum(1), 1.0, rtol=0, atol=1e-14)
    q = w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c
    scale = np.max(np.abs(x), axis=1) + 1.0
    # First-order optimality over the triangle (convex hull of a, b, c): (p - q) . (v - q) <= 0.
    kkt = np.stack([_dot(p - q, v - q) for v in (a, b, c)], axis=1).max(1)
    assert np.all(kkt <= 1e-13 * scale**2), kkt.max()
    # The NumPy reference gives the same point (weights may differ where vertices coincide).
    qn_w = point_triangle_closest_np(p, a, b, c)
    qn = qn_w[:, :1] * a + qn_w[:, 1:2] * b + qn_w[:, 2:] * c
    np.testing.assert_allclose(np.linalg.norm(q - qn, axis=1), 0.0, atol=1e-12 * scale.max())
    # Dense sampling of the triangle (1,326 barycentric points): nothing sampled is closer.
    g = np.array([(i, j) for i in range(51) for j in range(51 - i)], dtype=float) / 50.0
    wg = np.c_[1.0 - g.sum(1), g]
    d = np.linalg.norm(p - q, axis=1)
    for lo in range(0, len(x), 400):
        sl = slice(lo, lo + 400)
        samples = np.einsum("gk,nkd->ngd", wg, np.stack([a[sl], b[sl], c[sl]], axis=1))
        ds = np.linalg.norm(samples - p[sl, None, :], axis=-1).min(1)
        assert np.all(d[sl] <= ds + 1e-12 * scale[sl])


def test_point_triangle_feature_codes():
    """Points placed in each Voronoi region of well-shaped triangles, and exactly on features."""
    rng = np.random.default_rng(6)
    n = 300
    # Even integer coordinates: edge midpoints are then exactly on the edges.
    a, b, c = (2.0 * np.round(rng.normal(size=(n, 3)) * 3.0) for _ in range(3))
    nrm = np.cross(b - a, c - a)
    keep = np.linalg.norm(nrm, axis=1) > 2.0
    a, b, c, nrm = a[keep], b[keep], c[keep], nrm[keep]
    nh = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    m = len(a)
    h = rng.uniform(-2.0, 2.0, size=(m, 1)) * nh
    unit = lambda v: v / np.linalg.norm(v, axis=1, keepdims=True)  # noqa: E731
    rows, expect = [], []
    rows.append((a + b + c) / 3 + h), expect.append(0)
    for code, (x, y, z) in zip((1, 2, 3), ((a, b, c), (b, c, a), (c, a, b)), strict=True):
        out_dir = unit(np.cross(y - x, nh))
        out_dir *= np.sign(_dot(out_dir, x - z))[:, None]  # away from the third vertex
        rows.append(0.5 * (x + y) + out_dir + h), expect.append(code)
        rows.append(0.5 * (x + y)), expect.append(code)
    for code, (x, y, z) in zip((4, 5, 6), ((a, b, c), (b, c, a), (c, a, b)), strict=True):
        rows.append(x - unit(y - x) - unit(z - x) + h), expect.append(code)
        rows.append(x.copy()), expect.append(code)
    p = np.concatenate(rows)
    code = np.repeat(expect, m)
    tri = np.tile(np.concatenate([a, b, c], axis=1), (len(rows), 1))
    out = _run_closest(np.concatenate([p, tri], axis=1))
    np.testing.assert_array_equal(out[:, 3], code)
    np.testing.assert_array_equal(point_triangle_feature_np(out[:, :3]), code)


def _segment_cases(rng):
    n = 3000
    x = rng.normal(size=(n, 4, 3))
    k = n // 10
    d = rng.normal(size=(k, 1, 3))
    x[k : 2 * k, 1] = x[k : 2 * k, 0] + d[:, 0]  # parallel
    x[k : 2 * k, 3] = x[k : 2 * k, 2] + rng.uniform(-2, 2, size=(k, 1)) * d[:, 0]
    sl = slice(2 * k, 3 * k)  # collinear
    x[sl, 2] = x[sl, 0] + rng.uniform(-2, 2, size=(k, 1)) * (x[sl, 1] - x[sl, 0])
    x[sl, 3] = x[sl, 0] + rng.uniform(-2, 2, size=(k, 1)) * (x[sl, 1] - x[sl, 0])
    x[3 * k : 4 * k, 1] = x[3 * k : 4 * k, 0]  # first is a point
    x[4 * k : 5 * k, 3] = x[4 * k : 5 * k, 2]  # second is a point
    x[5 * k : 5 * k + k // 2, 1] = x[5 * k : 5 * k + k // 2, 0]
    x[5 * k : 5 * k + k // 2, 3] = x[5 * k : 5 * k + k // 2, 2]  # both points
    x[5 * k + k // 2 : 6 * k] = x[5 * k + k // 2 : 6 * k, :1]  # all coincident
    sl = slice(6 * k, 7 * k)  # nearly parallel
    x[sl, 3] = x[sl, 2] + (x[sl, 1] - x[sl, 0]) * (1 + 1e-9)
    x[7 * k : 8 * k] *= 1e6
    x[8 * k : 9 * k] -= 1e3
    # Crossing segments: the second passes through a point of the first.
    s = rng.uniform(0, 1, size=(k, 1))
    mid = x[9 * k :, 0] + s * (x[9 * k :, 1] - x[9 * k :, 0])
    x[9 * k :, 3] = 2 * mid - x[9 * k :, 2]
    return x.reshape(n, 12)


def test_segment_segment_closest_is_optimal_and_matches_sampling():
    from scipy.optimize import minimize

    rng = np.random.default_rng(7)
    x = _segment_cases(rng)
    out = _run_closest(x)
    p0, p1, q0, q1 = (x[:, 3 * k : 3 * k + 3] for k in range(4))
    s, t = out[:, 4], out[:, 5]
    assert np.all((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1))
    xs = p0 + s[:, None] * (p1 - p0)
    ys = q0 + t[:, None] * (q1 - q0)
    scale = np.max(np.abs(x), axis=1) + 1.0
    # Optimality of the pair over the product of the two segments: (x - y) . (p - x) >= 0 for p in
    # {p0, p1} and (y - x) . (q - y) >= 0 for q in {q0, q1}.
    g = np.stack(
        [_dot(xs - ys, p0 - xs), _dot(xs - ys, p1 - xs), _dot(ys - xs, q0 - ys), _dot(ys - xs, q1 - ys)], 1
    ).min(1)
    assert np.all(g >= -1e-12 * scale**2), g.min()
    d = np.linalg.norm(xs - ys, axis=1)
    sn, tn = segment_segment_closest_np(p0, p1, q0, q1)
    dn = np.linalg.norm(p0 + sn[:, None] * (p1 - p0) - q0 - tn[:, None] * (q1 - q0), axis=1)
    np.testing.assert_allclose(d, dn, rtol=0, atol=1e-12 * scale.max())
    # Dense sampling (65 x 65 parameter pairs).
    u = np.linspace(0.0, 1.0, 65)
    for lo in range(0, len(x), 500):
        sl = slice(lo, lo + 500)
        a_ = p0[sl, None, :] + u[None, :, None] * (p1 - p0)[sl, None, :]
        b_ = q0[sl, None, :] + u[None, :, None] * (q1 - q0)[sl, None, :]
        ds = np.linalg.norm(a_[:, :, None, :] - b_[:, None, :, :], axis=-1).min(axis=(1, 2))
        assert np.all(d[sl] <= ds + 1e-12 * scale[sl])
    # scipy on a subset, from several starts.
    for i in rng.choice(len(x), 40, replace=False):
        f = lambda z, i=i: np.sum((p0[i] + z[0] * (p1[i] - p0[i]) - q0[i] - z[1] * (q1[i] - q0[i])) ** 2)  # noqa: E731
        best = min(
            minimize(f, z0, bounds=[(0, 1), (0, 1)], method="L-BFGS-B", options={"ftol": 1e-15}).fun
            for z0 in ([0.5, 0.5], [0.0, 1.0], [1.0, 0.0])
        )
        assert d[i] ** 2 <= best + 1e-9 * scale[i] ** 2


def test_closest_points_in_f32_are_finite_and_close():
    """f32: degenerate input gives no NaN, and distances stay within 1e-5 of the scene scale."""
    ta.init("cpu", precision="f32")
    rng = np.random.default_rng(8)
    for x in (_point_triangle_cases(rng), _segment_cases(rng)):
        keep = np.max(np.abs(x), axis=1) < 10.0  # f32 absolute accuracy is relative to the coordinates
        x = x[keep]
        x = x.astype(np.float32).astype(np.float64)
        out = _run_closest(x, np.float32)
        assert np.all(np.isfinite(out))
        p, a, b, c = (x[:, 3 * k : 3 * k + 3] for k in range(4))
        w = out[:, :3]
        assert w.min() >= 0.0 and np.allclose(w.sum(1), 1.0, atol=1e-6)
        d = np.linalg.norm(p - (w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c), axis=1)
        wn = point_triangle_closest_np(p, a, b, c)
        dn = np.linalg.norm(p - (wn[:, :1] * a + wn[:, 1:2] * b + wn[:, 2:] * c), axis=1)
        assert np.all(np.abs(d - dn) <= 1e-5 * 10.0)
        s, t = out[:, 4:5], out[:, 5:6]
        ds = np.linalg.norm(p + s * (a - p) - b - t * (c - b), axis=1)
        sn, tn = segment_segment_closest_np(p, a, b, c)
        dsn = np.linalg.norm(p + sn[:, None] * (a - p) - b - tn[:, None] * (c - b), axis=1)
        assert np.all(np.abs(ds - dsn) <= 1e-5 * 10.0)
