"""The distance between two convex bodies' cores: Gilbert, Johnson & Keerthi, "A fast procedure for
computing the distance between complex objects in three-dimensional space" (IEEE J. Robotics and
Automation 4(2), 1988), with the closest point on each simplex found by Voronoi regions (Ericson,
"Real-Time Collision Detection", 2005, sec. 5.1.2, 5.1.5 and 9.5) instead of Johnson's subalgorithm.

A body's core is what rigid contacts hold of its shape (geometry.py): a polytope's vertices (a box in
closed form), a round shape's core segment (its end points), whose radius the caller adds. A point can
stand for a body (index < 0): the distance from a point to a polytope is then exact also beyond a face's
edge, where the polytope's plane distance is only a lower bound."""

import taichi as ti

GJK_ITERATIONS = 32
# GJK stops when a support step no longer brings the simplex closer to the origin than this fraction of
# the squared distance (Gilbert et al.'s stopping rule, sec. V): the distance is then within about half
# of it, relatively.
GJK_TOLERANCE = 1e-9


@ti.func
def core_support(model: ti.template(), i, x, r, u):
    """The point of geom i's core (its frame at x, rotation r) farthest along u; for i < 0, the point x."""
    best_p = x
    if i >= 0:
        if model.geom_box[i]:
            local = r.transpose() @ u
            corner = ti.Vector([1.0 if local[k] >= 0.0 else -1.0 for k in ti.static(range(3))])
            best_p = x + r @ (corner * model.geom_half[i])
        else:
            best = -1e30
            for k in range(model.geom_point_start[i], model.geom_point_start[i + 1]):
                p = x + r @ model.geom_points[k]
                if u.dot(p) > best:
                    best, best_p = u.dot(p), p
    return best_p


@ti.func
def _row(m, k):
    """Row k (chosen at run time) of a 4x3 matrix."""
    return ti.Vector([m[k, 0], m[k, 1], m[k, 2]])


@ti.func
def _set_row(m: ti.template(), k, value):
    for c in ti.static(range(3)):
        m[k, c] = value[c]


@ti.func
def _segment_weights(p0, p1):
    """Barycentric weights of the point of segment p0 p1 closest to the origin."""
    d = p1 - p0
    t = ti.min(ti.max(-p0.dot(d) / ti.max(d.norm_sqr(), 1e-300), 0.0), 1.0)
    return ti.Vector([1.0 - t, t])


@ti.func
def _triangle_weights(p0, p1, p2):
    """Barycentric weights of the point of triangle p0 p1 p2 closest to the origin (Ericson 5.1.5)."""
    ab, ac = p1 - p0, p2 - p0
    d1, d2 = -ab.dot(p0), -ac.dot(p0)
    d3, d4 = -ab.dot(p1), -ac.dot(p1)
    d5, d6 = -ab.dot(p2), -ac.dot(p2)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    weights = ti.Vector([1.0, 0.0, 0.0])
    if d1 <= 0.0 and d2 <= 0.0:
        weights = ti.Vector([1.0, 0.0, 0.0])
    elif d3 >= 0.0 and d4 <= d3:
        weights = ti.Vector([0.0, 1.0, 0.0])
    elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        s = d1 / (d1 - d3)
        weights = ti.Vector([1.0 - s, s, 0.0])
    elif d6 >= 0.0 and d5 <= d6:
        weights = ti.Vector([0.0, 0.0, 1.0])
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        s = d2 / (d2 - d6)
        weights = ti.Vector([1.0 - s, 0.0, s])
    elif va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        s = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        weights = ti.Vector([0.0, 1.0 - s, s])
    else:
        total = va + vb + vc
        weights = ti.Vector([va, vb, vc]) / total
    return weights


@ti.func
def _simplex_weights(w, n):
    """(weights (4,) of the point of the simplex w[0..n) closest to the origin, whether the origin is
    inside the tetrahedron when n == 4). A triangle is the tetrahedron's one face case: the triangle's
    closest point is written once in the kernel (a copy per face made the detection compile seconds
    longer)."""
    weights = ti.Vector.zero(float, 4)
    inside = False
    if n == 1:
        weights[0] = 1.0
    elif n == 2:
        s = _segment_weights(_row(w, 0), _row(w, 1))
        weights[0], weights[1] = s[0], s[1]
    else:
        inside = n == 4
        best = ti.cast(1e300, float)
        for f in range(1 if n == 3 else 4):
            out = 3 if n == 3 else f  # the slot left out: this face's opposite corner
            i = 1 if out == 0 else 0
            j = 2 if out <= 1 else 1
            k = 3 if out <= 2 else 2
            pi, pj, pk, pm = _row(w, i), _row(w, j), _row(w, k), _row(w, out)
            normal = (pj - pi).cross(pk - pi)
            # a triangle, or the origin beyond this face seen from the opposite corner (a flat
            # tetrahedron: every face)
            if n == 3 or normal.dot(-pi) * normal.dot(pm - pi) <= 0.0:
                inside = False
                s = _triangle_weights(pi, pj, pk)
                closest = s[0] * pi + s[1] * pj + s[2] * pk
                if closest.norm_sqr() < best:
                    best = closest.norm_sqr()
                    weights = ti.Vector.zero(float, 4)
                    weights[i], weights[j], weights[k] = s[0], s[1], s[2]
    return weights, inside


@ti.func
def gjk(model: ti.template(), a, xa, ra, b, xb, rb):
    """(distance [m] between the cores of geoms a and b (0 where they meet), the closest point on a's
    core, the closest point on b's). a < 0: the point xa stands for geom a."""
    sa_ = ti.Matrix.zero(float, 4, 3)  # the simplex's points as support points of a and of b
    sb_ = ti.Matrix.zero(float, 4, 3)
    weights = ti.Vector([1.0, 0.0, 0.0, 0.0])
    n = 0
    v = xa - xb
    if v.norm_sqr() == 0.0:
        v = ti.Vector([1.0, 0.0, 0.0])
    met = False
    # Pass 0 takes the first pair of support points, the others GJK's iterations: one copy of the
    # support in the kernel (core_support, twice a pass) instead of two, the same operations in order.
    for it in range(GJK_ITERATIONS + 1):
        vv = v.norm_sqr()
        if it > 0 and vv <= 1e-24:
            met = True
            break
        pa = core_support(model, a, xa, ra, -v)
        pb = core_support(model, b, xb, rb, v)
        if it == 0:
            _set_row(sa_, 0, pa)
            _set_row(sb_, 0, pb)
            n = 1
            v = pa - pb
            continue
        if vv - v.dot(pa - pb) <= GJK_TOLERANCE * vv:
            break  # no support point comes closer: v is the closest point of a - b
        _set_row(sa_, n, pa)
        _set_row(sb_, n, pb)
        n += 1
        w = sa_ - sb_
        new_weights, inside = _simplex_weights(w, n)
        if inside:
            met = True
            break
        new_v = ti.Vector.zero(float, 3)
        for k in range(n):
            new_v += new_weights[k] * _row(w, k)
        if new_v.norm_sqr() >= vv:
            n -= 1  # round-off: the new point did not help; keep the last simplex
            break
        # keep the points with weight: the smallest simplex holding the closest point
        kept = 0
        for k in range(n):
            if new_weights[k] > 0.0:
                _set_row(sa_, kept, _row(sa_, k))
                _set_row(sb_, kept, _row(sb_, k))
                weights[kept] = new_weights[k]
                kept += 1
        n = kept
        v = new_v
    closest_a = ti.Vector.zero(float, 3)
    closest_b = ti.Vector.zero(float, 3)
    total = 0.0
    for k in range(n):
        closest_a += weights[k] * _row(sa_, k)
        closest_b += weights[k] * _row(sb_, k)
        total += weights[k]
    closest_a /= total
    closest_b /= total
    dist = 0.0 if met else (closest_a - closest_b).norm()
    return dist, closest_a, closest_b
