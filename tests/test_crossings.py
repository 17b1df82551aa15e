"""Mesh crossing checks against exact brute force over all pairs.

Triangle–triangle reference: closed triangles A and B meet iff the origin lies in the convex hull of the
nine differences a_i - b_j (the Minkowski difference A - B), and by Carathéodory's theorem iff it lies in
one of the non-degenerate simplices (point, segment, triangle, tetrahedron) spanned by at most four of
them; each membership test is a sign test in exact rational arithmetic (fractions.Fraction). This shares
nothing with the implementation's edge-against-triangle orientation tests.

Distance reference: the squared distance between a point and a triangle, or two segments, is a convex
quadratic minimised in the relative interior of some face of the pair (vertex, edge, triangle); on that face
it is the unconstrained minimum of the affine hull (a 1x1 or 2x2 Gram system), so the exact minimum is the
smallest feasible such candidate, computed in Fractions.
"""

import itertools
from fractions import Fraction

import numpy as np
import pytest

from taichi_anim import ParameterError
from taichi_anim.spatial.crossings import (
    intersecting_triangle_pairs,
    min_separation,
    point_triangle_distance,
    segment_segment_distance,
    triangles_meet,
)


@pytest.fixture(autouse=True)
def taichi_f64():
    """The crossing checks are NumPy only: this replaces conftest's per-test Taichi runtime, whose start
    would cost more than most of these tests."""
    yield


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def orient(a, b, c, d):
    return dot(sub(b, a), cross(sub(c, a), sub(d, a)))


ZERO = (Fraction(0),) * 3


def origin_in_simplex(pts):
    """Whether the origin lies in the closed simplex of pts; None if the points are affinely dependent."""
    if len(pts) == 1:
        return pts[0] == ZERO
    if len(pts) == 2:
        p, q = pts
        d = sub(q, p)
        if d == ZERO:
            return None
        t = dot(sub(ZERO, p), d)
        return cross(d, p) == ZERO and 0 <= t <= dot(d, d)
    if len(pts) == 3:
        p, q, r = pts
        n = cross(sub(q, p), sub(r, p))
        if n == ZERO:
            return None
        if dot(n, p) != 0:  # the origin is off the triangle's plane
            return False
        return all(dot(cross(u, v), n) >= 0 for u, v in ((q, r), (r, p), (p, q)))
    vol = orient(*pts)
    if vol == 0:
        return None
    sides = [orient(*pts[:i], ZERO, *pts[i + 1 :]) for i in range(4)]
    return all(s * vol >= 0 for s in sides)


def triangles_meet_exact(ta, tb):
    diffs = sorted({sub(a, b) for a in ta for b in tb})
    # A shortcut only: all differences strictly on one side of a plane through the origin -> disjoint.
    ea = [sub(ta[i], ta[i - 1]) for i in range(3)]
    eb = [sub(tb[i], tb[i - 1]) for i in range(3)]
    axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1), cross(ea[0], ea[1]), cross(eb[0], eb[1])]
    for axis in axes + [cross(u, v) for u in ea for v in eb]:
        side = [dot(axis, d) for d in diffs]
        if all(h > 0 for h in side) or all(h < 0 for h in side):
            return False
    for k in range(1, 5):
        for pts in itertools.combinations(diffs, k):
            if origin_in_simplex(pts):
                return True
    return False


def exact(x):
    return [tuple(Fraction(float(c)) for c in p) for p in x]


def brute_pairs(x, tris):
    """All pairs of triangles sharing no vertex index that meet, by the exact reference."""
    xf = exact(x)
    out = []
    for i, j in itertools.combinations(range(len(tris)), 2):
        if set(tris[i]) & set(tris[j]):
            continue
        if triangles_meet_exact([xf[v] for v in tris[i]], [xf[v] for v in tris[j]]):
            out.append((i, j))
    return np.array(out, np.int64).reshape(-1, 2)


def grid(n, h=1.0):
    """A flat (n+1)x(n+1)-vertex grid in the z = 0 plane, two triangles per cell, alternating diagonals."""
    ii, jj = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    x = np.stack([ii.ravel() * h, jj.ravel() * h, np.zeros(ii.size)], axis=1)
    tris = []
    for i in range(n):
        for j in range(n):
            a, b = i * (n + 1) + j, (i + 1) * (n + 1) + j
            c, d = b + 1, a + 1
            tris += [(a, b, c), (a, c, d)] if (i + j) % 2 == 0 else [(a, b, d), (b, c, d)]
    return x, np.array(tris, np.int64)


def soup(seed, *, n_vert=10, n_tri=14, lo=-1, hi=2):
    """Random integer vertices in a small box (many coplanar, collinear and touching triangles)."""
    rng = np.random.default_rng(seed)
    x = rng.integers(lo, hi + 1, size=(n_vert, 3)).astype(np.float64)
    tris = np.array([rng.choice(n_vert, 3, replace=False) for _ in range(n_tri)], np.int64)
    return x, tris


@pytest.mark.parametrize("seed", range(12))
def test_pairs_equal_exact_reference_on_random_soups(seed):
    x, tris = soup(seed)
    got = intersecting_triangle_pairs(x, tris)
    np.testing.assert_array_equal(got, brute_pairs(x, tris))


ADVERSARIAL = {
    # name: (triangle A, triangle B, meet?)
    "vertex_on_face": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(1, 1, 0), (1, 1, 3), (2, 3, 5)], True),
    "vertex_on_edge": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(2, 0, 0), (2, -1, 3), (3, -2, 1)], True),
    "vertex_on_vertex": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(4, 0, 0), (5, 1, 1), (6, 0, 2)], True),
    "edges_cross": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(1, -1, 0), (1, 2, 0), (1, 0, 3)], True),
    "pierce": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(1, 1, -1), (1, 1, 1), (3, 3, 1)], True),
    "above": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(1, 1, 1), (2, 1, 1), (1, 2, 3)], False),
    "coplanar_overlap": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(1, 1, 0), (5, 1, 0), (1, 5, 0)], True),
    "coplanar_inside": ([(0, 0, 0), (8, 0, 0), (0, 8, 0)], [(1, 1, 0), (2, 1, 0), (1, 2, 0)], True),
    "coplanar_edge_touch": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(2, 2, 0), (4, 4, 0), (0, 8, 0)], True),
    "coplanar_apart": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(3, 3, 0), (5, 3, 0), (3, 5, 0)], False),
    "coplanar_star": ([(0, 0, 0), (6, 0, 0), (3, 6, 0)], [(0, 4, 0), (6, 4, 0), (3, -2, 0)], True),
    "beside_corner": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(-1, -1, 1), (-2, -1, -1), (-1, -2, 0)], False),
    "needle_through": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(1, 1, -2), (1, 1, 2), (1, 1, 5)], True),
    "needle_beside": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(3, 3, -2), (3, 3, 2), (3, 3, 5)], False),
    "point_on_face": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(1, 2, 0), (1, 2, 0), (1, 2, 0)], True),
    "point_off_face": ([(0, 0, 0), (4, 0, 0), (0, 4, 0)], [(3, 2, 0), (3, 2, 0), (3, 2, 0)], False),
    "needles_cross": ([(0, 0, 0), (2, 2, 2), (4, 4, 4)], [(4, 0, 0), (2, 2, 2), (0, 4, 4)], True),
    "needles_skew": ([(0, 0, 0), (2, 2, 2), (4, 4, 4)], [(4, 0, 1), (2, 2, 3), (0, 4, 5)], False),
    "needles_collinear_overlap": ([(0, 0, 0), (1, 1, 0), (3, 3, 0)], [(2, 2, 0), (5, 5, 0), (4, 4, 0)], True),
    "needles_collinear_apart": ([(0, 0, 0), (1, 1, 0), (2, 2, 0)], [(3, 3, 0), (5, 5, 0), (4, 4, 0)], False),
}


@pytest.mark.parametrize("name", sorted(ADVERSARIAL))
def test_adversarial_pairs(name):
    a, b, expected = ADVERSARIAL[name]
    assert triangles_meet_exact(exact(a), exact(b)) is expected  # the reference agrees with the label
    for ta, tb in ((a, b), (b, a), (a[::-1], b[1:] + b[:1])):  # the order of the pair and of the corners
        got = triangles_meet(np.array([ta], np.float64), np.array([tb], np.float64))
        assert bool(got[0]) is expected


def test_shared_vertex_index_is_not_a_pair_but_a_duplicated_vertex_is():
    x = np.array([(0, 0, 0), (4, 0, 0), (0, 4, 0), (0, 0, 4), (-4, 0, 0), (0, 0, 0)], np.float64)
    assert intersecting_triangle_pairs(x, [(0, 1, 2), (0, 3, 4)]).shape == (0, 2)
    np.testing.assert_array_equal(intersecting_triangle_pairs(x, [(0, 1, 2), (5, 3, 4)]), [[0, 1]])


def test_flat_grid_has_no_pairs():
    x, tris = grid(12, 0.1)
    assert intersecting_triangle_pairs(x, tris).shape == (0, 2)
    x, tris = grid(4)
    assert brute_pairs(x, tris).shape == (0, 2)


def rotation(seed):
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


@pytest.mark.parametrize("seed", range(3))
def test_rotated_flat_and_stacked_grids_have_no_pairs(seed):
    """Round-off makes a rotated flat grid only nearly coplanar: no pair may appear from noise."""
    x, tris = grid(16, 1 / 16)
    rot = rotation(seed)
    assert intersecting_triangle_pairs(x @ rot.T + 0.3, tris).shape == (0, 2)
    stacked = np.concatenate([x, x + (0.01, 0.02, 1e-3)]) @ rot.T
    assert intersecting_triangle_pairs(stacked, np.concatenate([tris, tris + len(x)])).shape == (0, 2)
    crossing = np.concatenate([x, x + (0.01, 0.02, 0.0)]) @ rot.T  # coplanar to round-off, overlapping
    assert len(intersecting_triangle_pairs(crossing, np.concatenate([tris, tris + len(x)]))) > 0


def folded_grid(n):
    """A flat grid whose far half is folded back over the near half along a wavy line, crossing it."""
    x, tris = grid(n)
    fold = n // 2
    far = x[:, 0] > fold
    u, y = x[far, 0] - fold, x[far, 1]
    x[far, 0] = fold - u
    x[far, 2] = u * (u - 2) + (y % 2)  # below the sheet near the fold, above it further out
    return x, tris


def test_folded_grid_pairs_equal_exact_reference():
    x, tris = folded_grid(6)
    got = intersecting_triangle_pairs(x, tris)
    assert len(got) > 0
    np.testing.assert_array_equal(got, brute_pairs(x, tris))


def crossing_sheets(n, angle):
    """Two n x n sheets, the second tilted by `angle` about the x axis through the first's middle."""
    xa, ta = grid(n, 1.0 / n)
    xb = xa.copy()
    xb[:, 1] -= 0.5
    c, s = np.cos(angle), np.sin(angle)
    xb[:, 1], xb[:, 2] = c * xb[:, 1], s * xb[:, 1]
    xb[:, 1] += 0.5
    xb[:, 0] = 0.5 + 1.1 * (xb[:, 0] - 0.5) + 0.25 / n  # wider than the first, its columns off the first's
    return np.concatenate([xa, xb]), np.concatenate([ta, ta + len(xa)])


def test_crossing_sheets_equal_exact_reference():
    x, tris = crossing_sheets(4, 0.7)
    got = intersecting_triangle_pairs(x, tris)
    assert len(got) > 0 and (got[:, 0] < 32).all() and (got[:, 1] >= 32).all()
    np.testing.assert_array_equal(got, brute_pairs(x, tris))


def test_large_sheets_crossing_line_is_covered():
    """Every triangle of sheet A cut by the plane of sheet B (tilted, so the cut is one line) is found."""
    n = 32
    x, tris = crossing_sheets(n, 0.9)
    got = intersecting_triangle_pairs(x, tris)
    half = len(tris) // 2
    cut = x[tris[:half]][:, :, 1]  # sheet B meets sheet A's plane on the line y = 0.5 (a grid line of A)
    straddle = (cut.min(axis=1) <= 0.5) & (cut.max(axis=1) >= 0.5)
    np.testing.assert_array_equal(np.unique(got[:, 0]), np.flatnonzero(straddle))


# ---------------------------------------------------------------- separations


def point_segment_sq(p, a, b):
    d, r = sub(b, a), sub(p, a)
    cands = [dot(r, r), dot(sub(p, b), sub(p, b))]
    dd = dot(d, d)
    if dd:
        t = dot(r, d) / dd
        if 0 <= t <= 1:
            e = sub(r, tuple(t * c for c in d))
            cands.append(dot(e, e))
    return min(cands)


def gram_candidate(r, e1, e2):
    """min |r - s e1 - t e2|^2 over the plane's interior s, t >= 0, s + t <= 1 (None if not interior)."""
    a, b, c = dot(e1, e1), dot(e1, e2), dot(e2, e2)
    det = a * c - b * b
    if det == 0:
        return None
    f, g = dot(e1, r), dot(e2, r)
    s, t = (c * f - b * g) / det, (a * g - b * f) / det
    if s < 0 or t < 0 or s + t > 1:
        return None
    e = tuple(r[k] - s * e1[k] - t * e2[k] for k in range(3))
    return dot(e, e)


def point_triangle_sq(p, a, b, c):
    cands = [point_segment_sq(p, u, v) for u, v in ((a, b), (b, c), (c, a))]
    inner = gram_candidate(sub(p, a), sub(b, a), sub(c, a))
    return min(cands + ([inner] if inner is not None else []))


def segment_segment_sq(p0, p1, q0, q1):
    cands = [point_segment_sq(p0, q0, q1), point_segment_sq(p1, q0, q1)]
    cands += [point_segment_sq(q0, p0, p1), point_segment_sq(q1, p0, p1)]
    u, v = sub(p1, p0), sub(q1, q0)
    a, b, c = dot(u, u), dot(u, v), dot(v, v)
    det = a * c - b * b
    if det:
        r = sub(p0, q0)
        d, e = dot(u, r), dot(v, r)
        s, t = (b * e - c * d) / det, (a * e - b * d) / det
        if 0 <= s <= 1 and 0 <= t <= 1:
            w = tuple(r[k] + s * u[k] - t * v[k] for k in range(3))
            cands.append(dot(w, w))
    return min(cands)


def brute_separations(x, tris):
    """{(kind, vertices): exact squared distance} of all non-adjacent vertex–triangle and edge–edge pairs."""
    xf = exact(x)
    out = {}
    for v in sorted({int(i) for t in tris for i in t}):
        for t in tris:
            if v not in t:
                out[("vertex_triangle", (v, *map(int, t)))] = point_triangle_sq(xf[v], *(xf[i] for i in t))
    edges = sorted({tuple(sorted((int(t[a]), int(t[b])))) for t in tris for a, b in ((0, 1), (1, 2), (2, 0))})
    for e, f in itertools.combinations(edges, 2):
        if not set(e) & set(f):
            out[("edge_edge", (*e, *f))] = segment_segment_sq(*(xf[i] for i in (*e, *f)))
    return out


def test_distances_equal_exact_reference_on_random_pairs():
    rng = np.random.default_rng(7)
    pts = rng.integers(-2, 3, size=(400, 4, 3)) + rng.integers(0, 2, size=(400, 4, 3)) / 2
    pts[:40, 2] = pts[:40, 1]  # zero-length edges and zero-area triangles
    pts[40:80, 3] = pts[40:80, 2] + (pts[40:80, 1] - pts[40:80, 0])  # parallel segments
    got_pt = point_triangle_distance(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3])
    got_ee = segment_segment_distance(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3])
    for k, quad in enumerate(pts):
        p = exact(quad)
        assert got_pt[k] == pytest.approx(float(point_triangle_sq(*p)) ** 0.5, rel=1e-12, abs=1e-12)
        assert got_ee[k] == pytest.approx(float(segment_segment_sq(*p)) ** 0.5, rel=1e-12, abs=1e-12)


def sparse_soup(seed, n_tri=8):
    """Small triangles around random centres, pairs of them sharing an edge (no crossings, mostly)."""
    rng = np.random.default_rng(seed)
    x, tris = [], []
    for k in range(n_tri // 2):
        c = rng.integers(-4, 5, size=3)
        quad = c + rng.integers(-4, 5, size=(4, 3)) / 4  # quarter steps keep the reference exact
        x += list(quad)
        tris += [(4 * k, 4 * k + 1, 4 * k + 2), (4 * k + 1, 4 * k + 3, 4 * k + 2)]
    return np.array(x), np.array(tris, np.int64)


@pytest.mark.parametrize("seed", range(10))
def test_min_separation_equals_exact_reference(seed):
    x, tris = sparse_soup(seed)
    ref = brute_separations(x, tris)
    d = float(min(ref.values())) ** 0.5
    got = min_separation(x, tris, max_distance=100.0)
    assert got.distance == pytest.approx(d, rel=1e-12, abs=1e-12)
    # The reported pair is a true minimiser.
    assert float(ref[(got.kind, got.vertices)]) ** 0.5 == pytest.approx(d, rel=1e-12, abs=1e-12)
    # Within max_distance: found; beyond it: distance is inf.
    assert min_separation(x, tris, max_distance=d * 1.001 + 1e-9).distance == pytest.approx(d, abs=1e-12)
    if d > 0:
        assert min_separation(x, tris, max_distance=d * 0.999).distance == float("inf")


def test_min_separation_on_flat_grid():
    """In a flat grid of spacing h the closest non-adjacent pair is a vertex and the diagonal facing it,
    at h / sqrt(2)."""
    h = 0.03
    x, tris = grid(6, h)
    got = min_separation(x, tris, max_distance=0.1)
    assert got.distance == pytest.approx(h / np.sqrt(2.0), rel=1e-12)
    ref = brute_separations(*grid(3, 1.0))
    assert float(min(ref.values())) == pytest.approx(0.5)


def test_min_separation_between_sheets_is_their_gap():
    xa, ta = grid(8, 0.125)
    xb = xa + (0.01, 0.02, 0.03)
    x, tris = np.concatenate([xa, xb]), np.concatenate([ta, ta + len(xa)])
    got = min_separation(x, tris, max_distance=0.05)
    assert got.distance == pytest.approx(0.03, rel=1e-12)


# ---------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "x, tris, word",
    [
        (np.zeros((4, 2)), [(0, 1, 2)], "x"),
        (np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), [(0, 1, 2)], "x"),
        (np.eye(3), [(0, 1)], "triangles"),
        (np.eye(3), [(0, 1, 3)], "triangles"),
        (np.eye(3), [(0, -1, 2)], "triangles"),
        (np.eye(3), [(0.0, 1.0, 2.0)], "triangles"),
    ],
)
def test_bad_input_raises(x, tris, word):
    with pytest.raises(ParameterError, match=word):
        intersecting_triangle_pairs(x, tris)
    with pytest.raises(ParameterError, match=word):
        min_separation(x, tris, max_distance=1.0)


def test_bad_max_distance_raises():
    with pytest.raises(ParameterError, match="max_distance"):
        min_separation(np.eye(3), [(0, 1, 2)], max_distance=-1.0)
