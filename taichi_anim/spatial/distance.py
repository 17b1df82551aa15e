"""Closest points as `@ti.func`s: point–segment, point–triangle (barycentric weights and the closest
feature) and segment–segment (the two parameters), robust for degenerate input.

Point–triangle: Ericson, Real-Time Collision Detection (2005), sec. 5.1.5. The closest point of a
triangle is the orthogonal projection of p when that projection falls inside (the face's Voronoi region);
otherwise it lies on the boundary, and the nearest of the three edges' closest points is taken (the
edge and vertex Voronoi regions of sec. 5.1.5, found by comparison rather than by region tests). The
projection's weights are ratios of signed areas, n . ((b - p) x (c - p)) / |n|^2 with n = (b - a) x (c - a),
accurate down to sliver angles. A triangle whose sine of angle is below 16 machine epsilons has no face
region (zero area, needle, three coincident points): the answer is then the closest point of the segment
or point it collapses to, and no division by a vanishing area happens, so no NaN.

Segment–segment: Ericson sec. 5.1.9 (the line–line parameters, clamped, then re-projected), with
b f - c e written as (d1 x d2) . (d2 x r) by Lagrange's identity: the cross product keeps the relative
error of s near eps / sin(angle) instead of eps / sin(angle)^2 for nearly parallel segments. Parallel
segments (sine below 16 epsilons) take s = 0 as the book does; a segment shorter than eps times the scene
scale counts as a point.

Weights are exact at features: on an edge the opposite weight is exactly 0, at a vertex the weights are
exactly (1, 0, 0) permuted, so `point_triangle_feature` reads the feature off them. Feature codes:
0 face; 1 edge ab, 2 edge bc, 3 edge ca; 4 vertex a, 5 vertex b, 6 vertex c.

NumPy (float64) references `*_np`, vectorised over rows, implement the same definitions for tests.
"""

import numpy as np
import taichi as ti

from .bounds import fp_epsilon

FEATURE_FACE = 0
FEATURE_EDGE_AB, FEATURE_EDGE_BC, FEATURE_EDGE_CA = 1, 2, 3
FEATURE_VERTEX_A, FEATURE_VERTEX_B, FEATURE_VERTEX_C = 4, 5, 6


@ti.func
def point_segment_closest(p, a, b):
    """Parameter t in [0, 1] of the point a + t (b - a) of segment ab closest to p (0 if a == b)."""
    ab = b - a
    l2 = ab.norm_sqr()
    t = 0.0
    if l2 > 0.0:
        t = ti.math.clamp((p - a).dot(ab) / l2, 0.0, 1.0)
    return t


@ti.func
def point_triangle_closest(p, a, b, c):
    """Barycentric weights w (3-vector, w >= 0, sum 1) of the point w0 a + w1 b + w2 c of the closed
    triangle abc closest to p; the closest point of the segment or point a degenerate triangle is."""
    ab = b - a
    ac = c - a
    n = ab.cross(ac)
    n2 = n.norm_sqr()
    w = ti.Vector([1.0, 0.0, 0.0])
    inside = False
    if n2 > (16.0 * fp_epsilon()) ** 2 * ab.norm_sqr() * ac.norm_sqr():
        wb = n.dot((p - a).cross(ac)) / n2
        wc = n.dot(ab.cross(p - a)) / n2
        if wb >= 0.0 and wc >= 0.0 and wb + wc <= 1.0:
            w = ti.Vector([1.0 - wb - wc, wb, wc])
            inside = True
    if not inside:
        # The boundary: the nearest of the three edges' closest points.
        t = point_segment_closest(p, a, b)
        best = (p - (a + t * ab)).norm_sqr()
        w = ti.Vector([1.0 - t, t, 0.0])
        t = point_segment_closest(p, b, c)
        d = (p - (b + t * (c - b))).norm_sqr()
        if d < best:
            best = d
            w = ti.Vector([0.0, 1.0 - t, t])
        t = point_segment_closest(p, c, a)
        d = (p - (c + t * (a - c))).norm_sqr()
        if d < best:
            w = ti.Vector([t, 0.0, 1.0 - t])
    return w


@ti.func
def point_triangle_feature(w):
    """Closest-feature code of the weights from `point_triangle_closest`: 0 face, 1 edge ab, 2 edge bc,
    3 edge ca, 4 vertex a, 5 vertex b, 6 vertex c (exact zeros mark the feature)."""
    code = FEATURE_FACE
    if w[0] == 1.0:
        code = FEATURE_VERTEX_A
    elif w[1] == 1.0:
        code = FEATURE_VERTEX_B
    elif w[2] == 1.0:
        code = FEATURE_VERTEX_C
    elif w[2] == 0.0:
        code = FEATURE_EDGE_AB
    elif w[0] == 0.0:
        code = FEATURE_EDGE_BC
    elif w[1] == 0.0:
        code = FEATURE_EDGE_CA
    return code


@ti.func
def point_triangle_distance_sq(p, a, b, c):
    """Squared distance [m^2] from p to the closed triangle abc."""
    w = point_triangle_closest(p, a, b, c)
    q = w[0] * a + w[1] * b + w[2] * c
    return (p - q).norm_sqr()


@ti.func
def segment_segment_closest(p0, p1, q0, q1):
    """Parameters (s, t) in [0, 1] of the closest points p0 + s (p1 - p0) and q0 + t (q1 - q0) of two
    closed segments; robust for zero-length and parallel segments (then one closest pair of many)."""
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a = d1.norm_sqr()
    e = d2.norm_sqr()
    f = d2.dot(r)
    tiny = fp_epsilon() ** 2 * (a + e + r.norm_sqr())
    s = 0.0
    t = 0.0
    if a <= tiny and e <= tiny:
        pass
    elif a <= tiny:
        t = ti.math.clamp(f / e, 0.0, 1.0)
    else:
        c = d1.dot(r)
        if e <= tiny:
            s = ti.math.clamp(-c / a, 0.0, 1.0)
        else:
            b = d1.dot(d2)
            n = d1.cross(d2)
            denom = n.norm_sqr()
            if denom > (16.0 * fp_epsilon()) ** 2 * a * e:
                s = ti.math.clamp(n.dot(d2.cross(r)) / denom, 0.0, 1.0)
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = ti.math.clamp(-c / a, 0.0, 1.0)
            elif t > 1.0:
                t = 1.0
                s = ti.math.clamp((b - c) / a, 0.0, 1.0)
    return s, t


# ------------------------------------------------------------------------------------- NumPy references


def _rows(*xs):
    return [np.asarray(x, dtype=np.float64) for x in xs]


def _dot(x, y):
    return (x * y).sum(-1)


def point_segment_closest_np(p, a, b):
    """Reference of `point_segment_closest` on rows: (N,) parameters."""
    p, a, b = _rows(p, a, b)
    ab = b - a
    l2 = _dot(ab, ab)
    return np.where(l2 > 0.0, np.clip(_dot(p - a, ab) / np.where(l2 > 0.0, l2, 1.0), 0.0, 1.0), 0.0)


def point_triangle_closest_np(p, a, b, c):
    """Reference of `point_triangle_closest` on rows: (N, 3) weights."""
    p, a, b, c = _rows(p, a, b, c)
    eps = np.finfo(np.float64).eps
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    n2 = _dot(n, n)
    face = n2 > (16.0 * eps) ** 2 * _dot(ab, ab) * _dot(ac, ac)
    safe = np.where(face, n2, 1.0)
    wb = _dot(n, np.cross(p - a, ac)) / safe
    wc = _dot(n, np.cross(ab, p - a)) / safe
    inside = face & (wb >= 0.0) & (wc >= 0.0) & (wb + wc <= 1.0)
    w = np.stack([1.0 - wb - wc, wb, wc], axis=-1)
    best = np.full(len(p), np.inf)
    wbnd = np.zeros_like(w)
    for x, y, cols in ((a, b, (0, 1)), (b, c, (1, 2)), (c, a, (2, 0))):
        t = point_segment_closest_np(p, x, y)
        d = _dot(p - x - t[:, None] * (y - x), p - x - t[:, None] * (y - x))
        better = d < best
        best = np.where(better, d, best)
        we = np.zeros_like(w)
        we[:, cols[0]], we[:, cols[1]] = 1.0 - t, t
        wbnd[better] = we[better]
    return np.where(inside[:, None], w, wbnd)


def point_triangle_distance_np(p, a, b, c):
    """Distances [m] from rows p to the triangles (a, b, c): (N,)."""
    p, a, b, c = _rows(p, a, b, c)
    w = point_triangle_closest_np(p, a, b, c)
    q = w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c
    return np.sqrt(_dot(p - q, p - q))


def point_triangle_feature_np(w):
    """Reference of `point_triangle_feature` on (N, 3) weights: (N,) codes."""
    w = np.asarray(w)
    code = np.zeros(len(w), dtype=np.int32)
    code = np.where(w[:, 1] == 0.0, FEATURE_EDGE_CA, code)
    code = np.where(w[:, 0] == 0.0, FEATURE_EDGE_BC, code)
    code = np.where(w[:, 2] == 0.0, FEATURE_EDGE_AB, code)
    for k in (2, 1, 0):
        code = np.where(w[:, k] == 1.0, FEATURE_VERTEX_A + k, code)
    return code


def segment_segment_closest_np(p0, p1, q0, q1):
    """Reference of `segment_segment_closest` on rows: (s, t), each (N,)."""
    p0, p1, q0, q1 = _rows(p0, p1, q0, q1)
    eps = np.finfo(np.float64).eps
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f, c, b = _dot(d1, d1), _dot(d2, d2), _dot(d2, r), _dot(d1, r), _dot(d1, d2)
    tiny = eps**2 * (a + e + _dot(r, r))
    pa, pe = a <= tiny, e <= tiny
    sa, se = np.where(pa, 1.0, a), np.where(pe, 1.0, e)
    n = np.cross(d1, d2)
    denom = _dot(n, n)
    par = denom <= (16.0 * eps) ** 2 * a * e
    s = np.where(par, 0.0, np.clip(_dot(n, np.cross(d2, r)) / np.where(par, 1.0, denom), 0.0, 1.0))
    t = (b * s + f) / se
    lo, hi = t < 0.0, t > 1.0
    s = np.where(lo, np.clip(-c / sa, 0.0, 1.0), np.where(hi, np.clip((b - c) / sa, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # Degenerate segments (points).
    s = np.where(pe & ~pa, np.clip(-c / sa, 0.0, 1.0), s)
    t = np.where(pe, 0.0, t)
    t = np.where(pa & ~pe, np.clip(f / se, 0.0, 1.0), t)
    s = np.where(pa, 0.0, s)
    t = np.where(pa & pe, 0.0, t)
    return s, t
