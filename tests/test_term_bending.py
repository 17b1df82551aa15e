"""BendingDihedral (taichi_anim/terms/bending.py): hinge listing, force = -grad E and grad theta against
central differences, the Gauss-Newton stiffness against the force's Jacobian at the rest angle, rigid
invariance, rest angles, the cylinder closed form and parameter errors.

Finite differences, f64: a central difference of a function with third derivative M3, evaluated to
relative accuracy eps, errs by at most delta^2 M3 / 6 + eps |value| / delta. For the hinge energy
(k/2) w theta^2, each derivative of theta brings a factor 1/ell (ell the smallest distance of a wing
tip from the edge, its lever arm), so M3 <~ 10 k w / ell^3 with theta = O(1); the tolerances below are
that bound with delta = 1e-6 (truncation ~1e-11 k w / ell^3, rounding ~1e-10 k w)."""

import math

import numpy as np
import pytest

from taichi_anim.errors import ParameterError
from taichi_anim.terms.bending import BendingDihedral, hinge_angles, mesh_hinges

from .helpers import assert_passes_match_element_arrays

EPS = np.finfo(np.float64).eps
DELTA = 1e-6


# ---- independent NumPy references


def theta_ref(P):
    """Dihedral angles of hinges P (H,4,3) from the wings projected on the plane normal to the edge
    (another route than the kernels' normals): theta = pi - (signed interior angle), in (-pi, pi]."""
    e = P[:, 1] - P[:, 0]
    e = e / np.linalg.norm(e, axis=1)[:, None]
    u2, u3 = P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]
    u2 = u2 - (u2 * e).sum(1)[:, None] * e
    u3 = u3 - (u3 * e).sum(1)[:, None] * e
    phi = np.arctan2((np.cross(u2, u3) * e).sum(1), (u2 * u3).sum(1))
    return -np.angle(np.exp(1j * (phi - math.pi)))  # pi - phi wrapped into (-pi, pi]


def weight_ref(P):
    """w = |e|^2 / (A1 + A2) of hinges P (H,4,3)."""
    e = P[:, 1] - P[:, 0]
    a1 = 0.5 * np.linalg.norm(np.cross(e, P[:, 2] - P[:, 0]), axis=1)
    a2 = 0.5 * np.linalg.norm(np.cross(P[:, 3] - P[:, 0], e), axis=1)
    return (e * e).sum(1) / (a1 + a2)


def lever(P):
    """Smallest distance of a wing tip from its edge, per hinge (the 1/ell of theta's derivatives)."""
    e = P[:, 1] - P[:, 0]
    le = np.linalg.norm(e, axis=1)
    h2 = np.linalg.norm(np.cross(e, P[:, 2] - P[:, 0]), axis=1) / le
    h3 = np.linalg.norm(np.cross(e, P[:, 3] - P[:, 0]), axis=1) / le
    return np.minimum(np.minimum(h2, h3), le)


def rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def make_hinge(rng, theta):
    """A random hinge (4,3) of dihedral angle theta (checked against theta_ref), randomly placed."""
    length = rng.uniform(0.7, 1.3)
    s2, s3 = length * rng.uniform(-0.2, 1.2, 2)
    h2, h3 = rng.uniform(0.4, 1.0, 2)
    phi = rng.uniform(0.0, 2.0 * math.pi)
    for sign in (1.0, -1.0):
        psi = phi + math.pi - sign * theta
        P = np.array(
            [
                [0, 0, 0],
                [length, 0, 0],
                [s2, h2 * math.cos(phi), h2 * math.sin(phi)],
                [s3, h3 * math.cos(psi), h3 * math.sin(psi)],
            ]
        )
        if abs(theta_ref(P[None])[0] - theta) < 1e-12:
            break
    return P @ rotation(rng).T + rng.normal(size=3)


def separate(P):
    """Positions (4H,3) and hinges (H,4) for hinges P (H,4,3) with their own particles."""
    return P.reshape(-1, 3), np.arange(P.shape[0] * 4).reshape(-1, 4)


def term_for(rest_P, **kw):
    x, hinges = separate(rest_P)
    return BendingDihedral(len(x), hinges, x, **kw)


def energy_gradient_fd(term, x, rest):
    """Central differences of the energy of each hinge alone: the others held at rest (energy 0), so
    the rounding of one hinge's difference scales with its own energy, not the total."""
    H = term.count
    x, rest = x.reshape(H, 12), rest.reshape(H, 12)
    g = np.zeros((H, 12))
    for e in range(H):
        for i in range(12):
            xp, xm = rest.copy(), rest.copy()
            xp[e], xm[e] = x[e], x[e]
            xp[e, i] += DELTA
            xm[e, i] -= DELTA
            g[e, i] = (term.energy(xp.reshape(-1, 3)) - term.energy(xm.reshape(-1, 3))) / (2 * DELTA)
    return g


def theta_gradient_fd(P):
    """Central differences of theta_ref, (H,12)."""
    g = np.zeros((P.shape[0], 12))
    for i in range(12):
        Pp, Pm = P.copy(), P.copy()
        Pp[:, i // 3, i % 3] += DELTA
        Pm[:, i // 3, i % 3] -= DELTA
        g[:, i] = (theta_ref(Pp) - theta_ref(Pm)) / (2 * DELTA)
    return g


def fd_tol(kw, ell, energy):
    """The central-difference bound of the module docstring, per hinge: k w, ell and energy per hinge."""
    return 10.0 * (DELTA**2 * kw / ell**3 + EPS * energy / DELTA)


# ---- 1. mesh_hinges


def grid_mesh(nx, ny, a=1.0, c=1.0):
    """nx x ny vertices at (i a, j c, 0), one diagonal per quad, counter-clockwise seen from +z."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    x = np.stack([i * a, j * c, 0.0 * i], -1).reshape(-1, 3).astype(float)
    q = (i[:-1, :-1] * ny + j[:-1, :-1]).reshape(-1)
    tris = np.concatenate([np.stack([q, q + ny, q + ny + 1], 1), np.stack([q, q + ny + 1, q + 1], 1)])
    return x, tris


@pytest.mark.parametrize("nx, ny", [(2, 2), (3, 2), (5, 4), (9, 7)])
def test_mesh_hinges_count_and_orientation(nx, ny):
    x, tris = grid_mesh(nx, ny)
    hinges = mesh_hinges(tris)
    assert len(hinges) == (nx - 1) * (ny - 1) + (nx - 2) * (ny - 1) + (nx - 1) * (ny - 2)
    # Every hinge's two triangles are mesh triangles in the mesh's own cyclic order.
    cyc = {tuple(np.roll(t, r)) for t in tris.tolist() for r in range(3)}
    assert all((a, b, c) in cyc and (b, a, d) in cyc for a, b, c, d in hinges.tolist())
    assert len({tuple(sorted(h[:2])) for h in hinges.tolist()}) == len(hinges)  # one hinge per edge
    # A flat, consistently oriented mesh: all angles 0 (a reversed wing would give pi).
    assert np.abs(hinge_angles(x, hinges)).max() == 0.0
    flipped = tris.copy()
    flipped[0] = flipped[0, ::-1]
    if len(tris) > 1:
        with pytest.raises(ParameterError, match="inconsistent orientation"):
            mesh_hinges(flipped)


# ---- 2, 3. force = -grad E, grad theta


def hinge_cases(rng):
    """Random, nearly flat (1e-4), strongly folded (+-3 rad) and general hinges, (H,4,3)."""
    return np.array(
        [rng.normal(size=(4, 3)) for _ in range(3)]
        + [make_hinge(rng, t) for t in (1e-4, -1e-4, 3.0, -3.0, 0.7, -1.9)]
    )


@pytest.mark.parametrize("rest", ["flat", "curved"])
def test_force_is_minus_energy_gradient(rest):
    rng = np.random.default_rng(2)
    P = hinge_cases(rng)
    # curved: theta0 != 0 (random, up to +-2.5), the current angle elsewhere
    theta0 = np.zeros(len(P)) if rest == "flat" else rng.uniform(-2.5, 2.5, len(P))
    R = np.array([make_hinge(rng, t) for t in theta0])
    term = term_for(R, stiffness=0.8)
    assert np.allclose(term.rest_angle, theta0, atol=1e-12)
    x = P.reshape(-1, 3)
    F = term.element_arrays(x, 0 * x)[0]
    err = np.abs(F + energy_gradient_fd(term, x, R.reshape(-1, 3))).max(1)
    kw = 0.8 * weight_ref(R)
    excess = np.angle(np.exp(1j * (theta_ref(P) - theta0)))
    tol = fd_tol(kw, lever(P), 0.5 * kw * excess**2)
    assert np.all(err <= tol), (err, tol)


def test_theta_and_gradient_match_reference():
    rng = np.random.default_rng(3)
    P = hinge_cases(rng)
    k = 2.0
    R = np.array([make_hinge(rng, 0.0) for _ in P])  # theta0 = 0: E = w theta^2 with k = 2
    term = term_for(R, stiffness=k)
    x = P.reshape(-1, 3)
    w = weight_ref(R)
    assert np.allclose(term.weight, w, rtol=1e-13)
    theta = theta_ref(P)
    assert np.abs(hinge_angles(x, separate(P)[1]) - theta).max() <= 1e-14
    assert term.energy(x) == pytest.approx((w * theta**2).sum(), rel=1e-13)
    # F = -k w theta g: g from the force against central differences of theta_ref. theta_ref rounds to
    # ~eps pi absolute (the FD's rounding term); the kernel's theta to ~eps absolute too, which the
    # division by theta turns into a relative error eps / |theta| of g (2e-12 at theta = 1e-4).
    F, _, S, _ = term.element_arrays(x, 0 * x)
    g_fd = theta_gradient_fd(P)
    g = -F / (k * w * theta)[:, None]
    tol = 10.0 * (DELTA**2 / lever(P) ** 3 + EPS * math.pi / DELTA)
    assert np.all(np.abs(g - g_fd).max(1) <= tol + 10 * EPS * np.abs(g_fd).max(1) / np.abs(theta))
    # S (h = 1, beta = 0) = k w g g^T, independent of theta (the nearly flat hinges included)
    outer = np.einsum("hi,hj->hij", g_fd, g_fd) * (k * w)[:, None, None]
    gmax = np.abs(g_fd).max(1)
    assert np.all(np.abs(S - outer).max((1, 2)) <= 2 * k * w * gmax * tol)


def test_excess_angle_wraps_across_pi():
    """A rest angle near pi (a sharp crease): folding on through pi to -3.0 is 2 pi - 6 from theta0 = 3.0,
    not -6, so the energy stays small and smooth there (its jump is opposite the rest angle)."""
    rng = np.random.default_rng(7)
    R = make_hinge(rng, 3.0)[None]
    term = term_for(R, stiffness=1.0)
    w = weight_ref(R)[0]
    for theta, excess in ((-3.0, 2 * math.pi - 6.0), (3.1, 0.1), (2.0, -1.0)):
        P = make_hinge(rng, theta)[None]
        assert term.energy(P.reshape(-1, 3)) == pytest.approx(0.5 * w * excess**2, rel=1e-12)


# ---- 4. the Gauss-Newton stiffness


def force_jacobian_fd(term, x):
    """Central differences of the element forces: (H,12,12), J[:, :, j] = dF/dX_j."""
    H = term.count
    J = np.zeros((H, 12, 12))
    for j in range(12):
        xp, xm = x.copy().reshape(H, 12), x.copy().reshape(H, 12)
        xp[:, j] += DELTA
        xm[:, j] -= DELTA
        Fp = term.element_arrays(xp.reshape(-1, 3), 0 * x)[0]
        Fm = term.element_arrays(xm.reshape(-1, 3), 0 * x)[0]
        J[:, :, j] = (Fp - Fm) / (2 * DELTA)
    return J


def test_gauss_newton_exact_at_rest_angle():
    rng = np.random.default_rng(4)
    # rest configurations: flat, nearly flat (1e-4), curved (0.7, -2.5) and random; evaluated at rest
    R = np.array([make_hinge(rng, t) for t in (0.0, 1e-4, -1e-4, 0.7, -2.5)] + [rng.normal(size=(4, 3))])
    term = term_for(R, stiffness=1.7)
    x = R.reshape(-1, 3)
    F, _, S, _ = term.element_arrays(x, 0 * x, h=1.0)
    assert np.abs(F).max() <= 1e-13  # at rest
    J = force_jacobian_fd(term, x)
    kw = 1.7 * weight_ref(R)
    ell = lever(R)
    # the force's derivatives are k w (theta' theta'' ...): its third derivative <~ 10 k w / ell^4
    tol = 10.0 * (DELTA**2 * kw / ell**4 + EPS * kw / ell / DELTA)
    assert np.all(np.abs(S + J).max((1, 2)) <= tol)


def test_gauss_newton_structure_elsewhere():
    rng = np.random.default_rng(5)
    R = np.array([make_hinge(rng, t) for t in (0.0, 0.4, -1.0, 2.0)])
    P = np.array([make_hinge(rng, t) for t in (1.2, -0.5, 3.0, 0.3)])  # far from rest
    k, beta, h = 0.9, 0.03, 0.01
    x, v = P.reshape(-1, 3), rng.normal(size=(16, 3))
    elastic = term_for(R, stiffness=k)
    damped = term_for(R, stiffness=k, damping=beta)
    K = elastic.element_arrays(x, v, h=1.0)[2]  # (h beta + h^2) = 1: S = K
    F0 = elastic.element_arrays(x, v)[0]
    F, FL, S, KV = damped.element_arrays(x, v, h=h)
    scale = np.abs(K).max((1, 2))
    assert np.abs(K - K.transpose(0, 2, 1)).max() == 0.0
    ev = np.linalg.eigvalsh(K)
    assert np.all(ev[:, 0] >= -1e-13 * scale)  # PSD
    assert np.all(ev[:, -2] <= 1e-13 * scale)  # rank one
    # K = k w g g^T with g the central-difference gradient of theta_ref
    g = theta_gradient_fd(P)
    kw = k * weight_ref(R)
    tol = 10.0 * (DELTA**2 / lever(P) ** 3 + EPS * math.pi / DELTA) * np.abs(g).max(1)
    assert np.all(np.abs(K - kw[:, None, None] * np.einsum("hi,hj->hij", g, g)).max((1, 2)) <= 2 * kw * tol)
    Vs = v.reshape(-1, 12)
    KVs = np.einsum("hij,hj->hi", K, Vs)
    assert np.allclose(S, (h * beta + h * h) * K, rtol=0, atol=1e-14 * scale.max())
    assert np.allclose(KV, -KVs, rtol=0, atol=1e-13 * np.abs(KVs).max())
    assert np.allclose(FL, F, rtol=0, atol=1e-14 * np.abs(F).max())
    assert np.allclose(F, F0 - beta * KVs, rtol=0, atol=1e-13 * np.abs(F).max())
    # Why Gauss-Newton: away from the rest angle the exact stiffness -dF/dX differs from K by
    # k w (theta - theta0) Hess(theta), which is indefinite.
    Hd = -force_jacobian_fd(elastic, x) - K
    Hd = 0.5 * (Hd + Hd.transpose(0, 2, 1))
    ed = np.linalg.eigvalsh(Hd)
    assert np.all(ed[:, 0] < -0.01 * scale) and np.all(ed[:, -1] > 0.01 * scale)


# ---- 5, 6. invariance, rest angle


def test_rigid_motions():
    rng = np.random.default_rng(6)
    R = np.array([make_hinge(rng, t) for t in (0.0, 1e-4, 0.9, -2.8)])
    P = np.array([make_hinge(rng, t) for t in (0.5, -0.3, 2.9, 1e-3)])
    term = term_for(R, stiffness=1.1)
    Q, shift = rotation(rng), rng.normal(size=3)
    moved_rest = R.reshape(-1, 3) @ Q.T + shift
    F = term.element_arrays(moved_rest, 0 * moved_rest)[0]
    kw = 1.1 * weight_ref(R)
    assert np.all(np.abs(F).max(1) <= 100 * EPS * kw / lever(R))  # rounding of theta, times |g| ~ 1/ell
    assert term.energy(moved_rest) <= (100 * EPS) ** 2 * kw.sum()
    x = P.reshape(-1, 3)
    F = term.element_arrays(x, 0 * x)[0]
    Fm = term.element_arrays(x @ Q.T + shift, 0 * x)[0]
    assert term.energy(x @ Q.T + shift) == pytest.approx(term.energy(x), rel=1e-13)
    assert np.abs(Fm.reshape(-1, 3) - F.reshape(-1, 3) @ Q.T).max() <= 1e-13 * np.abs(F).max()
    f = F.reshape(-1, 4, 3)
    assert np.abs(f.sum(1)).max() <= 1e-14 * np.abs(f).max()  # no net force
    assert np.abs(np.cross(P, f).sum(1)).max() <= 1e-14 * np.abs(f).max() * np.abs(P).max()  # no torque


def cylinder(x_flat, kappa):
    """Bend a flat mesh (z = 0) isometrically about the y axis: the x coordinate becomes arc length."""
    s, y = x_flat[:, 0], x_flat[:, 1]
    return np.stack([np.sin(kappa * s) / kappa, y, (1.0 - np.cos(kappa * s)) / kappa], 1)


def test_curved_rest_mesh_is_at_rest():
    flat, tris = grid_mesh(8, 5, a=0.1, c=0.15)
    kappa, k = 2.0, 0.4
    rest = cylinder(flat, kappa)
    term = BendingDihedral.from_mesh(len(rest), tris, rest, stiffness=k)
    F = term.element_arrays(rest, 0 * rest)[0]
    assert np.abs(F).max() <= 100 * EPS * k * term.weight.max() / 0.1
    assert term.energy(rest) <= (100 * EPS) ** 2 * k * term.weight.sum()
    # Flattened, each of the 6 x 4 hinges on axis-parallel interior edges turns back by kappa a; its
    # weight is c / chord from the curved rest triangles (chord = 2 sin(kappa a / 2) / kappa).
    chord = 2 * math.sin(kappa * 0.1 / 2) / kappa
    assert term.energy(flat) == pytest.approx(0.5 * k * (kappa * 0.1) ** 2 * 0.15 / chord * 6 * 4, rel=1e-12)


# ---- 7. closed form


@pytest.mark.parametrize("nx", [4, 8, 16, 32])
def test_cylinder_energy_closed_form(nx):
    """A flat grid strip (spacing a across the axis, c along it) bent isometrically into a cylinder arc of
    curvature kappa: every quad stays a planar chord rectangle, so only the (nx-2)(ny-1) hinges on
    axis-parallel interior edges turn, each by exactly kappa a, with w = c / a: E = D/2 kappa^2 per area
    of their two triangles, (nx-2)(ny-1) a c, with no chord/arc error (rounding only). Against the whole
    strip's area (nx-1)(ny-1) a c the ratio is (nx-2)/(nx-1): the free edges' half cells carry no hinge,
    an O(1/nx) boundary term that vanishes with resolution."""
    ny, width, c, kappa, D = 5, 0.6, 0.07, 4.0, 2.5e-3
    a = width / (nx - 1)
    flat, tris = grid_mesh(nx, ny, a=a, c=c)
    term = BendingDihedral.from_mesh(len(flat), tris, flat, stiffness=D)
    E = term.energy(cylinder(flat, kappa))
    assert E == pytest.approx(0.5 * D * kappa**2 * (nx - 2) * (ny - 1) * a * c, rel=1e-11)
    full = 0.5 * D * kappa**2 * width * (ny - 1) * c
    assert E / full == pytest.approx((nx - 2) / (nx - 1), rel=1e-11)


def equilateral_mesh(n, a, axis_along_edge):
    """An n x n patch of equilateral triangles of side a, centred at 0; rows along x (or along y)."""
    j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    p = np.stack([a * (i + 0.5 * (j % 2)), a * math.sqrt(3) / 2 * j], -1).reshape(-1, 2)
    tris = []
    for r in range(n - 1):
        for s in range(n - 1):
            q, u = r * n + s, (r + 1) * n + s
            tris += [[q, q + 1, u], [q + 1, u + 1, u]] if r % 2 == 0 else [[q, u + 1, u], [q, q + 1, u + 1]]
    p = p - p.mean(0)
    if axis_along_edge:
        p = p[:, ::-1] * [1, -1]  # a quarter turn (orientation kept): edges along y, the cylinder axis
    return np.concatenate([p, np.zeros((len(p), 1))], 1), np.array(tris)


@pytest.mark.parametrize("shape", ["cylinder_along_edge", "cylinder_across_edge", "sphere"])
def test_equilateral_mesh_constant(shape):
    """The docstring's mesh dependence: energy per unit cell (area sqrt(3)/2 a^2, one edge of each of the
    three directions) of the hinges within |x|, |y| < w of the centre of an equilateral mesh, side a.
    Cylinder about an edge direction: the strips between axis-parallel edges stay flat and those edges
    turn by kappa sqrt(3)/2 a exactly: E/area = D/2 kappa^2 to rounding. Across an edge direction:
    D/2 kappa^2 up to O((kappa a)^2) (measured 3e-9 here). Sphere (from flat by z = R - sqrt(R^2 - r^2)):
    2/3 of the nu = 0 plate's D kappa^2. That map is not isometric: it stretches radially by
    (kappa r)^2 / 2, changing the energy by at most (kappa w)^2 relative in the window (r <= sqrt(2) w);
    the mesh's own error is O((kappa a)^2), with coefficient ~4 (measured at a = 0.025 and 0.05). Measured
    total: 2.5e-5 of the 2/3."""
    a, w, D = 0.05, 0.1, 1.0
    kappa = 0.1 if shape == "sphere" else 0.2
    flat, tris = equilateral_mesh(40, a, shape == "cylinder_along_edge")
    term = BendingDihedral.from_mesh(len(flat), tris, flat, stiffness=D)
    if shape == "sphere":
        r2 = (flat[:, :2] ** 2).sum(1)
        x = flat + np.stack([0 * r2, 0 * r2, 1 / kappa - np.sqrt(kappa**-2 - r2)], 1)
    else:
        x = cylinder(flat, kappa)
    hin = term.vertices
    E = 0.5 * D * term.weight * (hinge_angles(x, hin) - term.rest_angle) ** 2
    mid = flat[hin[:, :2]].mean(1)[:, :2]
    inner = np.all(np.abs(mid) < w, 1)  # away from the free boundary (the patch is ~2 x 1.7)
    d = flat[hin[:, 1]] - flat[hin[:, 0]]
    direction = np.round(np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180).astype(int) % 180
    cell = sum(E[inner & (direction == k)].mean() for k in np.unique(direction[inner]))
    density = cell / (math.sqrt(3) / 2 * a * a)
    if shape == "sphere":
        tol = 2 / 3 * (kappa * w) ** 2 + 5 * (kappa * a) ** 2
        assert density / (D * kappa**2) == pytest.approx(2 / 3, abs=tol)
    else:
        tol = 1e-11 if shape == "cylinder_along_edge" else 5 * (kappa * a) ** 2
        assert density / (0.5 * D * kappa**2) == pytest.approx(1.0, abs=tol)


# ---- the element protocol through the engine's passes (gathers, S p)


def test_protocol_gathers_match_element_arrays():
    rng = np.random.default_rng(8)
    flat, tris = grid_mesh(4, 3, a=0.2, c=0.3)
    term = BendingDihedral.from_mesh(len(flat), tris, cylinder(flat, 1.5), stiffness=0.3, damping=0.02)
    x, v, p = (
        flat + 0.02 * rng.normal(size=flat.shape),
        rng.normal(size=flat.shape),
        rng.normal(size=flat.shape),
    )
    assert_passes_match_element_arrays(term, x, v, p, h=0.005)


# ---- 8. parameter errors


def test_parameter_errors():
    rest = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [2, 0, 0]], dtype=float)
    hinge = [[0, 1, 2, 3]]
    ok = dict(stiffness=1.0)
    cases = [
        (dict(stiffness=0.0), "stiffness.*0.0"),
        (dict(stiffness=float("nan")), "stiffness.*nan"),
        (dict(stiffness=1.0, damping=-0.1), "damping.*-0.1"),
    ]
    for kw, msg in cases:
        with pytest.raises(ParameterError, match=msg):
            BendingDihedral(5, hinge, rest, **kw)
    with pytest.raises(ParameterError, match="rest_positions must have 5 rows, got 4"):
        BendingDihedral(5, hinge, rest[:4], **ok)
    bad = rest.copy()
    bad[2, 1] = np.inf
    with pytest.raises(ParameterError, match="rest_positions contains 1 non-finite"):
        BendingDihedral(5, hinge, bad, **ok)
    with pytest.raises(ParameterError, match=r"hinges holds 1 indices outside \[0, 5\)"):
        BendingDihedral(5, [[0, 1, 2, 5]], rest, **ok)
    with pytest.raises(ParameterError, match=r"hinges must have shape \(M, 4\)"):
        BendingDihedral(5, [[0, 1, 2]], rest, **ok)
    with pytest.raises(ParameterError, match="at least one hinge"):
        BendingDihedral(5, np.zeros((0, 4), int), rest, **ok)
    with pytest.raises(ParameterError, match=r"hinge 1 repeats a particle: \[0, 1, 2, 2\]"):
        BendingDihedral(5, [[0, 1, 2, 3], [0, 1, 2, 2]], rest, **ok)
    # x3 = (2, 0, 0) lies on the edge's line: hinge 1's second rest triangle has zero area
    with pytest.raises(ParameterError, match=r"first hinge 1 \[0, 1, 2, 4\]"):
        BendingDihedral(5, [[0, 1, 2, 3], [0, 1, 2, 4]], rest, **ok)
    term = BendingDihedral(5, hinge, rest, stiffness=2e-3, damping=0.01)
    assert term.settings() == {"type": "bending_dihedral", "count": 1, "stiffness": 2e-3, "damping": 0.01}
