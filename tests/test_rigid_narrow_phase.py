"""The exact narrow phase of rigid contacts (bodies/rigid/gjk.py, sat.py) against an independent
reference, python-fcl (the Flexible Collision Library), on 10^4 random pose pairs of every pair of shape
kinds, and the separating-axis test's Gauss-map pruning against the unpruned brute force over all edge
pairs, and a segment's depth in a polytope against every direction (the contacts these give in scenes:
test_rigid_contact_scenes.py)."""

import fcl
import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim.bodies.rigid.gjk import gjk
from taichi_anim.bodies.rigid.sat import box_edges, face_axes, hull_edges, polytope_axis, segment_axis
from taichi_anim.rotations import quat_to_matrix
from taichi_anim.runtime import compile_with

RNG_SEED = 20261129
PAIRS = 10_000
# Pairs closer than this to touching [m] are not counted as mismatches: both libraries stop their
# iterations at a relative tolerance (GJK's here, 1e-9 of the squared distance; fcl's at its own).
TOUCH_BAND = 1e-6

SHAPES = {
    "box": ta.shapes.Box((0.5, 0.3, 0.2)),
    "hull": ta.shapes.ConvexHull(np.random.default_rng(7).normal(size=(24, 3)) * [0.5, 0.4, 0.3]),
    "sphere": ta.shapes.Sphere(0.35),
    "capsule": ta.shapes.Capsule(0.2, 0.4),
    "cube": ta.shapes.Box((0.3, 0.3, 0.3)),
    "hull2": ta.shapes.ConvexHull(np.random.default_rng(8).normal(size=(12, 3)) * 0.4),
}
NAMES = list(SHAPES)


def build_model():
    b = ta.Builder()
    for i, shape in enumerate(SHAPES.values()):
        b.add_rigid_body(shape, position=(4.0 * i, 0.0, 0.0))
    return b.finalize()


# compiled as the step's kernel is (bodies/rigid/dynamics.py): with Taichi's default passes, seconds longer
@compile_with(cfg_optimization=False, advanced_optimization=False)
@ti.kernel
def _query(
    model: ti.template(),
    ia: ti.types.ndarray(),
    ib: ti.types.ndarray(),
    xa: ti.types.ndarray(),
    ra: ti.types.ndarray(),
    xb: ti.types.ndarray(),
    rb: ti.types.ndarray(),
    out: ti.types.ndarray(),
):
    """Per pair: GJK's distance between the shapes (cores' distance less the radii), the separating-axis
    value and its face-only part (polytope pairs), the GJK closest points, and the best edge-edge axis's
    separation."""
    for t in range(ia.shape[0]):
        a, b = ia[t], ib[t]
        pos_a = ti.Vector([xa[t, 0], xa[t, 1], xa[t, 2]], float)
        pos_b = ti.Vector([xb[t, 0], xb[t, 1], xb[t, 2]], float)
        rot_a = ti.Matrix([[ra[t, i, j] for j in range(3)] for i in range(3)], float)
        rot_b = ti.Matrix([[rb[t, i, j] for j in range(3)] for i in range(3)], float)
        dist, pa, pb = gjk(model, a, pos_a, rot_a, b, pos_b, rot_b)
        out[t, 0] = dist - model.geom_radius[a] - model.geom_radius[b]
        out[t, 1] = 0.0
        out[t, 2] = 0.0
        if model.geom_round[a] == 0:
            if model.geom_round[b] == 0:
                normal, s, edge, _p = polytope_axis(model, a, pos_a, rot_a, b, pos_b, rot_b)
                face_s, _n = face_axes(model, a, pos_a, rot_a, b, pos_b, rot_b)
                edge_s = hull_edges(model, a, pos_a, rot_a, b, pos_b, rot_b)[0]
                if model.geom_box[a] and model.geom_box[b]:
                    edge_s = box_edges(model, a, pos_a, rot_a, b, pos_b, rot_b)[0]
                out[t, 1] = s
                out[t, 2] = face_s
                out[t, 9] = edge_s
        for k in ti.static(range(3)):
            out[t, 3 + k] = pa[k]
            out[t, 6 + k] = pb[k]


def random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.array([quat_to_matrix(x) for x in q])


def principal_vertices(model, i):
    """Body i's shape as (vertices in its principal frame, triangles)."""
    v, f = model.rigid_shapes[i].triangles()
    axes = quat_to_matrix(model.rigid_principal[i])
    return (np.asarray(v) - model.rigid_com[i]) @ axes, np.asarray(f)


def fcl_object(model, i, x, r):
    """Body i at com x, principal rotation r, as fcl sees it: its own box, sphere and capsule primitives,
    a hull as fcl's Convex."""
    kind = model.rigid_shapes[i].kind
    if kind == "box":
        half = model.geom_half.to_numpy()[i]
        return fcl.CollisionObject(fcl.Box(*(2 * half)), fcl.Transform(r, x))
    if kind == "sphere":
        return fcl.CollisionObject(fcl.Sphere(model.rigid_shapes[i].radius), fcl.Transform(r, x))
    if kind == "capsule":
        shape = model.rigid_shapes[i]
        s0, s1 = model.geom_seg0.to_numpy()[i], model.geom_seg1.to_numpy()[i]
        axis = (s1 - s0) / np.linalg.norm(s1 - s0)  # in the principal frame; fcl's capsule runs along z
        turn = np.column_stack([*_complete(axis), axis])
        center = x + r @ (0.5 * (s0 + s1))
        return fcl.CollisionObject(
            fcl.Capsule(shape.radius, 2 * shape.half_length), fcl.Transform(r @ turn, center)
        )
    v, f = principal_vertices(model, i)
    faces = np.column_stack([np.full(len(f), 3), f]).ravel()
    return fcl.CollisionObject(fcl.Convex(v @ r.T + x, len(f), faces), fcl.Transform())


def _complete(axis):
    """Two unit vectors completing `axis` to a right-handed orthonormal basis."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, axis)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def fcl_query(oa, ob):
    """(whether the two meet, their distance when they do not, else 0)."""
    result = fcl.CollisionResult()
    met = fcl.collide(oa, ob, fcl.CollisionRequest(), result) > 0
    if met:
        return True, 0.0
    d = fcl.DistanceResult()
    return False, fcl.distance(oa, ob, fcl.DistanceRequest(), d)


@pytest.fixture(scope="module")
def random_pairs():
    """The random pairs, our answers and fcl's, as NumPy arrays (each test starts a fresh Taichi
    runtime: no field outlives this fixture)."""
    ta.init("cpu", precision="f64")
    model = build_model()
    rng = np.random.default_rng(RNG_SEED)
    kinds = [(a, b) for a in range(len(NAMES)) for b in range(a, len(NAMES))]
    pick = rng.integers(len(kinds), size=PAIRS)
    ia = np.array([kinds[k][0] for k in pick], dtype=np.int32)
    ib = np.array([kinds[k][1] for k in pick], dtype=np.int32)
    xa = rng.uniform(-0.1, 0.1, size=(PAIRS, 3))
    xb = xa + rng.uniform(-1.0, 1.0, size=(PAIRS, 3))  # about half of the pairs meet
    ra, rb = random_rotations(rng, PAIRS), random_rotations(rng, PAIRS)
    out = np.zeros((PAIRS, 10))
    _query(model, ia, ib, xa, ra, xb, rb, out)
    ref = np.array([fcl_query(fcl_object(model, a, x, r), fcl_object(model, b, y, s))
                    for a, b, x, r, y, s in zip(ia, ib, xa, ra, xb, rb, strict=True)])  # fmt: skip
    geometry = dict(
        round=model.geom_round.to_numpy()[: len(NAMES)] != 0,
        radius=model.geom_radius.to_numpy()[: len(NAMES)],
        segment=np.stack([model.geom_seg0.to_numpy(), model.geom_seg1.to_numpy()], axis=1)[: len(NAMES)],
        principal=[principal_vertices(model, i) for i in range(len(NAMES))],
    )
    met = ref[:, 0].astype(bool)
    return dict(ia=ia, ib=ib, xa=xa, ra=ra, xb=xb, rb=rb, out=out, met=met, dist=ref[:, 1], **geometry)


def test_gjk_and_the_separating_axes_agree_with_fcl_on_which_pairs_meet(random_pairs):
    p = random_pairs
    met = p["met"]
    assert 0.3 < met.mean() < 0.7  # both outcomes well represented
    gap, sat = p["out"][:, 0], p["out"][:, 1]
    poly = polytope_pairs(p)
    # GJK's distance is 0 where two polytopes meet (how deep, the separating axes say)
    depth = np.where(poly & (gap == 0.0), sat, gap)
    near = np.abs(depth) <= TOUCH_BAND
    assert near.sum() < 0.01 * PAIRS
    mismatched = np.flatnonzero(((gap <= 0.0) != met) & ~near)
    assert mismatched.size == 0, [(NAMES[p["ia"][k]], NAMES[p["ib"][k]], depth[k]) for k in mismatched[:5]]
    # the separating-axis test of two polytopes (boxes, hulls) says the same
    assert poly.sum() > 0.3 * PAIRS
    assert np.count_nonzero(poly & ~near & ((sat <= 0.0) != met)) == 0


def polytope_pairs(p):
    """Which pairs are of two polytopes (boxes, hulls)."""
    return ~p["round"][p["ia"]] & ~p["round"][p["ib"]]


def point_mesh_distance(q, v, f):
    """The exact distance from point q to a closed triangle mesh's surface (the smallest over its
    triangles: the projection onto the plane where it falls inside, else the nearest edge)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    h = np.einsum("ij,ij->i", q - a, n)
    foot = q - h[:, None] * n
    inside = np.ones(len(f), dtype=bool)
    for p0, p1 in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(p1 - p0, foot - p0), n) >= 0.0
    best = np.where(inside, np.abs(h), np.inf)
    for p0, p1 in ((a, b), (b, c), (c, a)):
        d = p1 - p0
        t = np.clip(np.einsum("ij,ij->i", q - p0, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(q - (p0 + t[:, None] * d), axis=1))
    return best.min()


def round_to_polytope(p, k):
    """The exact distance between pair k's round shape (a ball about a point or a segment) and its
    polytope: the distance to the polytope's surface is convex along the core segment, so a
    golden-section search over the segment finds its minimum."""
    a, b = p["ia"][k], p["ib"][k]
    if p["round"][a]:
        rnd, x, r, poly, y, s = a, p["xa"][k], p["ra"][k], b, p["xb"][k], p["rb"][k]
    else:
        rnd, x, r, poly, y, s = b, p["xb"][k], p["rb"][k], a, p["xa"][k], p["ra"][k]
    v, f = p["principal"][poly]
    world = v @ s.T + y
    s0, s1 = (x + r @ e for e in p["segment"][rnd])
    dist = lambda t: point_mesh_distance(s0 + t * (s1 - s0), world, f)
    lo, hi = 0.0, 1.0
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        m1, m2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        if dist(m1) < dist(m2):
            hi = m2
        else:
            lo = m1
    return min(dist(0.0), dist(1.0), dist(0.5 * (lo + hi))) - p["radius"][rnd]


def test_gjk_distances_and_closest_points_match_fcl_and_an_exact_reference(random_pairs):
    p = random_pairs
    apart = ~p["met"] & (p["out"][:, 0] > TOUCH_BAND)
    assert apart.sum() > 0.3 * PAIRS
    ours = p["out"][:, 0]
    # the closest points on the cores are as far apart as the cores are (a witness pair, not a guess)
    radii = p["radius"][p["ia"]] + p["radius"][p["ib"]]
    gap = np.linalg.norm(p["out"][:, 3:6] - p["out"][:, 6:9], axis=1) - radii
    np.testing.assert_allclose(gap[apart], ours[apart], atol=1e-9)
    # Two polytopes, or two round shapes: fcl's distances, to its own GJK's tolerance.
    mixed = p["round"][p["ia"]] != p["round"][p["ib"]]
    np.testing.assert_allclose(ours[apart & ~mixed], p["dist"][apart & ~mixed], rtol=2e-6, atol=2e-6)
    # A sphere or capsule against a polytope: fcl (through libccd) answers up to 0.5 mm too far here, so
    # the reference is exact (round_to_polytope); fcl's answer is never below it.
    for k in np.flatnonzero(apart & mixed)[:300]:
        exact = round_to_polytope(p, k)
        assert ours[k] == pytest.approx(exact, abs=1e-9)
        assert p["dist"][k] >= exact - 2e-6


def brute_force_separation(p, a, xa, ra, b, xb, rb):
    """The largest separation of a beyond b over every triangle normal of both and the cross product of
    every pair of their triangles' edges (a superset of the separating-axis theorem's candidates, no
    pruning)."""
    va, fa = p["principal"][a]
    vb, fb = p["principal"][b]
    wa, wb = va @ ra.T + xa, vb @ rb.T + xb

    def normals(w, f):
        n = np.cross(w[f[:, 1]] - w[f[:, 0]], w[f[:, 2]] - w[f[:, 0]])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def edges(w, f):
        e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
        return w[e[:, 1]] - w[e[:, 0]]

    axes = [normals(wa, fa), normals(wb, fb)]
    cross = np.cross(edges(wa, fa)[:, None, :], edges(wb, fb)[None, :, :]).reshape(-1, 3)
    length = np.linalg.norm(cross, axis=1)
    axes.append(cross[length > 1e-9] / length[length > 1e-9, None])
    u = np.concatenate(axes)
    # separation along u and -u: b's extent against a's
    s_plus = (wa @ u.T).min(axis=0) - (wb @ u.T).max(axis=0)
    s_minus = (wb @ u.T).min(axis=0) - (wa @ u.T).max(axis=0)
    return max(s_plus.max(), s_minus.max())


def test_the_gauss_map_pruned_separating_axes_give_the_brute_force_depth(random_pairs):
    # Where two polytopes overlap, the largest separation over all candidate axes is minus their
    # penetration depth, reached at a face of their Minkowski difference: the pruned search must find it.
    p = random_pairs
    overlapping = np.flatnonzero(polytope_pairs(p) & p["met"])
    assert overlapping.size > 400
    for k in overlapping[:400]:
        a, b = p["ia"][k], p["ib"][k]
        brute = brute_force_separation(p, a, p["xa"][k], p["ra"][k], b, p["xb"][k], p["rb"][k])
        face, edge, chosen = p["out"][k, 2], p["out"][k, 9], p["out"][k, 1]
        assert max(face, edge) == pytest.approx(brute, abs=1e-9), (NAMES[a], NAMES[b])
        # an edge axis is chosen only when clearly better (sat.EDGE_BIAS)
        assert brute - 1e-3 - 1e-9 <= chosen <= brute + 1e-9


@compile_with(cfg_optimization=False, advanced_optimization=False)
@ti.kernel
def _segment_depth(
    model: ti.template(),
    g: ti.i32,
    x: ti.types.ndarray(),
    r: ti.types.ndarray(),
    s: ti.types.ndarray(),
    out: ti.types.ndarray(),
):
    """Per row: segment_axis of the segment s[t, 0] s[t, 1] against geom g at x[t], r[t]: depth, axis."""
    for t in range(x.shape[0]):
        pos = ti.Vector([x[t, 0], x[t, 1], x[t, 2]], float)
        rot = ti.Matrix([[r[t, i, j] for j in range(3)] for i in range(3)], float)
        s0 = ti.Vector([s[t, 0, 0], s[t, 0, 1], s[t, 0, 2]], float)
        s1 = ti.Vector([s[t, 1, 0], s[t, 1, 1], s[t, 1, 2]], float)
        depth, axis = segment_axis(model, s0, s1, g, pos, rot)
        out[t, 0] = depth
        for k in ti.static(range(3)):
            out[t, 1 + k] = axis[k]


def fibonacci_sphere(n):
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    rho = np.sqrt(1.0 - z * z)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


@pytest.mark.parametrize("name", ["box", "hull"])
def test_a_segments_depth_in_a_polytope_is_the_least_over_every_direction(name):
    # A capsule's core through a polytope, both ends outside (EPA's case): segment_axis's depth is the
    # least translation out, h(u) - min(u . s0, u . s1), over g's face normals and its edges' cross
    # products with the segment. Brute force over 20,000 directions (and the axes found, recomputed in
    # NumPy) on 200 random segments through the shape: no direction needs less.
    model = build_model()
    g = NAMES.index(name)
    vertices, _ = principal_vertices(model, g)
    rng = np.random.default_rng(RNG_SEED)
    n = 200
    x = rng.normal(size=(n, 3))
    r = random_rotations(rng, n)
    # a point strictly inside, per row: halfway from the vertices' centroid to the mean of four of them
    inside = 0.5 * (vertices.mean(axis=0) + vertices[rng.integers(len(vertices), size=(n, 4))].mean(axis=1))
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    mid = x + np.einsum("nij,nj->ni", r, inside)
    s = np.stack([mid - 1.5 * direction, mid + 1.5 * direction], axis=1)  # 3 m: longer than the shape
    out = np.zeros((n, 4))
    _segment_depth(model, g, x, r, s, out)
    world = np.einsum("nij,vj->nvi", r, vertices) + x[:, None]  # (n, V, 3)

    def depth(u):  # (n, D, 3) directions -> (n, D) depths
        h = np.einsum("nvi,ndi->ndv", world, u).max(axis=2)
        return h - np.minimum(np.einsum("ni,ndi->nd", s[:, 0], u), np.einsum("ni,ndi->nd", s[:, 1], u))

    ours, axis = out[:, 0], out[:, 1:]
    np.testing.assert_allclose(np.linalg.norm(axis, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(depth(axis[:, None])[:, 0], ours, atol=1e-12)  # the depth along its axis
    chunks = np.split(fibonacci_sphere(20_000), 10)
    sampled = np.concatenate([depth(np.broadcast_to(u, (n, *u.shape))) for u in chunks], axis=1)
    assert (ours > 0.0).all()
    assert (ours <= sampled.min(axis=1) + 1e-12).all()
