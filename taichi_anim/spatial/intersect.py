"""Exact-predicate intersection tests as `@ti.func`s: closed triangle–triangle, segment–triangle and
ray–triangle.

Triangle–triangle follows Guigue & Devillers, "Fast and robust triangle-triangle overlap test using
orientation predicates" (JGT 8(1), 2003): every decision is the sign of an orientation determinant
(orient3d, or orient2d after dropping the dominant axis of the normal for coplanar input), so the test
has no division and no epsilon, and their first step is kept: if the vertices of one triangle lie
strictly on one side of the other's plane, they do not meet. Their interval permutation table is replaced
by an equivalent criterion that needs no case analysis: two closed triangles meet iff an edge of one meets
the other (an extreme point of their intersection, a segment or a convex polygon, lies on an edge of one
of them). Segment pq meets triangle abc:
- p, q strictly on one side of its plane: no;
- p, q on the plane (coplanar): p inside the triangle, or pq crossing one of its edges (orient2d);
- otherwise iff orient3d(p, q, a, b), orient3d(p, q, b, c), orient3d(p, q, c, a) are all >= 0 or all <= 0
  (each is the signed area of a sub-triangle of the crossing point, times the same non-zero factor).
A degenerate triangle (zero area, needle, a point) is the union of its edges, so the same criterion
holds with segment–segment tests against it (coplanar, and meeting in each coordinate projection).
The six edge tests run in a loop rather than unrolled: the inlined code stays small enough to compile.

The tests are exact whenever the orientation determinants are: for integer coordinates (or dyadic
rationals on a common grid, scaled) of magnitude <= 2^15 in f64, every determinant is an integer below
2^53, computed exactly, and the answers equal exact rational arithmetic. With general floats they are as
robust as the rounded determinants.

Segment/ray–triangle: Möller & Trumbore, "Fast, minimum storage ray-triangle intersection" (JGT 2(1),
1997), with the bounds checked on the numerators before dividing by the determinant (exact decisions on
integer input, no division by a vanishing determinant). A segment or ray parallel to the triangle's plane,
lying in it, or meeting a zero-area triangle gets no hit: they have no single crossing point.
"""

import taichi as ti

NO_HIT = 2.0  # the `t` of a segment that does not cross, outside [0, 1]


@ti.func
def _orient3(a, b, c, d):
    """(b - a) x (c - a) . (d - a): > 0 if d is on the side of plane abc that its normal points to."""
    return (b - a).cross(c - a).dot(d - a)


@ti.func
def _orient2(a, b, c):
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


@ti.func
def _same_strict_sign(x, y):
    # Compares signs instead of multiplying: the product of two exact determinants may not be exact.
    return (x > 0.0 and y > 0.0) or (x < 0.0 and y < 0.0)


@ti.func
def _mixed_signs(x, y, z):
    return (x < 0.0 or y < 0.0 or z < 0.0) and (x > 0.0 or y > 0.0 or z > 0.0)


@ti.func
def _pick(j, x0, x1, x2):
    """x_j for a run-time index j in {0, 1, 2}."""
    r = x0
    if j == 1:
        r = x1
    elif j == 2:
        r = x2
    return r


@ti.func
def _drop(v, k):
    """v projected on the coordinate plane normal to axis k (cyclic order: orient2d has the sign of n_k)."""
    r = ti.Vector([v[0], v[1]])
    if k == 0:
        r = ti.Vector([v[1], v[2]])
    elif k == 1:
        r = ti.Vector([v[2], v[0]])
    return r


@ti.func
def _dominant_axis(n):
    m = ti.abs(n)
    k = 2
    if m[0] >= m[1] and m[0] >= m[2]:
        k = 0
    elif m[1] >= m[2]:
        k = 1
    return k


@ti.func
def _segments_meet_2d(p, q, a, b):
    """Closed 2-D segments pq and ab share a point."""
    o1 = _orient2(p, q, a)
    o2 = _orient2(p, q, b)
    o3 = _orient2(a, b, p)
    o4 = _orient2(a, b, q)
    hit = True
    if _same_strict_sign(o1, o2) or _same_strict_sign(o3, o4):
        hit = False
    elif o1 == 0.0 and o2 == 0.0 and o3 == 0.0 and o4 == 0.0:
        # Collinear (or points): they meet iff their bounding boxes do.
        lo = ti.max(ti.min(p, q), ti.min(a, b))
        hi = ti.min(ti.max(p, q), ti.max(a, b))
        hit = lo[0] <= hi[0] and lo[1] <= hi[1]
    return hit


@ti.func
def _segments_meet_3d(p, q, r, s):
    """Closed 3-D segments meet: coplanar, and meeting in all three coordinate projections (one of them
    is one-to-one on their common plane or line)."""
    hit = _orient3(p, q, r, s) == 0.0
    for k in range(3):
        if hit:
            hit = _segments_meet_2d(_drop(p, k), _drop(q, k), _drop(r, k), _drop(s, k))
    return hit


@ti.func
def _segment_meets_triangle(p, q, op, oq, a, b, c, n):
    """Closed segment pq meets closed triangle abc of normal n = (b - a) x (c - a); op, oq: n . (p - a),
    n . (q - a). A zero n means a degenerate triangle, tested as its three edges."""
    hit = False
    if (n == 0.0).all():
        for e in range(3):
            if not hit:
                hit = _segments_meet_3d(p, q, _pick(e, a, b, c), _pick(e, b, c, a))
    elif _same_strict_sign(op, oq):
        hit = False
    elif op == 0.0 and oq == 0.0:
        # In the plane: p inside, or pq crossing an edge (pq inside the triangle has p inside).
        k = _dominant_axis(n)
        p2, q2 = _drop(p, k), _drop(q, k)
        a2, b2, c2 = _drop(a, k), _drop(b, k), _drop(c, k)
        hit = not _mixed_signs(_orient2(a2, b2, p2), _orient2(b2, c2, p2), _orient2(c2, a2, p2))
        for e in range(3):
            if not hit:
                hit = _segments_meet_2d(p2, q2, _pick(e, a2, b2, c2), _pick(e, b2, c2, a2))
    else:
        hit = not _mixed_signs(_orient3(p, q, a, b), _orient3(p, q, b, c), _orient3(p, q, c, a))
    return hit


@ti.func
def triangle_triangle_intersect(p0, p1, p2, q0, q1, q2):
    """Whether closed triangles (p0, p1, p2) and (q0, q1, q2) share a point (touching and coplanar overlap
    count; degenerate triangles are the segments or points they collapse to)."""
    n1 = (p1 - p0).cross(p2 - p0)
    n2 = (q1 - q0).cross(q2 - q0)
    # Orientations of each triangle's vertices with respect to the other's plane.
    d = ti.Vector([n2.dot(p0 - q0), n2.dot(p1 - q0), n2.dot(p2 - q0)])
    f = ti.Vector([n1.dot(q0 - p0), n1.dot(q1 - p0), n1.dot(q2 - p0)])
    hit = True
    if (d > 0.0).all() or (d < 0.0).all() or (f > 0.0).all() or (f < 0.0).all():
        hit = False
    else:
        hit = False
        for j in range(6):
            if not hit:
                # Edge (i, i + 1) of one triangle against the other: j < 3 edges of p, j >= 3 edges of q.
                i = j % 3
                i1 = (i + 1) % 3
                first = j < 3
                x = ti.select(first, _pick(i, p0, p1, p2), _pick(i, q0, q1, q2))
                y = ti.select(first, _pick(i1, p0, p1, p2), _pick(i1, q0, q1, q2))
                ox = ti.select(first, d[i], f[i])
                oy = ti.select(first, d[i1], f[i1])
                a = ti.select(first, q0, p0)
                b = ti.select(first, q1, p1)
                c = ti.select(first, q2, p2)
                n = ti.select(first, n2, n1)
                hit = _segment_meets_triangle(x, y, ox, oy, a, b, c, n)
    return hit


@ti.func
def _moller_trumbore(o, d, a, b, c, t_max):
    """(hit, t, u, v) of o + t d, 0 <= t <= t_max, with the closed triangle; point (1-u-v) a + u b + v c."""
    e1 = b - a
    e2 = c - a
    pv = d.cross(e2)
    det = e1.dot(pv)
    hit = False
    t = 0.0
    u = 0.0
    v = 0.0
    if det != 0.0:
        s = o - a
        qv = s.cross(e1)
        un = s.dot(pv)
        vn = d.dot(qv)
        tn = e2.dot(qv)
        if det < 0.0:
            # Flip all signs so the bounds read the same for both windings.
            det = -det
            un = -un
            vn = -vn
            tn = -tn
        if un >= 0.0 and vn >= 0.0 and un + vn <= det and tn >= 0.0 and tn <= t_max * det:
            hit = True
            t = tn / det
            u = un / det
            v = vn / det
    return hit, t, u, v


@ti.func
def segment_triangle(o, e, a, b, c):
    """Crossing of segment o -> e with closed triangle abc: (t, u, v), point o + t (e - o) =
    (1 - u - v) a + u b + v c with t in [0, 1]; t = NO_HIT (2.0) if it does not cross (parallel, in the
    plane, or a zero-area triangle)."""
    hit, t, u, v = _moller_trumbore(o, e - o, a, b, c, 1.0)
    if not hit:
        t = NO_HIT
    return t, u, v


@ti.func
def ray_triangle(o, d, a, b, c, t_max):
    """Ray o + t d, 0 <= t <= t_max, against closed triangle abc: (hit, t, u, v), point
    (1 - u - v) a + u b + v c; no hit for a ray parallel to the plane or a zero-area triangle."""
    return _moller_trumbore(o, d, a, b, c, t_max)
