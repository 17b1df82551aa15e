"""Continuous point–triangle and edge–edge tests (taichi_anim.spatial.ccd, Bridson et al. 2002 sec. 6.4).

Randomized sets (seeded, 3,000 motions of each kind, coordinates in [-1, 1] plus random motion, a tenth
shifted far into negative coordinates) are checked against a reference that samples the step at 4,000
times in NumPy: a crossing is a sign change of the signed volume f(t) between two samples (of its
polynomial form), refined by bisection on the triple product, at which the point's projection lies
inside the triangle (the two lines' intersection lies inside both edges). Required: NO false negatives
(every reference crossing is reported, no later than the reference's first crossing), and every
reported hit is a real near-contact (at tau, distance <= thickness and |f| near round-off).

False positives are near misses within the thickness (the point crosses the plane just outside the
triangle, or the edges pass within h of each other), which the thickness makes count by design. Measured
on these sets (f64): with thickness 1e-6, 0 false positives of 3,000 motions for point–triangle and 0
for edge–edge; with thickness 1e-2 (1% of the primitives' size), 16 of 3,000 point–triangle motions
(0.5%; 3.9% of the 409 reported hits) and 23 of 3,000 edge–edge motions (0.8%; 2.6% of 899 reported
hits). The bounds asserted below keep these figures honest.

Adversarial cases have hand-derived answers: crossing through a face, an edge, a vertex; near misses
inside and outside the thickness; motion within the plane; parallel motion just above it; parallel and
collinear edges; a vertex through an edge; zero motion; zero-area triangles and zero-length edges; far
coordinates; also in f32.
"""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim.spatial import NO_HIT, ccd_edge_edge, ccd_point_triangle
from taichi_anim.spatial.distance import point_triangle_distance_np, segment_segment_closest_np

SAMPLES = 4000
N_CASES = 3000


@ti.func
def _v(a: ti.template(), i, k: ti.template()):
    return ti.Vector([a[i, 3 * k], a[i, 3 * k + 1], a[i, 3 * k + 2]])


@ti.kernel
def _ccd_kernel(x: ti.types.ndarray(ndim=2), h: float, edge: ti.i32, out: ti.types.ndarray(ndim=1)):
    # x rows: 4 points at the start, then the same 4 at the end of the step.
    for i in range(x.shape[0]):
        if edge:
            out[i] = ccd_edge_edge(
                _v(x, i, 0),
                _v(x, i, 1),
                _v(x, i, 2),
                _v(x, i, 3),
                _v(x, i, 4),
                _v(x, i, 5),
                _v(x, i, 6),
                _v(x, i, 7),
                h,
            )
        else:
            out[i] = ccd_point_triangle(
                _v(x, i, 0),
                _v(x, i, 1),
                _v(x, i, 2),
                _v(x, i, 3),
                _v(x, i, 4),
                _v(x, i, 5),
                _v(x, i, 6),
                _v(x, i, 7),
                h,
            )


def _run(x, h, edge, dtype=np.float64):
    x = np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(len(x), 24), dtype=dtype)
    out = np.zeros(len(x), dtype=dtype)
    _ccd_kernel(x, h, int(edge), out)
    return out.astype(np.float64)


def _at(x, t):
    """The four points of each case (N, 8, 3) at times t (N,): (N, 4, 3)."""
    return x[:, :4] + t[:, None, None] * (x[:, 4:] - x[:, :4])


def _cubic_vectors(pts, edge):
    """(X, Y, Z) of the coplanarity cubic f = (X x Y) . Z for points (..., 4, 3)."""
    if edge:
        return (
            pts[..., 1, :] - pts[..., 0, :],
            pts[..., 3, :] - pts[..., 2, :],
            pts[..., 2, :] - pts[..., 0, :],
        )
    return pts[..., 2, :] - pts[..., 1, :], pts[..., 3, :] - pts[..., 1, :], pts[..., 0, :] - pts[..., 1, :]


def _f(pts, edge):
    X, Y, Z = _cubic_vectors(pts, edge)
    return (np.cross(X, Y) * Z).sum(-1)


def _inside(pts, edge):
    """At a coplanar configuration: the point's projection is in the triangle / the lines' intersection
    is in both edges (parallel edges: no)."""
    if edge:
        p, q, r, s = (pts[:, k] for k in range(4))
        d1, d2, w = q - p, s - r, r - p
        n = np.cross(d1, d2)
        nn = (n * n).sum(-1)
        ok = nn > 1e-20 * (d1 * d1).sum(-1) * (d2 * d2).sum(-1)
        safe = np.where(ok, nn, 1.0)
        u = (np.cross(w, d2) * n).sum(-1) / safe
        v = (np.cross(w, d1) * n).sum(-1) / safe
        return ok & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    p, a, b, c = (pts[:, k] for k in range(4))
    n = np.cross(b - a, c - a)
    w = [(np.cross(y - p, z - p) * n).sum(-1) for y, z in ((b, c), (c, a), (a, b))]
    return (w[0] >= 0) & (w[1] >= 0) & (w[2] >= 0) & ((n * n).sum(-1) > 0)


def _cubic_coefficients(x, edge):
    """a0..a3 of f(t) = a0 + a1 t + a2 t^2 + a3 t^3 per case: (N, 4)."""
    X0, Y0, Z0 = _cubic_vectors(x[:, :4], edge)
    X1, Y1, Z1 = _cubic_vectors(x[:, 4:], edge)
    dX, dY, dZ = X1 - X0, Y1 - Y0, Z1 - Z0
    c0, c1, c2 = np.cross(X0, Y0), np.cross(X0, dY) + np.cross(dX, Y0), np.cross(dX, dY)
    dot = lambda u, v: (u * v).sum(-1)  # noqa: E731
    return np.stack([dot(c0, Z0), dot(c0, dZ) + dot(c1, Z0), dot(c1, dZ) + dot(c2, Z0), dot(c2, dZ)], 1)


def _reference_first_crossing(x, edge):
    """First sampled crossing time (bisection-refined) with the contact inside, else inf: (N,)."""
    t = np.linspace(0.0, 1.0, SAMPLES + 1)
    first = np.full(len(x), np.inf)
    a = _cubic_coefficients(x, edge)
    for lo in range(0, len(x), 1000):
        ac, xc = a[lo : lo + 1000], x[lo : lo + 1000]
        f = ((ac[:, 3:] * t + ac[:, 2:3]) * t + ac[:, 1:2]) * t + ac[:, :1]  # (C, S+1)
        change = (np.sign(f[:, :-1]) * np.sign(f[:, 1:]) < 0) | ((f[:, 1:] == 0) & (f[:, :-1] != 0))
        ci, ki = np.nonzero(change)
        ta, tb = t[ki], t[ki + 1]
        fa = _f(_at(xc[ci], ta), edge)
        for _ in range(45):  # bisection on the triple product itself, to ~1e-17
            m = 0.5 * (ta + tb)
            fm = _f(_at(xc[ci], m), edge)
            left = np.sign(fm) != np.sign(fa)
            tb = np.where(left, m, tb)
            ta = np.where(left, ta, m)
            fa = np.where(left, fa, fm)
        tc = 0.5 * (ta + tb)
        ok = _inside(_at(xc[ci], tc), edge)
        np.minimum.at(first[lo : lo + 1000], ci[ok], tc[ok])
    return first


def _distance(x, tau, edge):
    pts = _at(x, np.minimum(tau, 1.0))
    if edge:
        p, q, r, s = (pts[:, k] for k in range(4))
        u, v = segment_segment_closest_np(p, q, r, s)
        return np.linalg.norm(p + u[:, None] * (q - p) - r - v[:, None] * (s - r), axis=1)
    return point_triangle_distance_np(*(pts[:, k] for k in range(4)))


def _random_motions(rng, edge):
    n = N_CASES
    x0 = rng.uniform(-1.0, 1.0, size=(n, 4, 3))
    x1 = x0 + rng.normal(scale=0.3, size=(n, 4, 3))
    # The point / second edge travels farther, through the other primitive's neighbourhood.
    target = x1[:, 1:].mean(1) if not edge else x1[:, :2].mean(1)
    mover = [0] if not edge else [2, 3]
    for k in mover:
        x1[:, k] = target + rng.normal(scale=0.6, size=(n, 3))
    x = np.concatenate([x0, x1], axis=1)
    x[: n // 10] -= np.array([300.0, 120.0, 45.0])  # far, negative coordinates
    return x


def _check_random(edge, seed):
    rng = np.random.default_rng(seed)
    x = _random_motions(rng, edge)
    ref = _reference_first_crossing(x, edge)
    ref_hit = np.isfinite(ref)
    assert 0.1 < ref_hit.mean() < 0.9
    scale = np.abs(x).max(axis=(1, 2))
    fps = {}
    for h in (1e-6, 1e-2):
        tau = _run(x, h, edge)
        hit = tau <= 1.0
        assert np.all((tau == NO_HIT) | ((tau >= 0.0) & (tau <= 1.0)))
        missed = ref_hit & ~hit
        assert not missed.any(), f"false negatives at h={h}: {np.nonzero(missed)[0][:10]}"
        assert np.all(tau[ref_hit] <= ref[ref_hit] + 1.0 / SAMPLES)
        # Every hit is a real near-contact: within h, and (near-)coplanar.
        d = _distance(x[hit], tau[hit], edge)
        assert np.all(d <= h * (1 + 1e-6) + 1e-12 * scale[hit]), (h, d.max())
        X, Y, Z = _cubic_vectors(_at(x[hit], tau[hit]), edge)
        f = (np.cross(X, Y) * Z).sum(-1)
        size = np.linalg.norm(X, axis=1) * np.linalg.norm(Y, axis=1) * np.linalg.norm(Z, axis=1)
        near_plane = np.abs(f) <= 1e-9 * (size + scale[hit] ** 2 * (np.linalg.norm(X, axis=1) + 1))
        assert near_plane.all()
        fps[h] = int((hit & ~ref_hit).sum())
    return fps, int(ref_hit.sum())


def test_point_triangle_random_motions_have_no_false_negatives():
    fps, hits = _check_random(edge=False, seed=20)
    assert fps[1e-6] == 0
    assert fps[1e-2] <= 0.06 * hits
    print(f"point-triangle: {hits} reference hits of {N_CASES}; false positives {fps}")


def test_edge_edge_random_motions_have_no_false_negatives():
    fps, hits = _check_random(edge=True, seed=21)
    assert fps[1e-6] == 0
    assert fps[1e-2] <= 0.06 * hits
    print(f"edge-edge: {hits} reference hits of {N_CASES}; false positives {fps}")


# --------------------------------------------------------------------------------------------- adversarial

H = 1e-3
A, B, C = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]


def _pt(p0, p1, a0=A, b0=B, c0=C, a1=None, b1=None, c1=None):
    a1, b1, c1 = a0 if a1 is None else a1, b0 if b1 is None else b1, c0 if c1 is None else c1
    return np.array([p0, a0, b0, c0, p1, a1, b1, c1], dtype=np.float64)


def _ee(p0, q0, r0, s0, p1=None, q1=None, r1=None, s1=None):
    p1, q1 = p0 if p1 is None else p1, q0 if q1 is None else q1
    r1, s1 = r0 if r1 is None else r1, s0 if s1 is None else s1
    return np.array([p0, q0, r0, s0, p1, q1, r1, s1], dtype=np.float64)


# (name, case, expected tau interval or None for no hit)
PT_CASES = [
    ("through the face", _pt([0.25, 0.25, 1], [0.25, 0.25, -1]), (0.5 - H / 2, 0.5)),
    ("through an edge", _pt([0.5, 0, 1], [0.5, 0, -1]), (0.5 - H / 2, 0.5)),
    ("through a vertex", _pt([0, 0, 1], [0, 0, -1]), (0.5 - H / 2, 0.5)),
    ("outside within h", _pt([0.5, -H / 2, 1], [0.5, -H / 2, -1]), (0.5 - H / 2, 0.5)),
    ("outside beyond h", _pt([0.5, -2 * H, 1], [0.5, -2 * H, -1]), None),
    ("beyond the hypotenuse", _pt([0.6, 0.6, 1], [0.6, 0.6, -1]), None),
    (
        "sliding in the plane into the face",
        _pt([-1, 0.25, 0], [1, 0.25, 0]),
        (0.5 - H / 2 - 1e-9, 0.5 - H / 2 + 1e-9),
    ),
    ("sliding in the plane, passing by", _pt([-1, 1.5, 0], [1, 1.5, 0]), None),
    ("parallel 2h above", _pt([-1, 0.25, 2 * H], [1, 0.25, 2 * H]), None),
    ("parallel h/2 above (never coplanar)", _pt([-1, 0.25, H / 2], [1, 0.25, H / 2]), None),
    ("at rest on the face", _pt([0.25, 0.25, 0], [0.25, 0.25, 0]), (0.0, 0.0)),
    ("at rest above", _pt([0.25, 0.25, 0.1], [0.25, 0.25, 0.1]), None),
    ("at rest in the plane, outside", _pt([2, 2, 0], [2, 2, 0]), None),
    (
        "triangle moving onto a point",
        _pt(
            [0.25, 0.25, 0],
            [0.25, 0.25, 0],
            [0, 0, 1],
            [1, 0, 1],
            [0, 1, 1],
            [0, 0, -1],
            [1, 0, -1],
            [0, 1, -1],
        ),
        (0.5 - H / 2, 0.5),
    ),
    (
        "moving together, on the face",
        _pt([0.25, 0.25, 0], [1.25, 1.25, 1], A, B, C, [1, 1, 1], [2, 1, 1], [1, 2, 1]),
        (0.0, 0.0),
    ),
    (
        "zero-area triangle",
        _pt([0.5, 0, 1], [0.5, 0, -1], [0, 0, 0], [1, 0, 0], [2, 0, 0]),
        (0.5 - H / 2 - 1e-9, 0.5),
    ),
    ("a point triangle, missed", _pt([0.5, 0.5, 1], [0.5, 0.5, -1], [0, 0, 0], [0, 0, 0], [0, 0, 0]), None),
    (
        "far coordinates",
        _pt(
            [-999.75, 500.25, -699],
            [-999.75, 500.25, -701],
            [-1000, 500, -700],
            [-999, 500, -700],
            [-1000, 501, -700],
        ),
        (0.5 - H / 2, 0.5),
    ),
    (
        "tilting triangle sweeps a point",
        _pt([0.25, 0.5, 0.25], [0.25, 0.5, 0.25], A, B, [0, 1, 1], A, B, [0, 1, -1]),
        (0.25 - 1e-3, 0.25 + 1e-9),
    ),
]

E1 = ([-1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
EE_CASES = [
    ("crossing", _ee(*E1, [0, -1, 1], [0, 1, 1], *E1, [0, -1, -1], [0, 1, -1]), (0.5 - H / 2, 0.5)),
    ("passing beyond an end", _ee(*E1, [2, -1, 1], [2, 1, 1], *E1, [2, -1, -1], [2, 1, -1]), None),
    (
        "a vertex through the edge",
        _ee(*E1, [0, 0, 1], [0, 1, 1], *E1, [0, 0, -1], [0, 1, -1]),
        (0.5 - H / 2, 0.5),
    ),
    (
        "near miss within h",
        _ee(*E1, [0, H / 2, 1], [0, 1, 1], *E1, [0, H / 2, -1], [0, 1, -1]),
        (0.5 - H / 2, 0.5),
    ),
    ("near miss beyond h", _ee(*E1, [0, 2 * H, 1], [0, 1, 1], *E1, [0, 2 * H, -1], [0, 1, -1]), None),
    (
        "parallel, approaching in a plane",
        _ee(*E1, [-1, 1, 0], [1, 1, 0], *E1, [-1, -1, 0], [1, -1, 0]),
        (0.5 - H / 2 - 1e-9, 0.5 - H / 2 + 1e-9),
    ),
    (
        "parallel, passing 2h apart",
        _ee(*E1, [-1, 1, 2 * H], [1, 1, 2 * H], *E1, [-1, -1, 2 * H], [1, -1, 2 * H]),
        None,
    ),
    (
        "collinear, sliding into overlap",
        _ee(*E1, [2, 0, 0], [3, 0, 0], *E1, [0, 0, 0], [1, 0, 0]),
        (0.5 - H / 2 - 1e-9, 0.5 - H / 2 + 1e-9),
    ),
    ("at rest, touching", _ee(*E1, [0, 0, 0], [0, 1, 0]), (0.0, 0.0)),
    ("at rest, apart", _ee(*E1, [0, 0, 1], [0, 1, 1]), None),
    (
        "zero-length edge through the edge",
        _ee(*E1, [0.5, 0, 1], [0.5, 0, 1], *E1, [0.5, 0, -1], [0.5, 0, -1]),
        (0.5 - H / 2 - 1e-9, 0.5),
    ),
    (
        "far coordinates",
        _ee(
            [-1001, -50, 7],
            [-999, -50, 7],
            [-1000, -51, 8],
            [-1000, -49, 8],
            [-1001, -50, 7],
            [-999, -50, 7],
            [-1000, -51, 6],
            [-1000, -49, 6],
        ),
        (0.5 - H / 2, 0.5),
    ),
]


def _check_adversarial(cases, edge, dtype, tol=1e-9):
    """The cases as written (axis-aligned: coplanar motion has f = 0 exactly) and rigidly rotated and
    moved (f is then round-off noise around 0, which the tolerance band must absorb); same answers."""
    x = np.array([c for _, c, _ in cases])
    q, _ = np.linalg.qr(np.random.default_rng(22).normal(size=(3, 3)))
    for xs in (x, x @ q.T + np.array([0.3, -0.7, 0.2])):
        tau = _run(xs, H, edge, dtype)
        for (name, _, want), got in zip(cases, tau, strict=True):
            if want is None:
                assert got == NO_HIT, (name, got)
            else:
                assert want[0] - tol <= got <= want[1] + tol, (name, got, want)


def test_point_triangle_adversarial():
    _check_adversarial(PT_CASES, False, np.float64)


def test_edge_edge_adversarial():
    _check_adversarial(EE_CASES, True, np.float64)


@pytest.mark.parametrize("edge", [False, True])
def test_adversarial_in_f32(edge):
    """The same answers in f32 (times to 1e-4 of the step), far coordinates included."""
    ta.init("cpu", precision="f32")
    _check_adversarial(EE_CASES if edge else PT_CASES, edge, np.float32, tol=1e-4)
