"""mesh_report: closed / manifold / oriented / self-intersection checks and the divergence-theorem volume,
against closed forms (tetrahedron, box, sphere, torus genus), hand-built defects (open grid, flipped face,
bow-tie vertex, fin, duplicate and degenerate triangles, fold-over), brute force over all pairs, an
independent rational-arithmetic reference, and a blob mesh on which Open3D raises a false alarm."""

import itertools
from fractions import Fraction

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.errors import ParameterError
from taichi_anim.spatial import mesh_report, triangle_pairs_intersect

# ------------------------------------------------------------------------------------------ meshes


def tetrahedron(a=(0.0, 0.0, 0.0), scale=(1.0, 2.0, 3.0)):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * scale + a
    return v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def box(lo=(0.0, 0.0, 0.0), size=(1.0, 1.0, 1.0)):
    """8 corners, 12 outward triangles."""
    v = np.array(list(itertools.product((0, 1), repeat=3)), float) * size + lo  # index = 4x + 2y + z
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return v, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])


def uv_sphere(radius, n_lat=24, n_lon=48):
    theta = np.pi * np.arange(1, n_lat) / n_lat
    phi = 2 * np.pi * np.arange(n_lon) / n_lon
    ring = np.stack(
        [
            np.outer(np.sin(theta), np.cos(phi)),
            np.outer(np.sin(theta), np.sin(phi)),
            np.outer(np.cos(theta), np.ones_like(phi)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    v = radius * np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    south = len(v) - 1
    idx = lambda i, j: 1 + i * n_lon + j % n_lon  # noqa: E731
    f = [(0, idx(0, j), idx(0, j + 1)) for j in range(n_lon)]
    for i in range(n_lat - 2):
        for j in range(n_lon):
            f += [
                (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)),
                (idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)),
            ]
    f += [(south, idx(n_lat - 2, j + 1), idx(n_lat - 2, j)) for j in range(n_lon)]
    return v, np.array(f)


def torus(big=1.0, small=0.3, n=24, m=12):
    u, w = np.meshgrid(2 * np.pi * np.arange(n) / n, 2 * np.pi * np.arange(m) / m, indexing="ij")
    r = big + small * np.cos(w)
    v = np.stack([r * np.cos(u), r * np.sin(u), small * np.sin(w)], axis=-1).reshape(-1, 3)
    k = lambda i, j: (i % n) * m + j % m  # noqa: E731
    f = [
        t
        for i in range(n)
        for j in range(m)
        for t in ((k(i, j), k(i + 1, j), k(i + 1, j + 1)), (k(i, j), k(i + 1, j + 1), k(i, j + 1)))
    ]
    return v, np.array(f)


def grid(n):
    """A flat open n x n grid of vertices in z = 0, two triangles per cell."""
    v = np.array([(i, j, 0.0) for i in range(n) for j in range(n)])
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f += [(a, b, c), (a, c, d)]
    return v, np.array(f)


def merged(*meshes):
    vs, fs, offset = [], [], 0
    for v, f in meshes:
        vs.append(v)
        fs.append(f + offset)
        offset += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def all_pairs(n):
    i, j = np.triu_indices(n, 1)
    return np.stack([i, j], axis=1)


def brute_force_pairs(v, f):
    pairs = all_pairs(len(f))
    return pairs[triangle_pairs_intersect(v, f, pairs)]


# ------------------------------------------------ an independent reference in rational arithmetic


def _q(p):
    return [Fraction(float(c)) for c in p]


def _orient3d(a, b, c, d):
    m = [[q[i] - a[i] for i in range(3)] for q in (b, c, d)]
    return (
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    )


def _orient2d(a, b, c):
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _in_triangle_2d(p, a, b, c):
    s = [_orient2d(a, b, p), _orient2d(b, c, p), _orient2d(c, a, p)]
    return all(x >= 0 for x in s) or all(x <= 0 for x in s)


def _segments_2d(p, q, a, b):
    d = [_orient2d(p, q, a), _orient2d(p, q, b), _orient2d(a, b, p), _orient2d(a, b, q)]
    if d[0] * d[1] < 0 and d[2] * d[3] < 0:
        return True
    within = lambda u, w, r: all(min(u[i], w[i]) <= r[i] <= max(u[i], w[i]) for i in range(2))  # noqa: E731
    return any(d[k] == 0 and within(*s) for k, s in enumerate([(p, q, a), (p, q, b), (a, b, p), (a, b, q)]))


def segment_meets_triangle(p, q, a, b, c):
    """Closed segment pq meets the closed non-degenerate triangle abc, with Fractions; the crossing
    point is formed explicitly (the library never forms it)."""
    s1, s2 = _orient3d(a, b, c, p), _orient3d(a, b, c, q)
    if s1 * s2 > 0:
        return False
    n = [
        (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1]),
        (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2]),
        (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]),
    ]
    k = max(range(3), key=lambda i: abs(n[i]))
    drop = lambda r: [r[i] for i in range(3) if i != k]  # noqa: E731
    a2, b2, c2 = drop(a), drop(b), drop(c)
    if s1 == s2 == 0:
        if _in_triangle_2d(drop(p), a2, b2, c2) or _in_triangle_2d(drop(q), a2, b2, c2):
            return True
        return any(_segments_2d(drop(p), drop(q), e0, e1) for e0, e1 in ((a2, b2), (b2, c2), (c2, a2)))
    x = [(s2 * p[i] - s1 * q[i]) / (s2 - s1) for i in range(3)]
    return _in_triangle_2d(drop(x), a2, b2, c2)


def triangles_meet_reference(t1, t2):
    """Closed non-degenerate triangles (3 points each) meet: an edge of one meets the other."""
    t1, t2 = [_q(p) for p in t1], [_q(p) for p in t2]
    return any(
        segment_meets_triangle(u[i], u[(i + 1) % 3], *w) for u, w in ((t1, t2), (t2, t1)) for i in range(3)
    )


# ------------------------------------------------------------------------ valid closed meshes


def test_tetrahedron_and_box_are_closed_manifolds_with_the_exact_volume():
    v, f = tetrahedron(a=(0.25, -1.0, 3.0), scale=(0.5, 2.0, 3.0))
    r = mesh_report(v, f)
    assert r.ok and r.closed and r.edge_manifold and r.vertex_manifold and r.oriented
    assert (r.vertex_count, r.edge_count, r.triangle_count, r.euler_characteristic, r.genus) == (
        4,
        6,
        4,
        2,
        0,
    )
    assert r.volume == pytest.approx(0.5 * 2 * 3 / 6, rel=1e-14)  # |det[u, v, w]| / 6
    v, f = box(lo=(-0.5, 1.0, 2.0), size=(0.2, 0.3, 0.5))
    r = mesh_report(v, f)
    assert r.ok and r.genus == 0 and r.component_count == 1 and not r.self_intersecting
    assert r.volume == pytest.approx(0.2 * 0.3 * 0.5, rel=1e-14)
    assert r.area == pytest.approx(2 * (0.2 * 0.3 + 0.3 * 0.5 + 0.2 * 0.5), rel=1e-14)
    assert mesh_report(v, f[:, ::-1]).volume == pytest.approx(-0.03, rel=1e-14)  # inward: negative
    assert "ok: closed manifold" in r.describe()


def test_uv_sphere_and_torus():
    radius = 0.1
    v, f = uv_sphere(radius)
    r = mesh_report(v, f)
    assert r.ok and r.genus == 0 and r.euler_characteristic == 2
    # Inscribed polyhedron: a little below 4/3 pi R^3 (sagitta of a 7.5 degree cell: ~0.9% per axis).
    assert -0.02 < r.volume / (4 / 3 * np.pi * radius**3) - 1 < 0
    r = mesh_report(*torus())
    assert r.ok and r.genus == 1 and r.euler_characteristic == 0
    two = mesh_report(*merged(torus(), box(lo=(3.0, 0.0, 0.0))))
    assert two.ok and two.component_count == 2 and two.genus == 1 and two.euler_characteristic == 2


def _blob_mesh(seed, resolution, *, sigma=0.04, method="open3d"):
    bf = ta.BlobField(capacity=8, sigma=sigma, bounds=((-0.2,) * 3, (0.2,) * 3), resolution=resolution)
    bf.evaluate(np.random.default_rng(seed).normal(0.0, 0.05, (8, 3)))
    mesh = bf.isosurface(0.3, method=method)
    return mesh.vertices, mesh.triangles


def test_blob_isosurface_is_a_closed_manifold_with_the_sphere_volume():
    sigma, iso = 0.05, 0.5
    bf = ta.BlobField(capacity=1, sigma=sigma, bounds=((-0.1,) * 3, (0.1,) * 3), resolution=32)
    bf.evaluate(np.array([[0.003, -0.002, 0.001]]))
    mesh = bf.isosurface(iso)
    r = mesh_report(mesh.vertices, mesh.triangles)
    assert r.ok and r.genus == 0
    radius = sigma * np.sqrt(np.log(1 / iso))  # one blob: exp(-r^2 / sigma^2) = iso
    # Marching cubes inscribes the sphere; a spacing of h = 6.25 mm at R = 42 mm loses about 2%.
    assert -0.04 < r.volume / (4 / 3 * np.pi * radius**3) - 1 < 0


# ----------------------------------------------------------------------------------------- defects


def test_open_grid_reports_exactly_its_perimeter_as_boundary():
    n = 6
    v, f = grid(n)
    r = mesh_report(v, f)
    assert not r.closed and r.edge_manifold and r.vertex_manifold and r.oriented and not r.ok
    assert not r.self_intersecting  # 50 coplanar triangles: adjacent ones meet only on shared features
    # Brute force: unit steps along one of the four lines x = 0, x = n - 1, y = 0, y = n - 1.
    rim = {
        (a, b)
        for a, b in itertools.combinations(range(len(v)), 2)
        if np.abs(v[a] - v[b]).sum() == 1
        and any(v[a, k] == v[b, k] and v[a, k] in (0, n - 1) for k in (0, 1))
    }
    assert {tuple(e) for e in r.boundary_edges.tolist()} == rim and len(rim) == 4 * (n - 1)
    assert r.euler_characteristic == 1 and r.genus is None


def test_a_flipped_face_is_reported_as_misoriented_on_its_three_edges():
    v, f = box()
    f = f.copy()
    f[5] = f[5, ::-1]
    r = mesh_report(v, f)
    assert r.closed and r.edge_manifold and not r.oriented and not r.ok and r.genus is None
    assert {tuple(e) for e in r.misoriented_edges.tolist()} == {
        tuple(sorted(e)) for e in itertools.combinations(f[5], 2)
    }


def _cone(apex, direction, k=8):
    """A closed cone: apex, a ring of k at apex + direction, the ring's centre; outward triangles."""
    phi = 2 * np.pi * np.arange(k) / k
    ring = np.stack([np.cos(phi), np.sin(phi), np.full(k, direction)], axis=1) + apex
    v = np.concatenate([[apex], ring, [np.add(apex, (0, 0, direction))]])
    side = [(0, 1 + (j + 1) % k, 1 + j) for j in range(k)]
    cap = [(k + 1, 1 + j, 1 + (j + 1) % k) for j in range(k)]
    f = np.array(side + cap)
    return v, f if direction > 0 else f[:, ::-1]


def test_bow_tie_vertex_of_two_cones_is_not_manifold_and_not_an_intersection():
    v1, f1 = _cone((0.0, 0.0, 0.0), 1.0)
    v2, f2 = _cone((0.0, 0.0, 0.0), -1.0)
    v = np.concatenate([v1, v2[1:]])  # one apex, shared
    f2 = np.where(f2 == 0, 0, f2 + len(v1) - 1)
    r = mesh_report(v, np.concatenate([f1, f2]))
    assert r.closed and r.edge_manifold and r.oriented
    assert r.non_manifold_vertices.tolist() == [0] and not r.vertex_manifold and not r.ok
    assert not r.self_intersecting  # the two cones meet only at the shared apex
    cone_volume = 8 / 2 * np.sin(2 * np.pi / 8) / 3  # base: a regular octagon of circumradius 1; h = 1
    assert r.volume == pytest.approx(2 * cone_volume, rel=1e-12)


def test_fin_of_three_triangles_on_one_edge_is_not_manifold():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0.5], [0.3, 0.2, 1]])
    r = mesh_report(v, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    assert r.non_manifold_edges.tolist() == [[0, 1]] and not r.edge_manifold and not r.closed
    assert set(r.non_manifold_vertices.tolist()) == {0, 1}
    assert len(r.boundary_edges) == 6 and not r.ok


def test_duplicate_and_degenerate_triangles_are_reported():
    v, f = box()
    v = np.concatenate([v, [[0.5, 0.5, 0.5], [0.25, 0.25, 0.25], [2, 2, 2]]])  # collinear with vertex 0
    f = np.concatenate([f, [f[3], [0, 8, 9], [0, 0, 10]]])
    r = mesh_report(v, f)
    assert r.duplicate_triangles.tolist() == [[3, 12]]
    assert r.degenerate_triangles.tolist() == [13, 14]
    assert not r.closed and not r.ok
    assert "duplicate_triangles: 1 ([3, 12])" in r.describe()


# --------------------------------------------------------------------------------- intersections


@pytest.mark.parametrize("offset", [(1.0, 1.0, 0.0), (1.0, 0.5, 0.25)])  # coplanar faces, general
def test_overlapping_cubes_report_every_intersecting_pair(offset):
    v, f = merged(box(size=(2, 2, 2)), box(lo=offset, size=(2, 2, 2)))
    r = mesh_report(v, f)
    assert r.closed and r.oriented and r.self_intersecting and not r.ok
    np.testing.assert_array_equal(r.intersecting_pairs, brute_force_pairs(v, f))
    # Rational reference for the pairs across the two cubes (no shared vertex).
    expected = [
        (i, j) for i in range(12) for j in range(12, 24) if triangles_meet_reference(v[f[i]], v[f[j]])
    ]
    assert [tuple(p) for p in r.intersecting_pairs.tolist()] == expected and len(expected) > 4


def test_report_on_a_random_soup_equals_brute_force_over_all_pairs():
    """Triangles on a few integer points: shared vertices, shared edges, coplanar and degenerate pairs
    of every kind; the grid broad phase must lose none of them."""
    rng = np.random.default_rng(2)
    v = rng.integers(0, 4, (40, 3)).astype(float) * 0.25
    f = np.array([rng.choice(40, 3, replace=False) for _ in range(250)])
    r = mesh_report(v, f)
    expected = brute_force_pairs(v, f)
    np.testing.assert_array_equal(r.intersecting_pairs, expected)
    shared = (f[expected[:, 0]][:, :, None] == f[expected[:, 1]][:, None, :]).sum(axis=(1, 2))
    assert set(np.unique(shared)) == {0, 1, 2}  # crossings, vertex-sharing crossings and fold-overs


def test_adjacent_pairs_meet_only_through_a_fold_or_a_crossing_away_from_the_shared_vertex():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [1, 1, 0], [1, -1, 0], [1, 1, 2.0**-60], [1, 1, 1e-300]])
    f = np.array([[0, 1, 2], [1, 0, 3], [1, 0, 4], [1, 0, 5], [1, 0, 6]])
    # (0, 1): coplanar, same side of the shared edge: a fold-over. (0, 2): the other side. (0, 3), (0, 4):
    # lifted by 2^-60 and 1e-300 out of the plane: they meet only on the shared edge, exactly.
    hits = triangle_pairs_intersect(v, f, [[0, 1], [0, 2], [0, 3], [0, 4]])
    assert hits.tolist() == [True, False, False, False]
    # One shared vertex (0): a crossing away from it, a touch at it only, a coplanar overlap, a coplanar
    # common segment along an edge, coplanar and apart.
    v = np.array(
        [[0, 0, 0], [4, 0, 0], [0, 4, 0], [1, 1, -1], [1, 1, 1], [1, 1, 1], [-1, 2, 1], [1, 1, 0], [3, 0, 0]]
        + [[2, 0, 0], [1, -1, 0], [-1, 0, 0], [0, -1, 0]],
        float,
    )
    f = np.array([[0, 1, 2], [0, 3, 4], [0, 5, 6], [0, 7, 8], [0, 9, 10], [0, 11, 12]])
    hits = triangle_pairs_intersect(v, f, [[0, k] for k in range(1, 6)])
    assert hits.tolist() == [True, False, True, True, False]
    r = mesh_report(v, f)  # (other pairs meet too: vertices 4 and 5 coincide, (1, 1, 0) lies on 3-4)
    np.testing.assert_array_equal(r.intersecting_pairs, brute_force_pairs(v, f))
    found = {tuple(p) for p in r.intersecting_pairs.tolist()}
    assert {(0, 1), (0, 3), (0, 4)} <= found and not {(0, 2), (0, 5)} & found


def test_exact_decisions_agree_with_rational_arithmetic_on_near_degenerate_pairs():
    """Triangles touching another's plane at float-rounded points (on, just above or just below it in
    exact arithmetic), and coplanar pairs with float coordinates: every decision is the rational one."""
    rng = np.random.default_rng(0)
    t1, t2 = [], []
    for k in range(300):
        a = rng.uniform(-1, 1, (3, 3)) * 10.0 ** rng.integers(-3, 3)
        w = rng.dirichlet((1, 1, 1)) * rng.choice([1.0, 1.02, 0.98])  # inside, or just past an edge
        p = w @ a  # rounded: on, above or below the plane of a, by a few ulps
        up = rng.normal(size=3)
        if k % 3 == 0:  # coplanar: the other corners in the plane too
            q, s = a[0] + 0.3 * (a[1] - a[0]) * 5, a[2] + 0.2 * (a[1] - a[2]) * 4
        else:
            q, s = p + up, p + up + rng.normal(size=3) * 0.5
        t1.append(a)
        t2.append([p, q, s])
    v = np.concatenate([np.concatenate(t1), np.concatenate(t2)]).reshape(-1, 3)
    m = len(t1)
    f = np.concatenate([np.arange(3 * m).reshape(m, 3), 3 * m + np.arange(3 * m).reshape(m, 3)])
    pairs = np.stack([np.arange(m), m + np.arange(m)], axis=1)
    got = triangle_pairs_intersect(v, f, pairs)
    expected = [triangles_meet_reference(v[f[i]], v[f[j]]) for i, j in pairs]
    assert got.tolist() == expected
    assert 0.2 < np.mean(expected) < 0.9  # both answers occur


# ---------------------------------------------------------------- Open3D's false alarm on a blob mesh


def test_blob_mesh_on_which_open3d_reports_false_self_intersections():
    o3d = pytest.importorskip("open3d")
    v, f = _blob_mesh(seed=4, resolution=12)  # 320 triangles, slivers around grid nodes
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
    flagged = np.asarray(mesh.get_self_intersecting_triangles())
    # Open3D 0.20: 4 pairs, so not watertight, and get_volume refuses.
    assert len(flagged) > 0 and not mesh.is_watertight()
    with pytest.raises(RuntimeError, match="not watertight"):
        mesh.get_volume()
    r = mesh_report(v, f)
    assert r.ok and not r.self_intersecting
    # Every pair, brute force, with the same exact predicate: none meets; Open3D's pairs by rational
    # arithmetic too (they share no vertex and lie about a micrometre apart).
    assert len(brute_force_pairs(v, f)) == 0
    assert not any(triangles_meet_reference(v[f[i]], v[f[j]]) for i, j in flagged)
    assert not (f[flagged[:, 0]][:, :, None] == f[flagged[:, 1]][:, None, :]).any()
    # The divergence-theorem volume Open3D refuses to give, against a direct sum.
    vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    assert r.volume == pytest.approx(vol, rel=1e-12) and r.volume > 0


# ------------------------------------------------------------------------------------------- input


def test_bad_input_raises_naming_the_parameter():
    v, f = tetrahedron()
    with pytest.raises(ParameterError, match="vertices"):
        mesh_report(np.full((4, 3), np.nan), f)
    with pytest.raises(ParameterError, match="vertices"):
        mesh_report(v[:, :2], f)
    with pytest.raises(ParameterError, match="triangles"):
        mesh_report(v, f[:, :2])
    with pytest.raises(ParameterError, match="triangles"):
        mesh_report(v, f + 1)
    with pytest.raises(ParameterError, match="triangles"):
        mesh_report(v, f.astype(float))
    with pytest.raises(ParameterError, match="pairs"):
        triangle_pairs_intersect(v, f, [[0, 4]])
    empty = mesh_report(v, np.zeros((0, 3), int))
    assert not empty.closed and not empty.ok and empty.triangle_count == 0
