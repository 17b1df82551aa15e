"""The StVK membrane term (taichi_anim/terms/membrane.py): force = -grad energy, the exact and projected
Hessians, rigid-motion invariance, the patch test, uniaxial tension of a strip solved by Newton's
method, warp/weft anisotropy and parameter checks. Tolerances are derived from the finite-difference
step, round-off (machine epsilon times the magnitudes involved) or the small-strain approximation."""

import numpy as np
import pytest

from taichi_anim.errors import ParameterError
from taichi_anim.terms.membrane import MembraneStVK

EPS = np.finfo(np.float64).eps
L = 0.1  # edge scale of the test triangles [m]
Y, NU = 1.0e3, 0.3  # areal Young's modulus [N/m], Poisson's ratio


def c_iso(e=Y, nu=NU):
    return e / (1 - nu * nu) * np.array([[1, nu, 0], [nu, 1, 0], [0, 0, (1 - nu) / 2]])


def c_ortho(e1, e2, nu12, g12):
    nu21 = nu12 * e2 / e1
    d = 1 - nu12 * nu21
    return np.array([[e1 / d, nu21 * e1 / d, 0], [nu12 * e2 / d, e2 / d, 0], [0, 0, g12]])


def rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# Deformations (3x2, from the triangle's 2D rest coordinates), before a random rotation.
CASES = {
    "stretched": np.array([[1.25, 0.1], [0.05, 1.1], [0.0, 0.0]]),  # both principal stresses > 0
    "compressed": np.array([[0.8, 0.05], [0.02, 0.75], [0.0, 0.0]]),  # both < 0
    "mixed": np.array([[1.2, 0.1], [0.0, 0.8], [0.0, 0.0]]),  # one of each sign
    "inverted": np.array([[1.1, 0.2], [0.1, -0.7], [0.0, 0.1]]),  # vertex 2 pushed through edge 0-1
    "collapsed": np.array([[1.0, 0.3], [0.0, 0.0], [0.0, 0.0]]),  # all three vertices on a line
}


def triangles(rng, cases):
    """Disjoint random triangles, one per deformation: rest (3k,3) in random planes, deformed (3k,3),
    2D rest coordinates (k,3,2) and the deformations (k,3,2)."""
    rest, x, X2, Fs = [], [], [], []
    for name in cases:
        X = np.array([[0, 0], [L, 0], [0.3 * L, 0.8 * L]]) + 0.2 * L * rng.uniform(-1, 1, (3, 2))
        Q = rotation(rng)[:, :2]
        c = rng.normal(size=3)
        F = rotation(rng) @ CASES[name]
        rest.append(c + X @ Q.T)
        x.append(rng.normal(size=3) + X @ F.T)
        X2.append(X)
        Fs.append(F)
    return np.vstack(rest), np.vstack(x), np.array(X2), np.array(Fs)


def term(rest, **kw):
    return MembraneStVK(len(rest), np.arange(len(rest)).reshape(-1, 3), rest, **kw)


def stress(F, C=None):
    """2nd Piola stress (2x2) of a deformation F (3x2) in the frame of its rest coordinates."""
    G = 0.5 * (F.T @ F - np.eye(2))
    s = (c_iso() if C is None else C) @ np.array([G[0, 0], G[1, 1], 2 * G[0, 1]])
    return np.array([[s[0], s[2]], [s[2], s[1]]])


@pytest.mark.parametrize("case", list(CASES))
def test_force_is_minus_energy_gradient(case):
    rng = np.random.default_rng(1)
    rest, x, _, F = triangles(rng, [case])
    m = term(rest)
    f = m.element_arrays(x, np.zeros_like(x))[0][0]
    d = 1e-6 * L
    grad = np.zeros(9)
    for k in range(9):
        xp, xm = x.copy(), x.copy()
        xp.flat[k] += d
        xm.flat[k] -= d
        grad[k] = (m.energy(xp) - m.energy(xm)) / (2 * d)
    # Round-off of the energy (eps times its largest terms, A0 Y |F|^4) over 2d, plus the O(d^2)
    # truncation of central differences relative to the force scale Y L (1 + |F|^2)^(3/2).
    nF = 1 + np.linalg.norm(F[0]) ** 2
    tol = 10 * (EPS * Y * L * L * nF**2 / d + (d / L) ** 2 * Y * L * nF**1.5)
    assert np.abs(f + grad).max() <= tol, (np.abs(f + grad).max(), tol)


def linear(m, x, v=None, h=1.0):
    F, FL, S, KV = m.element_arrays(x, np.zeros_like(x) if v is None else v, h=h)
    return F, FL, S, KV


def test_hessian_exact_and_projected():
    rng = np.random.default_rng(2)
    names = list(CASES)
    rest, x, _, Fs = triangles(rng, names)
    exact = term(rest, projected=False)
    K = linear(exact, x)[2]  # h = 1, no damping: S = K
    d = 1e-6 * L
    fd = np.zeros_like(K)
    for k in range(9):  # the triangles are disjoint: perturb coordinate k of each at once
        xp, xm = x.copy(), x.copy()
        xp.reshape(-1, 9)[:, k] += d
        xm.reshape(-1, 9)[:, k] -= d
        fd[:, :, k] = -(exact.element_arrays(xp, 0 * x)[0] - exact.element_arrays(xm, 0 * x)[0]) / (2 * d)
    kscale = Y * (1 + np.linalg.norm(Fs, axis=(1, 2)) ** 2)[:, None, None]
    tol = 10 * (EPS * kscale * L / d + (d / L) ** 2 * kscale)  # round-off of f over 2d + truncation
    assert (np.abs(K - fd) <= tol).all(), np.abs(K - fd).max()
    assert np.allclose(K, K.transpose(0, 2, 1), rtol=0, atol=1e3 * EPS * kscale.max())

    Kp = linear(term(rest), x)[2]
    for e, name in enumerate(names):
        principal = np.linalg.eigvalsh(stress(Fs[e]))
        lam = np.linalg.eigvalsh(Kp[e])
        assert lam.min() >= -1e-9 * lam.max(), (name, lam.min(), lam.max())
        if name == "stretched":
            assert principal.min() > 0
            assert np.abs(Kp[e] - K[e]).max() <= 100 * EPS * kscale[e, 0, 0]
        if name in ("compressed", "mixed", "inverted"):  # there the exact Hessian is indefinite
            assert principal.min() < 0 and np.linalg.eigvalsh(K[e]).min() < -1e-3 * lam.max()


# the unprojected Hessian's damping is the same algebra on an indefinite K: the slow run holds it
@pytest.mark.parametrize("projected", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_linearisation_damping(projected):
    rng = np.random.default_rng(3)
    rest, x, _, Fs = triangles(rng, list(CASES))
    v = rng.normal(size=x.shape)
    beta, h = 0.02, 0.01
    F0, _, K, _ = linear(term(rest, projected=projected), x)  # elastic force only; K (h = 1)
    F, FL, S, KV = linear(term(rest, damping=beta, projected=projected), x, v, h)
    KVref = -np.einsum("eij,ej->ei", K, v.reshape(-1, 9))
    scale = Y * L * (1 + np.linalg.norm(Fs, axis=(1, 2)).max() ** 2) * (1 + np.abs(v).max())
    assert np.abs(KV - KVref).max() <= 1e3 * EPS * scale
    assert np.abs(S - (h * beta + h * h) * K).max() <= 1e3 * EPS * (h * beta + h * h) * np.abs(K).max()
    assert np.abs(F - (F0 + beta * KVref)).max() <= 1e3 * EPS * scale  # matrix-free K v in element_force
    assert np.abs(FL - F).max() <= 1e3 * EPS * scale  # element_linear and element_force agree


def test_rigid_motions_are_free():
    rng = np.random.default_rng(4)
    rest, _, X2, _ = triangles(rng, ["stretched"] * 6)
    m = term(rest)
    for _ in range(5):
        R, c = rotation(rng), rng.normal(size=3)
        x = rest @ R.T + c
        f = m.element_arrays(x, 0 * x)[0]
        # Round-off: strains of order eps |x| / L, forces Y L times that.
        scale = 1 + np.abs(x).max() / L
        assert np.abs(f).max() <= 100 * EPS * Y * L * scale
        assert abs(m.energy(x)) <= (100 * EPS * scale) ** 2 * Y * L * L
    # A mirrored triangle is a rotation by pi about an edge in 3D: no strain either.
    p0, p1, p2 = rest[0], rest[1], rest[2]
    n = (p1 - p0) / np.linalg.norm(p1 - p0)
    q = p2 - p0
    mirror = np.array([p0, p1, p0 + 2 * (q @ n) * n - q])
    assert abs(term(mirror).energy(rest[:3])) <= (100 * EPS) ** 2 * Y * L * L


@pytest.mark.parametrize("C", [c_iso(), c_ortho(2.0e3, 5.0e2, 0.3, 150.0)], ids=["isotropic", "orthotropic"])
def test_patch(C):
    """A uniform deformation of an irregular 3x3-vertex patch: interior force 0, boundary forces the
    traction integrals P N times each node's share of the boundary length, energy A e.C.e/2."""
    lx, ly = 0.3, 0.2
    X = np.array(
        [[0, 0], [0.13, 0], [lx, 0], [0, 0.09], [0.17, 0.11], [lx, 0.08], [0, ly], [0.16, ly], [lx, ly]]
    )
    tri = []
    for j in range(2):
        for i in range(2):
            a, b, c, d = 3 * j + i, 3 * j + i + 1, 3 * j + i + 3, 3 * j + i + 4
            tri += [[a, b, d], [a, d, c]]
    tri = np.array(tri)
    kw = dict(youngs_modulus=Y, poisson_ratio=NU)
    if C[0, 0] != C[1, 1]:
        kw = dict(youngs_warp=2.0e3, youngs_weft=5.0e2, poisson_ratio=0.3, shear_modulus=150.0)
    m = MembraneStVK(9, tri, np.c_[X, np.zeros(9)], **kw)
    F = rotation(np.random.default_rng(5)) @ np.array([[1.08, 0.06], [0.03, 0.95], [0.0, 0.0]])
    x = X @ F.T + np.array([0.3, -0.2, 1.0])
    fe = m.element_arrays(x, 0 * x)[0].reshape(-1, 3, 3)
    f = np.zeros((9, 3))
    np.add.at(f, tri, fe)
    P = F @ stress(F, C)
    expect = np.zeros((9, 3))
    loop = [0, 1, 2, 5, 8, 7, 6, 3, 0]  # the boundary, counter-clockwise
    for p, q in zip(loop[:-1], loop[1:], strict=True):
        t = X[q] - X[p]
        traction = P @ np.array([t[1], -t[0]])  # P N |t| with N the outward normal
        expect[[p, q]] -= traction / 2  # the element force holds the boundary back
    scale = np.abs(P).max() * (lx + ly)
    assert np.abs(f - expect).max() <= 1e3 * EPS * scale, np.abs(f - expect).max()
    assert np.abs(f[4]).max() <= 1e3 * EPS * scale
    G = 0.5 * (F.T @ F - np.eye(2))
    e = np.array([G[0, 0], G[1, 1], 2 * G[0, 1]])
    energy = lx * ly * 0.5 * e @ C @ e
    assert abs(m.energy(x) - energy) <= 1e3 * EPS * energy


def strip(nx=8, ny=3, lx=0.4, ly=0.1):
    X = np.stack(np.meshgrid(np.linspace(0, lx, nx), np.linspace(0, ly, ny)), -1).reshape(-1, 2)
    tri = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a, b, c, d = j * nx + i, j * nx + i + 1, (j + 1) * nx + i, (j + 1) * nx + i + 1
            tri += [[a, b, d], [a, d, c]] if (i + j) % 2 else [[a, b, c], [b, d, c]]
    return np.c_[X, np.zeros(len(X))], np.array(tri)


def pull(m, X, tri, tension, lx=0.4):
    """Statics of the strip: x of the left end fixed (its bottom node fully), z fixed everywhere (a flat
    membrane at zero stress has no out-of-plane stiffness), total force `tension` on the right end
    shared by edge length; Newton's method on the assembled force and K (h = 1, no damping: S = K)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    n = len(X)
    ext = np.zeros((n, 3))
    right = np.flatnonzero(np.isclose(X[:, 0], lx))
    share = np.full(len(right), 1.0 / (len(right) - 1))  # of the end's width, equal spacing
    share[[0, -1]] /= 2
    ext[right, 0] = tension * share
    fixed = np.zeros((n, 3), bool)
    fixed[np.isclose(X[:, 0], 0), 0] = True
    fixed[0] = True
    fixed[:, 2] = True
    free = np.flatnonzero(~fixed.reshape(-1))
    dof = (3 * tri[:, :, None] + np.arange(3)).reshape(-1, 9)
    x = X.copy()
    for _ in range(20):
        fe, _, K, _ = m.element_arrays(x, 0 * x)
        r = ext.reshape(-1).copy()
        np.add.at(r, dof, fe)
        # Converged to round-off: stresses to eps Y, nodal forces to eps Y L (with a margin of 100).
        if np.abs(r[free]).max() <= 100 * EPS * Y * L:
            return x
        A = sp.coo_matrix((K.reshape(-1), (np.repeat(dof, 9, 1).reshape(-1), np.tile(dof, 9).reshape(-1))))
        A = A.tocsr()[free][:, free]
        x.reshape(-1)[free] += spla.spsolve(A.tocsc(), r[free])
    raise AssertionError("Newton did not converge")


def strains(x, X, lx=0.4, ly=0.1):
    """Axial and lateral engineering strains of every column of the strip (uniform when exact)."""
    u = x - X
    right, left = np.isclose(X[:, 0], lx), np.isclose(X[:, 0], 0)
    axial = (u[right, 0].mean() - u[left, 0].mean()) / lx
    top, bottom = np.isclose(X[:, 1], ly), np.isclose(X[:, 1], 0)
    lateral = (x[top, 1] - x[bottom, 1]) / ly - 1
    return axial, lateral


def test_uniaxial_tension():
    X, tri = strip()
    m = MembraneStVK(len(X), tri, X, youngs_modulus=Y, poisson_ratio=NU)
    eps0 = 1e-4
    sigma = Y * eps0  # [N/m]
    x = pull(m, X, tri, sigma * 0.1)
    axial, lateral = strains(x, X)
    # Green vs engineering strain: sigma = E (e + 3/2 e^2 + ...), so e = sigma/E (1 - 1.5 sigma/E);
    # the lateral strain deviates from -nu e by (1 - nu/2) e relatively: both within 2 sigma/E.
    assert abs(axial / eps0 - 1) <= 2 * eps0, axial
    assert np.abs(lateral / (-NU * eps0) - 1).max() <= 2 * eps0, lateral
    # The exact large-strain law: P = lambda1 E G11 with S22 = 0, G22 = -nu G11 (round-off only).
    l1, l2 = 1 + axial, 1 + lateral
    assert abs(l1 * Y * (l1 * l1 - 1) / 2 / sigma - 1) <= 1e-8
    assert np.abs((l2 * l2 - 1) / (-NU * (l1 * l1 - 1)) - 1).max() <= 1e-8


def test_anisotropy_warp_weft():
    X, tri = strip()
    e1, e2, nu12, g12 = 2.0e3, 5.0e2, 0.3, 150.0
    eps0 = 1e-4
    sigma = e2 * eps0
    got = {}
    for name, warp in (("warp", (1, 0, 0)), ("weft", (0, 1, 0))):
        m = MembraneStVK(
            len(X),
            tri,
            X,
            poisson_ratio=nu12,
            youngs_warp=e1,
            youngs_weft=e2,
            shear_modulus=g12,
            warp_direction=warp,
        )
        got[name] = strains(pull(m, X, tri, sigma * 0.1), X)
    # Stress per strain along warp over that along weft is E1/E2; each strain is within 2 sigma/E of
    # the small-strain law (as in test_uniaxial_tension), so the ratio within 4 sigma/E2.
    ratio = got["weft"][0] / got["warp"][0]
    assert abs(ratio / (e1 / e2) - 1) <= 4 * eps0, ratio
    # Reciprocity: the lateral strain is -nu12 sigma/E1 whichever way it is pulled.
    for name in got:
        assert np.abs(got[name][1] / (-nu12 * sigma / e1) - 1).max() <= 4 * eps0, (name, got[name][1])


def test_warp_falls_back_to_first_edge():
    rng = np.random.default_rng(6)
    rest, x, _, _ = triangles(rng, ["stretched"])
    edge = rest[1] - rest[0]
    normal = np.cross(edge, rest[2] - rest[0])
    kw = dict(poisson_ratio=0.3, youngs_warp=2.0e3, youngs_weft=5.0e2, shear_modulus=150.0)
    along = term(rest, warp_direction=edge, **kw).energy(x)
    fallback = term(rest, warp_direction=normal, **kw).energy(x)
    assert abs(fallback - along) <= 1e3 * EPS * along


@pytest.mark.parametrize(
    "kw, name",
    [
        (dict(youngs_modulus=-1.0), "youngs_modulus"),
        (dict(poisson_ratio=0.5), "poisson_ratio"),
        (dict(damping=-0.1), "damping"),
        (dict(youngs_warp=1.0e3), "youngs_weft"),
        (
            dict(youngs_warp=1.0e3, youngs_weft=5.0e3, shear_modulus=100.0, poisson_ratio=0.49),
            "poisson_ratio",
        ),
    ],
)
def test_bad_parameters(kw, name):
    rest = np.array([[0, 0, 0], [L, 0, 0], [0, L, 0.0]])
    with pytest.raises(ParameterError, match=name):
        term(rest, **kw)


def test_degenerate_triangle():
    rest = np.array([[0, 0, 0], [L, 0, 0], [0, L, 0], [2 * L, 0, 0.0]])
    with pytest.raises(ParameterError, match="first index 1"):
        MembraneStVK(4, [[0, 1, 2], [0, 1, 3]], rest)
