"""Bounding volumes as `@ti.func`s on 3-vectors: axis-aligned boxes (AABBs) and bounding spheres of points,
edges, triangles and swept primitives, with their overlap tests and the ray–box slab test.

A box is a pair (lo, hi) of 3-vectors and is closed: boxes that touch overlap. `pad` [m] grows a box on
every side (a contact thickness). A swept box encloses a primitive's start and end positions; with linear
vertex motion it encloses the primitive at every time in between, which is what continuous tests need.

Ray–box: the slab method of Kay & Kajiya, "Ray tracing complex scenes" (SIGGRAPH '86), as written by
Williams et al., "An efficient and robust ray-box intersection algorithm" (JGT 10(1), 2005), taking the
precomputed inverse direction. A component with |inv_d| > `INV_DIR_PARALLEL` (1/0 = inf included) counts
as parallel to its slabs: the ray is then inside those slabs either always or never, a comparison of the
origin with the slab, so no 0 * inf = NaN arises when the origin lies on a slab plane.

Minimal enclosing sphere of a triangle: the circumsphere if the triangle is acute, else the sphere on its
longest edge (Ericson, Real-Time Collision Detection, 2005, sec. 4.3). Both candidates are computed, each
with its radius taken as the largest distance to the three vertices, and the smaller one is kept: so the
sphere always encloses the triangle, needs no acute/obtuse test that round-off could flip, and a zero-area
triangle (whose circumcentre is skipped) gets the sphere of its longest edge without NaN.

NumPy (float64) references, vectorised over rows, are the `*_np` functions; the tests use them.
"""

import numpy as np
import taichi as ti
from taichi.lang import impl

# |inv_d| above this counts as a zero direction component (see the module docstring).
INV_DIR_PARALLEL = 1e30


@ti.func
def fp_epsilon():
    """Machine epsilon of the default float type (2^-52 for f64, 2^-23 for f32), for relative tolerances."""
    return ti.static(2.0**-52 if impl.get_runtime().default_fp == ti.f64 else 2.0**-23)


@ti.func
def aabb_point(x, pad):
    """Box of point x grown by pad [m]: (lo, hi)."""
    return x - pad, x + pad


@ti.func
def aabb_edge(a, b, pad):
    """Box of segment ab grown by pad [m]: (lo, hi)."""
    return ti.min(a, b) - pad, ti.max(a, b) + pad


@ti.func
def aabb_triangle(a, b, c, pad):
    """Box of triangle abc grown by pad [m]: (lo, hi)."""
    return ti.min(a, b, c) - pad, ti.max(a, b, c) + pad


@ti.func
def aabb_swept_point(x0, x1, pad):
    """Box of a point moving linearly from x0 to x1, grown by pad [m]: (lo, hi)."""
    return aabb_edge(x0, x1, pad)


@ti.func
def aabb_swept_edge(a0, b0, a1, b1, pad):
    """Box of edge (a, b) over a step from (a0, b0) to (a1, b1), grown by pad [m]: (lo, hi)."""
    return ti.min(a0, b0, a1, b1) - pad, ti.max(a0, b0, a1, b1) + pad


@ti.func
def aabb_swept_triangle(a0, b0, c0, a1, b1, c1, pad):
    """Box of triangle (a, b, c) over a step from (a0, b0, c0) to (a1, b1, c1), grown by pad [m]."""
    return ti.min(a0, b0, c0, a1, b1, c1) - pad, ti.max(a0, b0, c0, a1, b1, c1) + pad


@ti.func
def aabb_merge(lo0, hi0, lo1, hi1):
    """Smallest box holding both boxes: (lo, hi)."""
    return ti.min(lo0, lo1), ti.max(hi0, hi1)


@ti.func
def aabb_overlap(lo0, hi0, lo1, hi1):
    """Whether two closed boxes share a point (touching counts)."""
    return (lo0 <= hi1).all() and (lo1 <= hi0).all()


@ti.func
def aabb_contains(lo, hi, x):
    """Whether point x lies in the closed box."""
    return (lo <= x).all() and (x <= hi).all()


@ti.func
def aabb_point_distance_sq(lo, hi, x):
    """Squared distance [m^2] from point x to the closed box (0 inside), a lower bound for nearest queries."""
    d = ti.max(lo - x, 0.0) + ti.max(x - hi, 0.0)
    return d.dot(d)


@ti.func
def aabb_sphere_overlap(lo, hi, c, r):
    """Whether the closed box and the closed ball of centre c, radius r [m] share a point."""
    return aabb_point_distance_sq(lo, hi, c) <= r * r


@ti.func
def aabb_surface_area(lo, hi):
    """Surface area [m^2] of the box (0 for an empty box with hi < lo), the cost measure of SAH builds."""
    e = ti.max(hi - lo, 0.0)
    return 2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])


@ti.func
def aabb_ray(lo, hi, o, inv_d, t_max):
    """Slab test of the ray o + t d, 0 <= t <= t_max, against the closed box; inv_d = 1 / d per component
    (±inf allowed). Returns (hit, t_enter): t_enter is the first t in [0, t_max] inside the box (0 if the
    origin is inside)."""
    t0 = 0.0 * t_max
    t1 = t_max
    hit = True
    for k in ti.static(range(3)):
        if ti.abs(inv_d[k]) > INV_DIR_PARALLEL:
            if o[k] < lo[k] or o[k] > hi[k]:
                hit = False
        else:
            ta = (lo[k] - o[k]) * inv_d[k]
            tb = (hi[k] - o[k]) * inv_d[k]
            t0 = ti.max(t0, ti.min(ta, tb))
            t1 = ti.min(t1, ti.max(ta, tb))
    return hit and t0 <= t1, t0


@ti.func
def sphere_edge(a, b):
    """Smallest sphere holding segment ab: (centre, radius [m])."""
    return 0.5 * (a + b), 0.5 * (b - a).norm()


@ti.func
def sphere_triangle(a, b, c):
    """Minimal sphere enclosing triangle abc: (centre, radius [m]); robust for zero-area triangles."""
    lab = (b - a).norm_sqr()
    lbc = (c - b).norm_sqr()
    lca = (a - c).norm_sqr()
    # Candidate 1: the sphere on the longest edge.
    m = 0.5 * (a + b)
    if lbc >= lab and lbc >= lca:
        m = 0.5 * (b + c)
    elif lca >= lab and lca >= lbc:
        m = 0.5 * (c + a)
    r2 = ti.max((a - m).norm_sqr(), (b - m).norm_sqr(), (c - m).norm_sqr())
    # Candidate 2: the circumsphere, skipped when the triangle is too flat for its centre to be accurate.
    u = b - a
    v = c - a
    w = u.cross(v)
    w2 = w.norm_sqr()
    if w2 > 64.0 * fp_epsilon() * lab * lca:
        cc = a + (lab * v.cross(w) + lca * w.cross(u)) / (2.0 * w2)
        rc2 = ti.max((a - cc).norm_sqr(), (b - cc).norm_sqr(), (c - cc).norm_sqr())
        if rc2 < r2:
            m = cc
            r2 = rc2
    return m, ti.sqrt(r2)


@ti.func
def sphere_overlap(c0, r0, c1, r1):
    """Whether two closed balls share a point (touching counts)."""
    return (c1 - c0).norm_sqr() <= (r0 + r1) * (r0 + r1)


# ------------------------------------------------------------------------------------- NumPy references


def aabb_ray_np(lo, hi, o, d, t_max):
    """Reference slab test on rows, from the direction d itself (zero components handled by comparison).

    lo, hi, o, d: (N, 3); t_max: scalar or (N,). Returns (hit (N,) bool, t_enter (N,))."""
    lo, hi, o, d = (np.asarray(x, dtype=np.float64) for x in (lo, hi, o, d))
    n = len(o)
    t0 = np.zeros(n)
    t1 = np.broadcast_to(np.asarray(t_max, dtype=np.float64), (n,)).copy()
    hit = np.ones(n, dtype=bool)
    for k in range(3):
        par = d[:, k] == 0.0
        hit &= ~(par & ((o[:, k] < lo[:, k]) | (o[:, k] > hi[:, k])))
        dk = np.where(par, 1.0, d[:, k])
        ta, tb = (lo[:, k] - o[:, k]) / dk, (hi[:, k] - o[:, k]) / dk
        t0 = np.where(par, t0, np.maximum(t0, np.minimum(ta, tb)))
        t1 = np.where(par, t1, np.minimum(t1, np.maximum(ta, tb)))
    return hit & (t0 <= t1), t0


def sphere_triangle_np(a, b, c):
    """Reference minimal enclosing sphere of triangles given as rows: (centres (N, 3), radii (N,)).

    Enumerates the spheres on the three edges and the circumsphere, keeping the smallest that holds all
    three vertices (the minimal ball of three points is one of these)."""
    a, b, c = (np.asarray(x, dtype=np.float64) for x in (a, b, c))
    pts = np.stack([a, b, c], axis=1)  # (N, 3, 3)
    cands = [0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)]
    u, v = b - a, c - a
    w = np.cross(u, v)
    w2 = (w * w).sum(-1)
    ok = w2 > 1e-300
    safe = np.where(ok, w2, 1.0)[:, None]
    uu, vv = (u * u).sum(-1)[:, None], (v * v).sum(-1)[:, None]
    cc = a + (uu * np.cross(v, w) + vv * np.cross(w, u)) / (2.0 * safe)
    cands.append(np.where(ok[:, None], cc, 0.5 * (a + b)))
    best_c = np.zeros_like(a)
    best_r = np.full(len(a), np.inf)
    for m in cands:
        r = np.sqrt(((pts - m[:, None, :]) ** 2).sum(-1)).max(-1)
        better = r < best_r
        best_c[better], best_r[better] = m[better], r[better]
    return best_c, best_r
