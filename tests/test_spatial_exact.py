"""Triangle–triangle and segment/ray–triangle tests (taichi_anim.spatial) against an exact reference in
Python integers and `fractions.Fraction`. The kernels run in f64 on small-integer coordinates
(|x| <= 2^15, or dyadic rationals scaled to them): every orientation determinant is then an integer below
2^53, computed exactly in floating point, so the kernel's answer must EQUAL the exact one, touching cases
included."""

from fractions import Fraction

import numpy as np
import taichi as ti

from taichi_anim.spatial import ray_triangle, segment_triangle, triangle_triangle_intersect

from .helpers import row_vec3 as _v


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _idot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


ZERO = (0, 0, 0)


def _ref_segments_meet(p, q, r, s):
    """Closed segments pq, rs share a point: solve p + u (q - p) = r + v (s - r) exactly."""
    d1, d2, w = _sub(q, p), _sub(s, r), _sub(r, p)
    n = _cross(d1, d2)
    if n != ZERO:
        if _idot(n, w) != 0:
            return False  # skew lines
        nn = _idot(n, n)
        u, v = Fraction(_idot(_cross(w, d2), n), nn), Fraction(_idot(_cross(w, d1), n), nn)
        return 0 <= u <= 1 and 0 <= v <= 1
    if d1 == ZERO and d2 == ZERO:
        return p == r
    if d1 == ZERO:
        return _cross(_sub(p, r), d2) == ZERO and 0 <= _idot(_sub(p, r), d2) <= _idot(d2, d2)
    if d2 == ZERO:
        return _cross(w, d1) == ZERO and 0 <= _idot(w, d1) <= _idot(d1, d1)
    if _cross(w, d1) != ZERO:
        return False  # parallel, not collinear
    lo, hi = sorted((_idot(w, d1), _idot(_sub(s, p), d1)))
    return lo <= _idot(d1, d1) and hi >= 0


def _ref_in_triangle(x, a, b, c, n):
    """Point x (Fractions) in the plane of triangle abc (normal n != 0) lies in the closed triangle."""
    return all(_idot(_cross(_sub(v, x), _sub(w, x)), n) >= 0 for v, w in ((a, b), (b, c), (c, a)))


def _ref_segment_triangle(p, q, a, b, c):
    n = _cross(_sub(b, a), _sub(c, a))
    edges = ((a, b), (b, c), (c, a))
    if n == ZERO:  # a zero-area triangle is the union of its edges
        return any(_ref_segments_meet(p, q, x, y) for x, y in edges)
    op, oq = _idot(n, _sub(p, a)), _idot(n, _sub(q, a))
    if op == 0 and oq == 0:
        return (
            _ref_in_triangle(p, a, b, c, n)
            or _ref_in_triangle(q, a, b, c, n)
            or any(_ref_segments_meet(p, q, x, y) for x, y in edges)
        )
    if (op > 0 and oq > 0) or (op < 0 and oq < 0):
        return False
    t = Fraction(op, op - oq)
    x = tuple(p[k] + t * (q[k] - p[k]) for k in range(3))
    return _ref_in_triangle(x, a, b, c, n)


def _ref_triangles_meet(t1, t2):
    """Two closed triangles meet iff an edge of one meets the other (an extreme point of their
    intersection lies on an edge of one of them)."""
    e1 = [(t1[i], t1[(i + 1) % 3]) for i in range(3)]
    e2 = [(t2[i], t2[(i + 1) % 3]) for i in range(3)]
    return any(_ref_segment_triangle(p, q, *t2) for p, q in e1) or any(
        _ref_segment_triangle(p, q, *t1) for p, q in e2
    )


def _ref_separating_axis(t1, t2):
    """Independent check for triangles of non-zero area: disjoint iff some axis among the normals, the
    edge-pair cross products and the in-plane edge normals separates their exact integer projections."""
    n1, n2 = _cross(_sub(t1[1], t1[0]), _sub(t1[2], t1[0])), _cross(_sub(t2[1], t2[0]), _sub(t2[2], t2[0]))
    e1 = [_sub(t1[(i + 1) % 3], t1[i]) for i in range(3)]
    e2 = [_sub(t2[(i + 1) % 3], t2[i]) for i in range(3)]
    axes = [n1, n2] + [_cross(e, f) for e in e1 for f in e2] + [_cross(n1, e) for e in e1 + e2]
    for ax in axes:
        a = [_idot(ax, v) for v in t1]
        b = [_idot(ax, v) for v in t2]
        if max(a) < min(b) or max(b) < min(a):
            return False
    return True


def _tuple_tris(x):
    """(N, 6, 3) integer array -> list of pairs of triangles as tuples of int tuples."""
    return [
        (tuple(tuple(int(c) for c in v) for v in row[:3]), tuple(tuple(int(c) for c in v) for v in row[3:]))
        for row in x
    ]


@ti.kernel
def _tri_tri(x: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=1)):
    for i in range(x.shape[0]):
        out[i] = triangle_triangle_intersect(
            _v(x, i, 0), _v(x, i, 1), _v(x, i, 2), _v(x, i, 3), _v(x, i, 4), _v(x, i, 5)
        )


def _kernel_tri_tri(x_int, scale=1.0):
    x = (np.asarray(x_int, dtype=np.float64) * scale).reshape(len(x_int), 18)
    out = np.zeros(len(x))
    _tri_tri(np.ascontiguousarray(x), out)
    return out.astype(bool)


def _adversarial_pairs(rng, n):
    """Integer pairs built to touch, share features, be coplanar, or degenerate."""
    base = rng.integers(-6, 7, size=(n, 3, 3)) * 6  # multiples of 6: centroids and midpoints are integers
    out = []
    for i in range(n):
        p = base[i]
        q = rng.integers(-36, 37, size=(3, 3))
        u, v = p[1] - p[0], p[2] - p[0]
        kind = i % 12
        if kind == 0:  # shared vertex
            q[0] = p[0]
        elif kind == 1:  # shared edge
            q[0], q[1] = p[0], p[1]
        elif kind == 2:  # a vertex touching the face at its centroid, the rest on one side
            nrm = np.cross(u, v)
            q[0] = p.sum(0) // 3
            q[1], q[2] = q[0] + nrm + q[1] % 2, q[0] + 2 * nrm - q[2] % 2
        elif kind == 3:  # a vertex on an edge midpoint
            q[0] = (p[0] + p[1]) // 2
        elif kind in (4, 5):  # coplanar: integer combinations of the first triangle's edges
            coef = rng.integers(-2, 3, size=(3, 2))
            q = p[0] + coef[:, :1] * u // 2 + coef[:, 1:] * v // 2
        elif kind == 6:  # coplanar and far: disjoint or touching at most
            coef = rng.integers(-1, 3, size=(3, 2))
            q = p[0] + (coef[:, :1] + 1) * u + coef[:, 1:] * v
        elif kind == 7:  # zero area: collinear
            q[2] = q[0] + 2 * (q[1] - q[0])
        elif kind == 8:  # needle: an edge one unit long
            q[1] = q[0] + np.array([1, 0, 0])
        elif kind == 9:  # a point (three coincident vertices), sometimes on the first triangle
            q[:] = p.sum(0) // 3 if rng.random() < 0.5 else q[0]
        elif kind == 10:  # both degenerate: collinear segments, or segments crossing at a midpoint
            p = p.copy()
            h = (p[1] - p[0]) // 2
            p[2] = p[0] + h
            if rng.random() < 0.5:
                q = p[0] + rng.integers(-3, 5, size=(3, 1)) * h
            else:
                q[0], q[1] = p[2] - q[2] % 7, p[2] + q[2] % 7
            q[2] = q[1]
        else:  # an edge crossing another edge at its midpoint, the third vertex off the plane
            mid = (p[0] + p[1]) // 2
            q[0], q[1] = mid - (q[2] % 5) * 2 - 1, mid + (q[2] % 5) * 2 + 1
        out.append(np.concatenate([p, q]) - rng.integers(0, 40))  # negative coordinates
    return np.array(out)


def test_triangle_triangle_equals_exact_reference_on_random_pairs():
    rng = np.random.default_rng(9)
    x = np.concatenate(
        [
            rng.integers(-4, 5, size=(1500, 6, 3)),  # small grid: many touching and coplanar pairs
            rng.integers(-64, 65, size=(800, 6, 3)),
            rng.integers(-(2**14), 2**14, size=(300, 6, 3)),  # the largest exact range
        ]
    )
    ref = np.array([_ref_triangles_meet(t1, t2) for t1, t2 in _tuple_tris(x)])
    assert 0.2 < ref.mean() < 0.8
    np.testing.assert_array_equal(_kernel_tri_tri(x), ref)
    # Dyadic coordinates (k / 64) are exact too: same answers.
    np.testing.assert_array_equal(_kernel_tri_tri(x[:1500], 1.0 / 64.0), ref[:1500])
    # The separating-axis reference agrees wherever both triangles have non-zero area.
    tris = _tuple_tris(x)
    nondeg = [
        i
        for i, (t1, t2) in enumerate(tris)
        if _cross(_sub(t1[1], t1[0]), _sub(t1[2], t1[0])) != ZERO
        and _cross(_sub(t2[1], t2[0]), _sub(t2[2], t2[0])) != ZERO
    ]
    assert all(_ref_separating_axis(*tris[i]) == ref[i] for i in nondeg)


def test_triangle_triangle_equals_exact_reference_on_adversarial_pairs():
    rng = np.random.default_rng(10)
    x = _adversarial_pairs(rng, 2400)
    ref = np.array([_ref_triangles_meet(t1, t2) for t1, t2 in _tuple_tris(x)])
    got = _kernel_tri_tri(x)
    np.testing.assert_array_equal(got, ref)
    kinds = np.arange(len(x)) % 12
    for k in (0, 1, 2, 3):
        assert ref[kinds == k].all(), k  # shared or touching features always meet
    for k in (4, 5, 6, 7, 8, 9, 10, 11):
        assert 0 < ref[kinds == k].sum(), k
    # Named cases with known answers.
    named = [
        # (T1, T2, meets)
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[4, 0, 0], [8, 0, 0], [4, 4, 0]], True),  # coplanar, one vertex
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[5, 0, 0], [8, 0, 0], [5, 4, 0]], False),  # coplanar, apart
        (
            [[0, 0, 0], [4, 0, 0], [0, 4, 0]],
            [[2, 2, 0], [6, 2, 0], [2, 6, 0]],
            True,
        ),  # coplanar, on edge
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[1, 1, 0], [2, 1, 0], [1, 2, 0]], True),  # coplanar, contained
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[1, 1, 0], [1, 1, 3], [1, 2, 3]], True),  # vertex on the face
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[1, 1, 1], [1, 1, 3], [1, 2, 3]], False),  # above
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[2, -1, 0], [2, -1, 2], [2, 1, -2]], True),  # edge through edge
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[3, 3, -1], [3, 3, 1], [5, 5, 0]], False),  # beyond hypotenuse
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[2, 2, -1], [2, 2, 1], [5, 5, 0]], True),  # pierces hypotenuse
        ([[0, 0, 0], [4, 0, 0], [8, 0, 0]], [[2, 0, 0], [2, 0, 0], [2, 0, 0]], True),  # point on a segment
        ([[0, 0, 0], [4, 0, 0], [8, 0, 0]], [[9, 0, 0], [12, 0, 0], [10, 0, 0]], False),  # collinear apart
        ([[0, 0, 0], [4, 0, 0], [8, 0, 0]], [[8, 0, 0], [12, 0, 0], [10, 0, 0]], True),  # collinear, touching
        ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[-1, -1, 0], [-1, -1, 0], [-1, -1, 0]], False),  # point outside
    ]
    xn = np.array([np.concatenate([t1, t2]) for t1, t2, _ in named]) - 7
    want = np.array([m for *_, m in named])
    np.testing.assert_array_equal([_ref_triangles_meet(t1, t2) for t1, t2 in _tuple_tris(xn)], want)
    np.testing.assert_array_equal(_kernel_tri_tri(xn), want)
    np.testing.assert_array_equal(_kernel_tri_tri(xn[:, [3, 4, 5, 0, 1, 2]]), want)  # symmetric


@ti.kernel
def _seg_tri(x: ti.types.ndarray(ndim=2), t_max: float, out: ti.types.ndarray(ndim=2)):
    # x rows: o e a b c (segment o -> e; ray o + t (e - o) up to t_max).
    for i in range(x.shape[0]):
        o, e, a, b, c = _v(x, i, 0), _v(x, i, 1), _v(x, i, 2), _v(x, i, 3), _v(x, i, 4)
        t, u, v = segment_triangle(o, e, a, b, c)
        out[i, 0] = t
        out[i, 1] = u
        out[i, 2] = v
        hit, tr, ur, vr = ray_triangle(o, e - o, a, b, c, t_max)
        out[i, 3] = hit
        out[i, 4] = tr
        out[i, 5] = ur
        out[i, 6] = vr


def _ref_crossing(o, e, a, b, c):
    """Exact crossing (t, u, v) of segment oe with the closed triangle, or None (also when parallel)."""
    n = _cross(_sub(b, a), _sub(c, a))
    d = _sub(e, o)
    dn = _idot(d, n)
    if dn == 0:
        return None
    t = Fraction(_idot(_sub(a, o), n), dn)
    if not 0 <= t <= 1:
        return None
    x = tuple(o[k] + t * d[k] for k in range(3))
    nn = _idot(n, n)
    u = Fraction(_idot(_cross(_sub(c, x), _sub(a, x)), n), nn)
    v = Fraction(_idot(_cross(_sub(a, x), _sub(b, x)), n), nn)
    if u < 0 or v < 0 or u + v > 1:
        return None
    return t, u, v


def test_segment_and_ray_triangle_equal_exact_reference():
    rng = np.random.default_rng(11)
    n = 3000
    x = rng.integers(-6, 7, size=(n, 5, 3))
    x[: n // 6, 4] = x[: n // 6, 2] + 2 * (x[: n // 6, 3] - x[: n // 6, 2])  # zero-area triangles
    k = n // 6
    # Segments ending exactly on the triangle (vertex, edge midpoint) and lying in its plane.
    x[k : 2 * k, 2:] *= 2
    x[k : 2 * k, 1] = (x[k : 2 * k, 2] + x[k : 2 * k, 3]) // 2
    x[2 * k : 3 * k, 1] = x[2 * k : 3 * k, 2]
    sl = slice(3 * k, 4 * k)
    coef = rng.integers(-1, 3, size=(k, 2, 2, 1))
    x[sl, :2] = (
        x[sl, 2:3] + coef[:, :, 0] * (x[sl, 3:4] - x[sl, 2:3]) + coef[:, :, 1] * (x[sl, 4:5] - x[sl, 2:3])
    )
    x = x - 3
    t_max = 3.0
    out = np.zeros((n, 7))
    _seg_tri(np.ascontiguousarray(x.reshape(n, 15).astype(float)), t_max, out)
    rows = [tuple(tuple(int(c) for c in v) for v in r) for r in x]
    hits = 0
    for i, (o, e, a, b, c) in enumerate(rows):
        ref = _ref_crossing(o, e, a, b, c)
        if ref is None:
            assert out[i, 0] == 2.0, i
        else:
            hits += 1
            np.testing.assert_allclose(out[i, :3], [float(f) for f in ref], rtol=0, atol=1e-14)
        far = tuple(o[k] + 3 * (e[k] - o[k]) for k in range(3))
        ref_ray = _ref_crossing(o, far, a, b, c)
        assert bool(out[i, 3]) == (ref_ray is not None), i
        if ref_ray is not None:
            np.testing.assert_allclose(
                out[i, 4:7], [3 * float(ref_ray[0]), *map(float, ref_ray[1:])], atol=1e-14
            )
    assert 0.1 * n < hits < 0.9 * n
