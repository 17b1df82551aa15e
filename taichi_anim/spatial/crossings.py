"""Checks of a triangle mesh for self-intersections and separations, in vectorised NumPy float64.

`intersecting_triangle_pairs` lists every pair of non-adjacent triangles (no shared vertex) whose closed
triangles meet. Broad phase: triangle bounding boxes binned in a uniform grid; a box enters every cell it
overlaps, so two overlapping closed boxes share the cell of their overlap's lower corner, and a pair is
kept only in that cell (the prefilter drops no overlapping pair and reports none twice). Narrow phase:
two closed triangles meet iff an edge of one meets the other (the extreme points of T1 ∩ T2 lie on the
boundary of T1 or of T2). A segment pq meets a triangle abc iff it reaches the plane (the heights
sp = (p - a)·n and sq = (q - a)·n are not of one strict sign) and its crossing point X lies in the
triangle, tested in 2D after dropping the normal's largest axis (Möller 1997); X is never formed: the
edge orientations of X times (sq - sp) are sq·orient2d(e, p) - sp·orient2d(e, q). A segment in the plane
is tested in 2D against the triangle's edges, and a zero-area triangle is the union of its edges. The
results are exact when no product rounds, e.g. for integer coordinates of magnitude up to 256 (what the
tests use); for other inputs each sign is well conditioned, so an answer can be wrong only for a pair
that a perturbation of the order of eps·(mesh size) would change (touching within round-off).

`min_separation` returns the smallest distance between a vertex and a triangle that does not contain it,
and between two edges with no shared vertex (Ericson 2005, §5.1.5 and §5.1.9): the closest points lie
inside a face (the projection onto its plane or the two lines' common perpendicular) or at an endpoint
clamped onto the other primitive, and every such candidate is a true distance, so the minimum is exact up
to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..validate import finite_array, non_negative

_KEEP = np.array([[1, 2], [0, 2], [0, 1]])  # the two axes left when dropping axis k


@dataclass(frozen=True)
class Separation:
    """The closest non-adjacent pair found by `min_separation`.

    distance [m] is inf when no pair lies within max_distance; kind is "vertex_triangle" (vertices =
    (vertex, a, b, c)), "edge_edge" (vertices = (p0, p1, q0, q1)) or "" (none found, vertices = ()).
    """

    distance: float
    kind: str
    vertices: tuple[int, ...]


def _check_mesh(x, triangles) -> tuple[np.ndarray, np.ndarray]:
    xs = finite_array("x", x, (3,))
    t = np.asarray(triangles)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ParameterError(f"triangles must have shape (M, 3), got {t.shape}")
    if t.size and not np.issubdtype(t.dtype, np.integer):
        raise ParameterError(f"triangles must hold integer vertex indices, got dtype {t.dtype}")
    t = t.astype(np.int64)
    if t.size and (t.min() < 0 or t.max() >= len(xs)):
        bad = t[(t < 0) | (t >= len(xs))][0]
        raise ParameterError(f"triangles index vertex {bad}, outside [0, {len(xs)}) (x has {len(xs)} rows)")
    return xs, t


# ---------------------------------------------------------------- broad phase: boxes in a uniform grid


def overlapping_box_pairs(lo_a, hi_a, lo_b=None, hi_b=None) -> tuple[np.ndarray, np.ndarray]:
    """Every pair of overlapping closed axis-aligned boxes: box a_i with box b_j, or, without b, a_i with
    a_j for i < j. Boxes that only touch (a shared face, edge or corner) count as overlapping.

    lo_a, hi_a: (N, 3) lower and upper corners [m] of set a; lo_b, hi_b: (K, 3) of set b, or None.
    Returns (i, j), two int64 arrays of equal length: indices into a and into b (or into a), each pair
    once, in no particular order.

    Uniform-grid broad phase (module docstring): cells about the median box's largest side (coarsened
    while the boxes would fill more than 8 cells each on average), each box entered in every cell it
    covers, a pair kept only in the cell of its overlap's lower corner, then the exact box comparison, so
    no overlapping pair is lost or repeated. Linear in the boxes for boxes of similar size; vectorised
    NumPy, no Taichi runtime needed."""
    single = lo_b is None
    na = len(lo_a)
    lo = lo_a if single else np.concatenate([lo_a, lo_b])
    hi = hi_a if single else np.concatenate([hi_a, hi_b])
    empty = np.zeros(0, np.int64)
    if na == 0 or (not single and len(lo) == na):
        return empty, empty
    origin = lo.min(axis=0)
    span = float((hi.max(axis=0) - origin).max())
    # Cells about one typical box wide; at most 2**19 cells per axis so the keys stay in int64.
    h = max(float(np.median((hi - lo).max(axis=1))), span / 2**19)
    if h <= 0.0:
        h = 1.0
    while True:
        c_lo = np.floor((lo - origin) / h).astype(np.int64)
        c_hi = np.floor((hi - origin) / h).astype(np.int64)
        dims = c_hi - c_lo + 1
        counts = dims.prod(axis=1)
        if counts.sum() <= 8 * len(lo) + 64:  # large boxes coarsen the grid instead of flooding it
            break
        h *= 2.0
    box = np.repeat(np.arange(len(lo)), counts)
    k = np.arange(box.size) - np.repeat(np.cumsum(counts) - counts, counts)
    d = dims[box]
    cell = c_lo[box] + np.stack([k % d[:, 0], (k // d[:, 0]) % d[:, 1], k // (d[:, 0] * d[:, 1])], axis=1)
    key = (cell[:, 0] << 40) | (cell[:, 1] << 20) | cell[:, 2]
    side = box >= na  # False for set a, True for set b
    order = np.lexsort((side, key))
    box, key, side, cell = box[order], key[order], side[order], cell[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    size = np.diff(np.r_[start, key.size])
    g_start, g_end = np.repeat(start, size), np.repeat(start + size, size)
    pos = np.arange(key.size)
    if single:
        first = pos + 1
    else:  # set a sorts before set b within a cell: pair each a entry with the cell's b entries
        n_a_in_cell = np.add.reduceat(~side, start)
        first = np.where(side, g_end, g_start + np.repeat(n_a_in_cell, size))
    count = g_end - first
    src = np.repeat(pos, count)
    dst = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + np.repeat(first, count)
    i, j = box[src], box[dst]
    # Keep a pair only in the cell of its overlap's lower corner (unique), and only if the boxes overlap.
    corner = np.floor((np.maximum(lo[i], lo[j]) - origin) / h).astype(np.int64)
    keep = (corner == cell[src]).all(axis=1)
    keep &= (lo[i] <= hi[j]).all(axis=1) & (lo[j] <= hi[i]).all(axis=1)
    i, j = i[keep], j[keep]
    if single:
        i, j = np.minimum(i, j), np.maximum(i, j)
    else:
        j = j - na
    return i, j


# ---------------------------------------------------------------- narrow phase: orientation predicates


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _orient2d(a, b, c):
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def _drop(v, k):
    return np.take_along_axis(v, _KEEP[k], axis=1)


def _on_box(p, q, r):
    """r within the box of segment pq (the collinear case of the 2D segment test)."""
    return ((np.minimum(p, q) <= r) & (r <= np.maximum(p, q))).all(axis=1)


def _segments_meet_2d(p, q, a, b):
    o1, o2 = np.sign(_orient2d(p, q, a)), np.sign(_orient2d(p, q, b))
    o3, o4 = np.sign(_orient2d(a, b, p)), np.sign(_orient2d(a, b, q))
    hit = (o1 * o2 < 0) & (o3 * o4 < 0)
    hit |= (o1 == 0) & _on_box(p, q, a)
    hit |= (o2 == 0) & _on_box(p, q, b)
    hit |= (o3 == 0) & _on_box(a, b, p)
    hit |= (o4 == 0) & _on_box(a, b, q)
    return hit


def _segments_meet_3d(p, q, a, b):
    """Closed segments pq and ab meet (either may be a point)."""
    u, w, r = q - p, b - a, a - p
    coplanar = _dot(u, np.cross(r, b - p)) == 0
    # Project along a normal of their common plane, or along a line through all four points.
    m = np.cross(u, w)
    for alt in (np.cross(u, r), np.cross(w, -r)):
        zero = (m == 0).all(axis=1)
        m[zero] = alt[zero]
    k = np.argmax(np.abs(m), axis=1)
    line = (m == 0).all(axis=1)
    if line.any():  # collinear: drop an axis along which the line does not vanish
        d = np.stack([u, w, r], axis=1)[line]
        longest = np.argmax(np.abs(d).max(axis=2), axis=1)
        k[line] = np.argmin(np.abs(d[np.arange(len(d)), longest]), axis=1)
    return coplanar & _segments_meet_2d(_drop(p, k), _drop(q, k), _drop(a, k), _drop(b, k))


def _segment_meets_triangle(p, q, tri, n):
    """Closed segment pq meets the closed triangle tri (K, 3, 3) of non-zero normal n."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    sp, sq = _dot(p - a, n), _dot(q - a, n)
    apart = ((sp > 0) & (sq > 0)) | ((sp < 0) & (sq < 0))
    coplanar = (sp == 0) & (sq == 0)
    k = np.argmax(np.abs(n), axis=1)  # the projection along this axis keeps the triangle's area
    p2, q2 = _drop(p, k), _drop(q, k)
    corners = [_drop(a, k), _drop(b, k), _drop(c, k)]
    # The crossing point X = (sq p - sp q) / (sq - sp) lies on pq; the orientation of X against each
    # edge, times (sq - sp), is sq·orient2d(e, p) - sp·orient2d(e, q): no division, exact for small
    # integers, and a positive blend of two in-plane areas (well conditioned) when pq is nearly in-plane.
    w = []
    for i in range(3):
        e0, e1 = corners[i], corners[(i + 1) % 3]
        w.append(sq * _orient2d(e0, e1, p2) - sp * _orient2d(e0, e1, q2))
    w1, w2, w3 = w
    through = ((w1 >= 0) & (w2 >= 0) & (w3 >= 0)) | ((w1 <= 0) & (w2 <= 0) & (w3 <= 0))
    hit = ~apart & ~coplanar & through
    if coplanar.any():
        s = np.flatnonzero(coplanar)
        a2, b2, c2 = (v[s] for v in corners)
        inside = np.zeros(len(s), bool)
        for r in (p2[s], q2[s]):
            d1, d2, d3 = _orient2d(a2, b2, r), _orient2d(b2, c2, r), _orient2d(c2, a2, r)
            inside |= ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)) | ((d1 <= 0) & (d2 <= 0) & (d3 <= 0))
        for e0, e1 in ((a2, b2), (b2, c2), (c2, a2)):
            inside |= _segments_meet_2d(p2[s], q2[s], e0, e1)
        hit[s] = inside
    return hit


_EDGES = ((0, 1), (1, 2), (2, 0))


def triangles_meet(tri_a: np.ndarray, tri_b: np.ndarray) -> np.ndarray:
    """Whether closed triangles tri_a[k] and tri_b[k] (K, 3, 3) share a point; (K,) bool."""
    hit = np.zeros(len(tri_a), bool)
    normals = [np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) for t in (tri_a, tri_b)]
    flat = [(nrm == 0).all(axis=1) for nrm in normals]
    passes = ((tri_a, tri_b, normals[1], flat[1]), (tri_b, tri_a, normals[0], flat[0]))
    for edges_of, other, n_other, flat_other in passes:
        for e0, e1 in _EDGES:  # a zero-area `other` is covered by its own edges in the other pass
            s = np.flatnonzero(~hit & ~flat_other)
            hit[s] = _segment_meets_triangle(edges_of[s, e0], edges_of[s, e1], other[s], n_other[s])
    both_flat = np.flatnonzero(flat[0] & flat[1])
    for e0, e1 in _EDGES:  # two zero-area triangles: segments against segments
        for f0, f1 in _EDGES:
            s = both_flat[~hit[both_flat]]
            hit[s] = _segments_meet_3d(tri_a[s, e0], tri_a[s, e1], tri_b[s, f0], tri_b[s, f1])
    return hit


def intersecting_triangle_pairs(x, triangles) -> np.ndarray:
    """All pairs of triangles that share no vertex index and whose closed triangles meet.

    x: (N, 3) vertex positions [m]; triangles: (M, 3) vertex indices. Returns (K, 2) int64 triangle
    indices (i < j), sorted. Touching (a common point on the boundary) counts as meeting.
    """
    xs, t = _check_mesh(x, triangles)
    if len(t) < 2:
        return np.zeros((0, 2), np.int64)
    corners = xs[t]
    i, j = overlapping_box_pairs(corners.min(axis=1), corners.max(axis=1))
    apart = ~(t[i][:, :, None] == t[j][:, None, :]).any(axis=(1, 2))
    i, j = i[apart], j[apart]
    hit = triangles_meet(corners[i], corners[j])
    pairs = np.stack([i[hit], j[hit]], axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


# ---------------------------------------------------------------- distances


def _point_segment(p, a, b):
    d = b - a
    dd = _dot(d, d)
    t = np.clip(_dot(p - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - a - t[:, None] * d, axis=1)


def point_triangle_distance(p, a, b, c) -> np.ndarray:
    """Distance [m] from points p (K, 3) to closed triangles (a, b, c) (each (K, 3)); (K,)."""
    dist = np.minimum(np.minimum(_point_segment(p, a, b), _point_segment(p, b, c)), _point_segment(p, c, a))
    n = np.cross(b - a, c - a)
    nn = _dot(n, n)
    inside = nn > 0
    # The projection onto the plane lies inside iff it is on the inner side of each edge.
    for e0, e1 in ((a, b), (b, c), (c, a)):
        inside &= _dot(np.cross(e1 - e0, p - e0), n) >= 0
    plane = np.abs(_dot(p - a, n)) / np.sqrt(np.where(nn > 0, nn, 1.0))
    return np.where(inside, np.minimum(dist, plane), dist)


def segment_segment_distance(p0, p1, q0, q1) -> np.ndarray:
    """Distance [m] between closed segments p0p1 and q0q1 (each (K, 3)); (K,)."""
    ends = [_point_segment(p, q0, q1) for p in (p0, p1)] + [_point_segment(q, p0, p1) for q in (q0, q1)]
    dist = np.minimum.reduce(ends)
    u, v, r = p1 - p0, q1 - q0, p0 - q0
    a, b, c, d, e = _dot(u, u), _dot(u, v), _dot(v, v), _dot(u, r), _dot(v, r)
    den = a * c - b * b
    ok = den > 1e-12 * a * c  # not parallel: the common perpendicular may join two interior points
    den = np.where(ok, den, 1.0)
    s, t = (b * e - c * d) / den, (a * e - b * d) / den
    ok &= (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    inner = np.linalg.norm(r + s[:, None] * u - t[:, None] * v, axis=1)
    return np.where(ok, np.minimum(dist, inner), dist)


def min_separation(x, triangles, *, max_distance: float) -> Separation:
    """The closest vertex–triangle (vertex not in the triangle) or edge–edge (no shared vertex) pair.

    x: (N, 3) vertex positions [m]; triangles: (M, 3) vertex indices; max_distance [m]: pairs farther
    apart are not examined (the result is then distance = inf). Only vertices used by a triangle count.
    """
    xs, t = _check_mesh(x, triangles)
    reach = non_negative("max_distance", max_distance)
    best = Separation(float("inf"), "", ())
    if len(t) == 0:
        return best
    pad = reach * (1.0 + 1e-9)  # keep pairs at exactly max_distance despite round-off in the boxes
    corners = xs[t]
    verts = np.unique(t)
    vi, ti = overlapping_box_pairs(xs[verts] - pad, xs[verts] + pad, corners.min(axis=1), corners.max(axis=1))
    vi = verts[vi]
    keep = ~(t[ti] == vi[:, None]).any(axis=1)
    vi, ti = vi[keep], ti[keep]
    if len(vi):
        dist = point_triangle_distance(xs[vi], *(corners[ti, k] for k in range(3)))
        m = int(np.argmin(dist))
        if dist[m] <= reach and dist[m] < best.distance:
            best = Separation(float(dist[m]), "vertex_triangle", (int(vi[m]), *map(int, t[ti[m]])))
    edges = np.unique(np.sort(t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    ends = xs[edges]
    lo, hi = ends.min(axis=1) - pad / 2, ends.max(axis=1) + pad / 2
    ea, eb = overlapping_box_pairs(lo, hi)
    keep = ~(edges[ea][:, :, None] == edges[eb][:, None, :]).any(axis=(1, 2))
    ea, eb = ea[keep], eb[keep]
    if len(ea):
        dist = segment_segment_distance(ends[ea, 0], ends[ea, 1], ends[eb, 0], ends[eb, 1])
        m = int(np.argmin(dist))
        if dist[m] <= reach and dist[m] < best.distance:
            best = Separation(float(dist[m]), "edge_edge", (*map(int, edges[ea[m]]), *map(int, edges[eb[m]])))
    return best
