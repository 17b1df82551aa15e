"""Whether a triangle mesh is closed, manifold, consistently oriented and free of real self-intersections.

`mesh_report(vertices, triangles)` returns a `MeshReport`. Topology (plain NumPy, exact by construction):
edges are the sorted vertex pairs of the triangles' sides, counted with `np.unique`; a mesh is closed when
every edge has exactly two triangles and edge-manifold when none has more; it is consistently oriented
when no directed edge (i, j) occurs twice, i.e. the two triangles of an edge walk it in opposite
directions. A vertex is manifold when its triangles form one fan: its link (the sides opposite to it in
its triangles) is a single path or cycle, i.e. connected with no link vertex of degree above 2 (a bow-tie
vertex has two components, a vertex on a fin edge a link vertex of degree 3). Components are the
connected sets of triangles through shared vertices (union-find with pointer jumping); Euler
characteristic chi = V - E + F over the vertices used; genus = components - chi / 2 for a closed,
manifold, oriented mesh. Signed volume by the divergence theorem, V = (1/6) sum (a - o) . ((b - o) x
(c - o)) with o the centroid of the used vertices (any o gives the same V for a closed mesh; the centroid
keeps the terms small).

Self-intersection, exact for any float64 input. Broad phase: the closed bounding boxes of the triangles
binned in a uniform grid (`crossings.overlapping_box_pairs`, also the broad phase of
`intersecting_triangle_pairs`; comparisons of boxes are exact, so no overlapping pair is dropped).
Narrow phase, by how many vertex indices a pair shares:
- none: the closed triangles meet (touching counts: non-adjacent triangles of a valid mesh never touch);
- one, v (triangles v a b and v c d): they meet away from v iff the closed segment ab meets the closed
  triangle v c d or segment cd meets v a b (T1 and T2 are convex and contain v, so a common point other
  than v gives a common segment from v, whose far end lies on ab or on cd);
- two, a b (triangles a b c and a b d): their planes meet in the line ab, which cuts each triangle in the
  side ab, so they meet beyond ab iff they are coplanar, orient3d(a, b, c, d) = 0, with c and d on the
  same side of ab, (b - a) x (c - a) . (b - a) x (d - a) > 0: a fold-over;
- three (the same triangle twice): reported as duplicates, not as intersections.
The two adjacent cases assume non-degenerate triangles: a pair that shares a vertex and has a zero-area
triangle is not tested (zero-area triangles are reported on their own). Each test is first decided in
float64 with a rigorous error bound and only the undecided pairs are recomputed exactly:
- "disjoint" is certified by a separating axis (the two normals, the nine cross products of sides and
  the in-plane side normals: the separating axes of two triangles) along which the projections do not
  overlap by more than their rounding bound, 8 u m |axis|_1 each (u = 2^-53, m the largest |coordinate|
  of the pair: above the gamma_3 bound of a 3-term dot product plus the roundings of the bound and of
  the comparison); any axis proves separation, so the axis itself need not be exact;
- orient3d and the zero-area test use Shewchuk's static filters ("Adaptive precision floating-point
  arithmetic and fast robust geometric predicates", 1997: errbounds (7 + 56u)u and (3 + 16u)u times the
  permanent);
- the rest is decided in integer arithmetic: every float64 is an integer times a power of two, so the
  coordinates scaled by the smallest power in the mesh are Python integers, on which the orientation
  predicates of `crossings.triangles_meet` (Moeller 1997, only +, - and x) are exact.

Why not Open3D (0.20): `is_watertight` is edge-manifold and vertex-manifold and not `is_self_intersecting`,
and `get_volume` raises unless the mesh is watertight and orientable. `is_self_intersecting` tests every
pair of triangles without a shared vertex (F^2 / 2 box tests) with Moeller's 1997 test after scaling the
pair's six points to zero mean and unit spread per axis, and sets plane distances below a fixed 1e-6 to
zero. A sliver's normal is tiny, so every point lies "on" its plane, the pair goes to the coplanar branch
and overlapping projections count as an intersection: on blob meshes it reports pairs a micrometre apart
(tests/test_mesh_check.py has one: 320 triangles, 4 false pairs, so `get_volume` refuses it).
Cost: about linear in the triangle count (sorts, the grid and the vectorised filters); the exact integer
step only sees pairs that touch or nearly touch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..validate import finite_array
from .crossings import overlapping_box_pairs, triangles_meet

_U = 2.0**-53  # unit round-off of float64
_AXIS_BOUND = 8 * _U
_O3D_BOUND = (7.0 + 56.0 * _U) * _U
_O2D_BOUND = (3.0 + 16.0 * _U) * _U
_TINY = np.finfo(np.float64).tiny  # covers the absolute error of subnormal results
_SIDES = ((0, 1), (1, 2), (2, 0))
_CHUNK = 1 << 18  # pairs per vectorised batch (bounded memory)


def _ids(a: np.ndarray) -> np.ndarray:
    return a.reshape(-1, 2) if a.size else np.zeros((0, 2), np.int64)


@dataclass(frozen=True, eq=False)
class MeshReport:
    """What `mesh_report` found. Index arrays are int64; edges are (K, 2) sorted vertex pairs.

    vertex_count: vertices used by a triangle; edge_count: distinct edges; boundary_edges: edges of one
    triangle; non_manifold_edges: edges of three or more; misoriented_edges: edges whose two triangles
    walk them in the same direction; non_manifold_vertices: vertices whose triangles do not form one fan;
    degenerate_triangles: zero area (collinear or repeated corners); duplicate_triangles: (K, 2) pairs of
    triangles with the same three vertices; intersecting_pairs: (K, 2) triangle pairs (i < j) that meet
    where they should not (see the module docstring); component_count: sets of triangles connected
    through shared vertices; euler_characteristic: V - E + F; genus: for a closed, manifold, oriented
    mesh, else None; volume [m^3]: signed divergence-theorem volume (positive for outward normals;
    meaningful when closed and oriented); area [m^2].
    """

    vertex_count: int
    triangle_count: int
    edge_count: int
    boundary_edges: np.ndarray
    non_manifold_edges: np.ndarray
    misoriented_edges: np.ndarray
    non_manifold_vertices: np.ndarray
    degenerate_triangles: np.ndarray
    duplicate_triangles: np.ndarray
    intersecting_pairs: np.ndarray
    component_count: int
    euler_characteristic: int
    genus: int | None
    volume: float
    area: float

    @property
    def closed(self) -> bool:
        """Every edge is shared by exactly two triangles (and there is at least one triangle)."""
        return self.triangle_count > 0 and not len(self.boundary_edges) and not len(self.non_manifold_edges)

    @property
    def edge_manifold(self) -> bool:
        """No edge has more than two triangles."""
        return not len(self.non_manifold_edges)

    @property
    def vertex_manifold(self) -> bool:
        """The triangles around every vertex form one fan."""
        return not len(self.non_manifold_vertices)

    @property
    def oriented(self) -> bool:
        """Each edge shared by two triangles is walked once in each direction."""
        return not len(self.misoriented_edges)

    @property
    def self_intersecting(self) -> bool:
        """Some pair of triangles meets where it should not (`intersecting_pairs` is not empty)."""
        return bool(len(self.intersecting_pairs))

    @property
    def is_closed_manifold(self) -> bool:
        """Closed, edge- and vertex-manifold, consistently oriented, no duplicated triangle."""
        return self.closed and self.vertex_manifold and self.oriented and not len(self.duplicate_triangles)

    @property
    def ok(self) -> bool:
        """A closed manifold without self-intersections or zero-area triangles (whose adjacent pairs are
        not tested): the boundary of a solid."""
        return self.is_closed_manifold and not self.self_intersecting and not len(self.degenerate_triangles)

    def describe(self) -> str:
        """A few lines for people: the verdict, then each failed check with up to 5 examples."""
        head = "ok: closed manifold, oriented, no self-intersections" if self.ok else "NOT a valid solid"
        lines = [
            f"{head}; {self.triangle_count} triangles, {self.vertex_count} vertices, {self.edge_count} edges",
            f"components {self.component_count}, Euler characteristic {self.euler_characteristic}, "
            f"genus {self.genus}, volume {self.volume:.6g} m^3, area {self.area:.6g} m^2",
        ]
        for name in (
            "boundary_edges",
            "non_manifold_edges",
            "misoriented_edges",
            "non_manifold_vertices",
            "degenerate_triangles",
            "duplicate_triangles",
            "intersecting_pairs",
        ):
            items = getattr(self, name)
            if len(items):
                shown = ", ".join(str(x.tolist()) for x in items[:5])
                lines.append(f"{name}: {len(items)} ({shown}{', ...' if len(items) > 5 else ''})")
        return "\n".join(lines)


def _mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    x = finite_array("vertices", vertices, (3,))
    t = np.asarray(triangles)
    if t.size == 0:
        t = t.reshape(0, 3)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ParameterError(f"triangles must have shape (M, 3), got {t.shape}")
    if t.size and not np.issubdtype(t.dtype, np.integer):
        raise ParameterError(f"triangles must hold integer vertex indices, got dtype {t.dtype}")
    t = t.astype(np.int64)
    if t.size and (t.min() < 0 or t.max() >= len(x)):
        bad = t[(t < 0) | (t >= len(x))][0]
        raise ParameterError(
            f"triangles index vertex {bad}, outside [0, {len(x)}) (vertices has {len(x)} rows)"
        )
    return x, t


# ---------------------------------------------------------------- topology


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Component labels (n,) of the graph with edges (a, b): hook roots to the smaller root, then jump
    pointers until every node points at its root; repeat until no edge joins two labels."""
    label = np.arange(n)
    while True:
        la, lb = label[a], label[b]
        join = la != lb
        if not join.any():
            return label
        np.minimum.at(label, np.maximum(la, lb)[join], np.minimum(la, lb)[join])
        while True:
            nxt = label[label]
            if np.array_equal(nxt, label):
                break
            label = nxt


def _topology(n: int, t: np.ndarray) -> dict:
    half = t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    lo, hi = half.min(axis=1), half.max(axis=1)
    edges, counts = np.unique(lo * n + hi, return_counts=True)
    directed, d_counts = np.unique(half[:, 0] * n + half[:, 1], return_counts=True)
    twice = directed[d_counts > 1]
    mis = np.unique(np.minimum(twice // n, twice % n) * n + np.maximum(twice // n, twice % n))
    # The link of vertex v: nodes (v, w) for its neighbours w, one link edge per triangle corner at v.
    corner_a = np.concatenate([t[:, 0] * n + t[:, 1], t[:, 1] * n + t[:, 2], t[:, 2] * n + t[:, 0]])
    corner_b = np.concatenate([t[:, 0] * n + t[:, 2], t[:, 1] * n + t[:, 0], t[:, 2] * n + t[:, 1]])
    nodes, inv = np.unique(np.concatenate([corner_a, corner_b]), return_inverse=True)
    na, nb = inv[: len(corner_a)], inv[len(corner_a) :]
    label = _components(len(nodes), na, nb)
    degree = np.bincount(np.concatenate([na, nb]), minlength=len(nodes))
    owner = nodes // n
    fans = np.unique(owner * len(nodes) + label) // len(nodes)  # (vertex, link component), one per fan
    second_fan = fans[1:][np.diff(fans) == 0]
    bad = np.unique(np.concatenate([second_fan, owner[degree > 2]]))
    used = np.unique(t)
    vlabel = _components(n, np.concatenate([t[:, 0], t[:, 1]]), np.concatenate([t[:, 1], t[:, 2]]))
    return {
        "edge_count": len(edges),
        "boundary_edges": _ids(np.stack([edges[counts == 1] // n, edges[counts == 1] % n], axis=1)),
        "non_manifold_edges": _ids(np.stack([edges[counts > 2] // n, edges[counts > 2] % n], axis=1)),
        "misoriented_edges": _ids(np.stack([mis // n, mis % n], axis=1)),
        "non_manifold_vertices": bad.astype(np.int64),
        "vertex_count": len(used),
        "component_count": len(np.unique(vlabel[used])),
    }


def _duplicates(t: np.ndarray) -> np.ndarray:
    """(K, 2) pairs (first, other) of triangles with the same vertex set."""
    if not len(t):
        return np.zeros((0, 2), np.int64)
    _, group = np.unique(np.sort(t, axis=1), axis=0, return_inverse=True)
    group = group.ravel()
    first = np.full(group.max() + 1, len(t))
    np.minimum.at(first, group, np.arange(len(t)))
    other = np.flatnonzero(first[group] != np.arange(len(t)))
    pairs = np.stack([first[group[other]], other], axis=1)
    return pairs[np.lexsort(pairs.T[::-1])]


# ---------------------------------------------------------------- exact arithmetic


class _Exact:
    """Exact integer images of the coordinates: x = M 2^k with |M| < 2^53; scaled by 2^-E, E the smallest
    k in the mesh, every coordinate is the Python integer M << (k - E) (translation-free, so predicates
    on them have the signs of the same predicates on the float64 values)."""

    def __init__(self, x: np.ndarray):
        m, e = np.frexp(x)
        self.mant = (m * 2.0**53).astype(np.int64)  # exact: m has 53 significant bits
        k = e.astype(np.int64) - 53
        nonzero = self.mant != 0
        base = int(k[nonzero].min()) if nonzero.any() else 0
        self.shift = np.where(nonzero, k - base, 0)

    def points(self, ids: np.ndarray) -> np.ndarray:
        """Integer coordinates (..., 3) (object array) of vertices ids (...)."""
        flat = ids.ravel()
        out = np.empty((len(flat), 3), dtype=object)
        for c in range(3):
            out[:, c] = [
                int(mm) << int(s) for mm, s in zip(self.mant[flat, c], self.shift[flat, c], strict=True)
            ]
        return out.reshape(ids.shape + (3,))


def _dot(a, b):
    return (a * b).sum(axis=-1)


def _separated(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """True where a separating axis with a margin above the rounding bound proves that the convex hulls
    of the point triples p and q (K, 3, 3) are disjoint; False means undecided. Each projection p . u
    is off by at most 8 u_r m |u|_1 (m the largest |coordinate| of the pair, u_r = 2^-53)."""
    done = np.zeros(len(p), bool)
    rest = np.arange(len(p))
    m = np.maximum(np.abs(p).max(axis=(1, 2)), np.abs(q).max(axis=(1, 2)))
    for axis in range(17):
        if not len(rest):
            break
        pp, qq = p[rest], q[rest]
        if axis < 2:  # the normals
            t = pp if axis == 0 else qq
            u = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        elif axis < 11:  # side x side
            k = axis - 2
            u = np.cross(_side(pp, k // 3), _side(qq, k % 3))
        else:  # in the plane of p or q, normal to a side of p or q (coplanar pairs)
            k = axis - 11
            t = pp if k < 3 else qq
            n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
            u = np.cross(n, _side(pp if k % 2 else qq, k % 3))
        err = _AXIS_BOUND * m[rest] * np.abs(u).sum(axis=1) + _TINY
        with np.errstate(invalid="ignore", over="ignore"):  # inf and nan compare False: undecided
            proj_p, proj_q = np.einsum("kpi,ki->kp", pp, u), np.einsum("kpi,ki->kp", qq, u)
            apart = (proj_p.max(1) + err < proj_q.min(1) - err) | (proj_q.max(1) + err < proj_p.min(1) - err)
        done[rest[apart]] = True
        rest = rest[~apart]
    return done


def _side(t: np.ndarray, k: int) -> np.ndarray:
    i, j = _SIDES[k]
    return t[:, j] - t[:, i]


def _meet(x: np.ndarray, exact: _Exact, ip: np.ndarray, iq: np.ndarray) -> np.ndarray:
    """Whether the convex hulls of vertex triples ip and iq (K, 3) meet (a repeated index is a segment)."""
    hit = np.zeros(len(ip), bool)
    for start in range(0, len(ip), _CHUNK):
        sl = slice(start, start + _CHUNK)
        undecided = start + np.flatnonzero(~_separated(x[ip[sl]], x[iq[sl]]))
        if len(undecided):
            hit[undecided] = triangles_meet(exact.points(ip[undecided]), exact.points(iq[undecided]))
    return hit


def _orient3d_zero(x, exact, a, b, c, d) -> np.ndarray:
    """orient3d(a, b, c, d) == 0 exactly, for vertex index arrays (K,)."""
    ad, bd, cd = x[a] - x[d], x[b] - x[d], x[c] - x[d]
    m = [bd[:, 1] * cd[:, 2], bd[:, 2] * cd[:, 1], cd[:, 1] * ad[:, 2], cd[:, 2] * ad[:, 1]]
    m += [ad[:, 1] * bd[:, 2], ad[:, 2] * bd[:, 1]]
    det = ad[:, 0] * (m[0] - m[1]) + bd[:, 0] * (m[2] - m[3]) + cd[:, 0] * (m[4] - m[5])
    perm = np.abs(ad[:, 0]) * (np.abs(m[0]) + np.abs(m[1])) + np.abs(bd[:, 0]) * (np.abs(m[2]) + np.abs(m[3]))
    perm += np.abs(cd[:, 0]) * (np.abs(m[4]) + np.abs(m[5]))
    with np.errstate(invalid="ignore", over="ignore"):  # overflow gives inf or nan: undecided
        zero = ~(np.abs(det) > _O3D_BOUND * perm + _TINY)  # undecided; decided exactly below
    s = np.flatnonzero(zero)
    if len(s):
        pa, pb, pc, pd = (exact.points(v[s]) for v in (a, b, c, d))
        zero[s] = _dot(pa - pd, np.cross(pb - pd, pc - pd)) == 0
    return zero


def _zero_area(x: np.ndarray, exact: _Exact, t: np.ndarray) -> np.ndarray:
    """Exactly collinear corners (or a repeated index), for triangles t (M, 3)."""
    a, b, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
    flat = np.ones(len(t), bool)
    for i, j in ((0, 1), (1, 2), (2, 0)):  # the three 2D orientations are the components of the normal
        with np.errstate(invalid="ignore", over="ignore"):  # inf or nan: undecided
            left, right = (b[:, i] - a[:, i]) * (c[:, j] - a[:, j]), (b[:, j] - a[:, j]) * (c[:, i] - a[:, i])
            flat &= ~(np.abs(left - right) > _O2D_BOUND * (np.abs(left) + np.abs(right)) + _TINY)
    s = np.flatnonzero(flat)
    if len(s):
        pa, pb, pc = (exact.points(t[s, k]) for k in range(3))
        flat[s] = (np.cross(pb - pa, pc - pa) == 0).all(axis=1)
    return flat


# ---------------------------------------------------------------- the narrow phase by shared vertices


def _pair_hits(x, exact, t, flat, i, j) -> np.ndarray:
    ti, tj = t[i], t[j]
    eq = ti[:, :, None] == tj[:, None, :]
    shared = eq.sum(axis=(1, 2))
    hit = np.zeros(len(i), bool)
    s = np.flatnonzero(shared == 0)
    hit[s] = _meet(x, exact, ti[s], tj[s])
    k = np.arange(3)
    s = np.flatnonzero((shared == 1) & ~flat[i] & ~flat[j])
    if len(s):
        p1, p2 = eq[s].any(axis=2).argmax(axis=1), eq[s].any(axis=1).argmax(axis=1)
        opp1 = ti[s][np.arange(len(s))[:, None], (p1[:, None] + k[[1, 2, 2]]) % 3]  # segment a b b
        opp2 = tj[s][np.arange(len(s))[:, None], (p2[:, None] + k[[1, 2, 2]]) % 3]
        hit[s] = _meet(x, exact, opp1, tj[s]) | _meet(x, exact, opp2, ti[s])
    s = np.flatnonzero((shared == 2) & ~flat[i] & ~flat[j])
    if len(s):
        p1, p2 = (~eq[s].any(axis=2)).argmax(axis=1), (~eq[s].any(axis=1)).argmax(axis=1)
        r = np.arange(len(s))
        c, d = ti[s][r, p1], tj[s][r, p2]
        a, b = ti[s][r, (p1 + 1) % 3], ti[s][r, (p1 + 2) % 3]
        fold = _orient3d_zero(x, exact, a, b, c, d)
        f = np.flatnonzero(fold)
        if len(f):
            pa, pb, pc, pd = (exact.points(v[f]) for v in (a, b, c, d))
            fold[f] = _dot(np.cross(pb - pa, pc - pa), np.cross(pb - pa, pd - pa)) > 0
        hit[s] = fold
    return hit


def triangle_pairs_intersect(vertices, triangles, pairs) -> np.ndarray:
    """Whether each pair of triangles (K, 2) meets where it should not, decided exactly (module
    docstring): anywhere if they share no vertex, away from the shared vertex or beyond the shared edge
    otherwise; duplicates and pairs that share a vertex and have a zero-area triangle give False.

    vertices (N, 3) [m]; triangles (M, 3) int; returns (K,) bool."""
    x, t = _mesh(vertices, triangles)
    p = np.asarray(pairs)
    if p.size == 0:
        return np.zeros(0, bool)
    if p.ndim != 2 or p.shape[1] != 2 or not np.issubdtype(p.dtype, np.integer):
        raise ParameterError(f"pairs must be integers of shape (K, 2), got {p.dtype} {p.shape}")
    if p.min() < 0 or p.max() >= len(t):
        raise ParameterError(f"pairs index a triangle outside [0, {len(t)})")
    p = p.astype(np.int64)
    exact = _Exact(x)
    return _pair_hits(x, exact, t, _zero_area(x, exact, t), p[:, 0], p[:, 1])


def mesh_report(vertices, triangles) -> MeshReport:
    """Check a triangle mesh: closed, manifold, oriented, self-intersections, volume (module docstring).

    vertices (N, 3) [m]; triangles (M, 3) int vertex indices (vertices not used by a triangle are
    ignored). Triangles with a repeated index count as degenerate and are left out of everything else."""
    x, t_all = _mesh(vertices, triangles)
    n = len(x)
    exact = _Exact(x)
    repeated = (t_all[:, 0] == t_all[:, 1]) | (t_all[:, 1] == t_all[:, 2]) | (t_all[:, 2] == t_all[:, 0])
    keep = np.flatnonzero(~repeated)
    t = t_all[keep]
    flat = _zero_area(x, exact, t)
    topo = _topology(n, t)
    corners = x[t]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    i, j = overlapping_box_pairs(lo, hi) if len(t) > 1 else (np.zeros(0, np.int64),) * 2
    hit = np.zeros(len(i), bool)
    for start in range(0, len(i), _CHUNK):
        sl = slice(start, start + _CHUNK)
        hit[sl] = _pair_hits(x, exact, t, flat, i[sl], j[sl])
    pairs = np.sort(np.stack([keep[i[hit]], keep[j[hit]]], axis=1), axis=1)
    pairs = pairs[np.lexsort(pairs.T[::-1])]
    chi = topo["vertex_count"] - topo["edge_count"] + len(t)
    # Zero-area: every repeated-index triangle plus the exactly collinear ones.
    degenerate = np.sort(np.concatenate([np.flatnonzero(repeated), keep[flat]]))
    centre = x[np.unique(t)].mean(axis=0) if len(t) else np.zeros(3)
    a, b, c = corners[:, 0] - centre, corners[:, 1] - centre, corners[:, 2] - centre
    duplicates = keep[_duplicates(t)].reshape(-1, 2)
    closed_manifold = (
        len(t) > 0
        and not len(topo["boundary_edges"])
        and not len(topo["non_manifold_edges"])
        and not len(topo["misoriented_edges"])
        and not len(topo["non_manifold_vertices"])
        and not len(duplicates)
    )
    return MeshReport(
        vertex_count=topo["vertex_count"],
        triangle_count=len(t_all),
        edge_count=topo["edge_count"],
        boundary_edges=topo["boundary_edges"],
        non_manifold_edges=topo["non_manifold_edges"],
        misoriented_edges=topo["misoriented_edges"],
        non_manifold_vertices=topo["non_manifold_vertices"],
        degenerate_triangles=degenerate.astype(np.int64),
        duplicate_triangles=duplicates,
        intersecting_pairs=_ids(pairs),
        component_count=topo["component_count"],
        euler_characteristic=int(chi),
        genus=int(topo["component_count"] - chi // 2) if closed_manifold else None,
        volume=float(_dot(a, np.cross(b, c)).sum() / 6.0),
        area=float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum() / 2.0),
    )
