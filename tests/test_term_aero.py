"""Flat-plate drag and lift on triangles (taichi_anim/terms/aero.py): closed forms at head-on, edge-on
and 45 degrees, Galilean invariance, zero and degenerate cases, the implicit linearisation against
central differences, scaling laws, a falling sheet's terminal speed, and parameter errors."""

import math

import numpy as np
import pytest

from taichi_anim.errors import ParameterError
from taichi_anim.terms.aero import AeroTriangles

from .helpers import assert_passes_match_element_arrays

EPS = np.finfo(np.float64).eps
RHO, CD, CL = 1.25, 1.1, 0.7
# A right triangle with legs sqrt(2) in the z = 0 plane: area 1, normal +z.
UNIT = np.array([[0.0, 0.0, 0.0], [math.sqrt(2.0), 0.0, 0.0], [0.0, math.sqrt(2.0), 0.0]])
STILL = np.zeros((3, 3))


def term(**kw):
    kw = {"density": RHO, "drag_coefficient": CD, "lift_coefficient": CL, **kw}
    return AeroTriangles(3, [[0, 1, 2]], **kw)


def forces(aero, x, v=STILL, t=0.0, h=1.0):
    """Per-vertex forces (3,3), and F_lin (9,), S (9,9), KV (9,) of the one triangle."""
    F, FL, S, KV = aero.element_arrays(x, v, t, h)
    return F[0].reshape(3, 3), FL[0], S[0], KV[0]


def random_triangle(rng):
    return rng.normal(size=(3, 3))


# ---- 1. closed forms


def test_head_on_is_pure_drag():
    s = 3.0
    f, _, _, _ = forces(term(wind=(0.0, 0.0, -s)), UNIT)
    expected = 0.5 * RHO * CD * 1.0 * s**2  # A = 1, |u_n| = s
    total = f.sum(axis=0)
    # Some ten roundings of size eps * |f| each.
    np.testing.assert_allclose(total, [0.0, 0.0, -expected], rtol=0, atol=10 * EPS * expected)


def test_edge_on_is_zero():
    f, _, _, _ = forces(term(wind=(3.0, -2.0, 0.0)), UNIT)
    assert np.array_equal(f, np.zeros((3, 3)))  # u_n = 0 exactly: no drag, no lift


def test_45_degrees_drag_and_lift():
    s = 3.0
    u = s * np.array([1.0, 0.0, 1.0]) / math.sqrt(2.0)
    f, _, _, _ = forces(term(wind=u), UNIT)
    total = f.sum(axis=0)
    uhat = u / s
    drag = total @ uhat
    lift_vec = total - drag * uhat
    q = 0.5 * RHO * 1.0 * s**2
    tol = 20 * EPS * q * max(CD, CL)
    assert abs(drag - q * CD / math.sqrt(2.0)) < tol
    assert abs(np.linalg.norm(lift_vec) - q * CL / 2.0) < tol
    # Perpendicular to u (by construction above), in the plane of u and n: along n's part normal to u,
    # here (-1, 0, 1) / sqrt(2) with u_n > 0.
    np.testing.assert_allclose(lift_vec, q * CL / 2.0 * np.array([-1.0, 0.0, 1.0]) / math.sqrt(2.0), atol=tol)
    assert abs(lift_vec @ np.cross(u, [0.0, 0.0, 1.0])) < tol * s


def test_winding_and_rotation_do_not_matter():
    rng = np.random.default_rng(3)
    wind = rng.normal(size=3)
    x = random_triangle(rng)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    f, _, _, _ = forces(term(wind=wind), x)
    f_flip, _, _, _ = forces(term(wind=wind), x[[0, 2, 1]])
    f_rot, _, _, _ = forces(term(wind=q @ wind), x @ q.T)
    scale = np.abs(f).max()
    np.testing.assert_allclose(f_flip, f, rtol=0, atol=50 * EPS * scale)
    np.testing.assert_allclose(f_rot, f @ q.T, rtol=0, atol=50 * EPS * scale)


# ---- 2. Galilean invariance


def test_galilean_invariance():
    rng = np.random.default_rng(4)
    w = rng.normal(size=3) * 2.0
    x = random_triangle(rng)
    f_wind, _, _, _ = forces(term(wind=w), x)
    f_moving, _, _, _ = forces(term(), x, np.tile(-w, (3, 1)))
    np.testing.assert_allclose(f_moving, f_wind, rtol=0, atol=50 * EPS * np.abs(f_wind).max())


# ---- 3. zero relative velocity and degenerate triangles


@pytest.mark.parametrize("w", [(0.0, 0.0, 0.0), (2.0, -1.0, 0.5)])
def test_zero_relative_velocity_is_exactly_zero(w):
    # Representable velocities, so (v0 + v1 + v2) / 3 == w exactly and u = 0.
    f, fl, S, kv = forces(term(wind=w), UNIT + [0.1, 0.2, 0.3], np.tile(w, (3, 1)), h=0.01)
    for a in (f, fl, S, kv):
        assert np.array_equal(a, np.zeros_like(a))


def test_vanishing_relative_velocity_is_finite_and_tiny():
    f, _, S, _ = forces(term(wind=(1e-300, 0.0, 1e-300)), UNIT)
    assert np.all(np.isfinite(f)) and np.all(np.isfinite(S))
    assert np.abs(f).max() < 1e-290


@pytest.mark.parametrize(
    "x",
    [
        np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]),  # collinear
        np.zeros((3, 3)),  # collapsed to a point
    ],
)
def test_degenerate_triangle_is_zero(x):
    f, fl, S, kv = forces(term(wind=(1.0, 2.0, 3.0)), x, h=0.01)
    for a in (f, fl, S, kv):
        assert np.array_equal(a, np.zeros_like(a))


# ---- 4. the linearisation


def test_linearisation_against_finite_differences():
    rng = np.random.default_rng(5)
    x = random_triangle(rng)
    v = rng.normal(size=(3, 3))
    wind = rng.normal(size=3) * 3.0
    h, delta = 0.01, 1e-6
    n = np.cross(x[1] - x[0], x[2] - x[0])
    area = 0.5 * np.linalg.norm(n)
    n /= np.linalg.norm(n)
    un = n @ (wind - v.mean(axis=0))
    assert abs(un) > 1e3 * delta  # the differences (u_n +- delta/3) stay off the kink of |u_n| at 0
    drag_only = term(wind=wind, lift_coefficient=0.0)
    f, fl, S, kv = forces(drag_only, x, v, h=h)
    np.testing.assert_array_equal(fl, f.reshape(-1))
    assert np.array_equal(kv, np.zeros(9))
    # n . f of the drag is 1/2 rho C_d A |u_n| u_n / 3 per vertex: quadratic in u_n, so the central
    # difference is exact up to roundoff, ~ eps |f| / delta.
    tol = 10 * EPS * np.abs(f).max() / delta
    for b in range(3):
        fp, _, _, _ = forces(drag_only, x, v + np.outer(np.eye(3)[b], n) * delta)
        fm, _, _, _ = forces(drag_only, x, v - np.outer(np.eye(3)[b], n) * delta)
        d = (fp - fm) @ n / (2 * delta)  # d(n . f_a) / d(v_b . n), a = 0..2
        for a in range(3):
            blk = S[3 * a : 3 * a + 3, 3 * b : 3 * b + 3]
            assert abs(n @ blk @ n - (-h * d[a])) < h * tol
            # The whole block is that number times n n^T: damping normal to the panel only.
            np.testing.assert_allclose(
                blk, (n @ blk @ n) * np.outer(n, n), rtol=0, atol=1e-14 * np.abs(S).max()
            )
            assert abs(d[a] - (-RHO * CD * area * abs(un) / 9.0)) < tol
    assert np.array_equal(S, S.T)
    eig = np.linalg.eigvalsh(S)
    expected = h * RHO * CD * area * abs(un) / 3.0  # rank one: k (1 1^T) (x) n n^T, eigenvalue 3k
    assert eig[:-1].min() > -1e-14 * expected
    assert abs(eig[-1] - expected) < 1e-13 * expected
    # The lift is explicit: it changes F, not S.
    f_lift, _, S_lift, _ = forces(term(wind=wind), x, v, h=h)
    assert not np.allclose(f_lift, f)
    np.testing.assert_array_equal(S_lift, S)


# ---- 5. distribution and scaling


def test_solver_passes_match_the_element_linearisation():
    """The implicit solver's passes store the normal drag's blocks as their rank-one factor (rank_one.py):
    forces, diagonal blocks and S p through them equal element_linear's full 9x9 blocks summed per vertex,
    on a crumpled 4x3 sheet in a gusty wind."""
    rng = np.random.default_rng(3)
    gx, gy = np.meshgrid(np.arange(4) * 0.3, np.arange(3) * 0.25, indexing="ij")
    flat = np.stack([gx.ravel(), gy.ravel(), np.zeros(12)], axis=1)
    q = lambda i, j: 3 * i + j  # noqa: E731
    tris = [
        t
        for i in range(3)
        for j in range(2)
        for t in ((q(i, j), q(i + 1, j), q(i + 1, j + 1)), (q(i, j), q(i + 1, j + 1), q(i, j + 1)))
    ]
    aero = AeroTriangles(
        12,
        tris,
        wind=(3.0, -1.0, 4.0),
        density=RHO,
        drag_coefficient=CD,
        lift_coefficient=CL,
        gust_amplitude=0.3,
    )
    x, v, p = (
        flat + 0.05 * rng.normal(size=flat.shape),
        rng.normal(size=flat.shape),
        rng.normal(size=flat.shape),
    )
    assert_passes_match_element_arrays(aero, x, v, p, h=0.01)


def test_thirds_and_scaling():
    rng = np.random.default_rng(6)
    x = random_triangle(rng)
    w = rng.normal(size=3)
    f, _, _, _ = forces(term(wind=w), x)
    assert np.array_equal(f[0], f[1]) and np.array_equal(f[0], f[2])
    # The sum over the vertices against an independent NumPy evaluation of the docstring's formulas.
    c = np.cross(x[1] - x[0], x[2] - x[0])
    area, n = 0.5 * np.linalg.norm(c), c / np.linalg.norm(c)
    s, un = np.linalg.norm(w), n @ w
    ref = 0.5 * RHO * area * (CD * abs(un) * w + CL * un * (s * n - un * w / s))
    tol = 50 * EPS * np.abs(ref).max()
    np.testing.assert_allclose(f.sum(axis=0), ref, rtol=0, atol=tol)

    def total(**kw):
        return forces(term(**{"wind": w, **kw}), x)[0].sum(axis=0)

    np.testing.assert_allclose(total(density=2 * RHO), 2 * ref, rtol=0, atol=2 * tol)
    np.testing.assert_allclose(
        total(drag_coefficient=2 * CD), ref + total(lift_coefficient=0.0), atol=2 * tol
    )
    np.testing.assert_allclose(
        total(lift_coefficient=3 * CL), ref + 2 * total(drag_coefficient=0.0), atol=4 * tol
    )
    np.testing.assert_allclose(total(wind=3 * w), 9 * ref, rtol=0, atol=9 * tol)


def test_gust_scales_the_wind():
    a, freq = 0.4, 2.5
    gusty = term(wind=(1.0, 0.5, 2.0), gust_amplitude=a, gust_frequency=freq)
    f0, _, _, _ = forces(term(wind=(1.0, 0.5, 2.0)), UNIT)
    # sin(2 pi f t) = +1 at t = 1/(4f) and -1 at 3/(4f): wind (1 +- a), force (1 +- a)^2.
    for t, k in ((0.25 / freq, 1 + a), (0.75 / freq, 1 - a)):
        f, _, _, _ = forces(gusty, UNIT, t=t)
        np.testing.assert_allclose(f, k**2 * f0, rtol=0, atol=50 * EPS * np.abs(f0).max())


# ---- 6. terminal speed of a falling sheet


def test_falling_sheet_reaches_terminal_speed():
    m, g = 0.01, 9.81  # a 10 g sheet of area 1 (UNIT), horizontal, in still air
    aero = term(lift_coefficient=CL)
    v_t = math.sqrt(2 * m * g / (RHO * CD * 1.0))
    tau = v_t / g  # v(t) = v_t tanh(t / tau)
    dt, steps = tau / 200, 1200  # six time constants: tanh(6) = 1 - 1.2e-5
    x, v = UNIT.copy(), np.zeros((3, 3))
    for step in range(1, steps + 1):
        f, _, _, _ = forces(aero, x, v)
        acc = f / (m / 3) + [0.0, 0.0, -g]
        x, v = x + dt * v, v + dt * acc
        if step == 200:  # t = tau: on the tanh curve up to explicit Euler's global error O(dt / tau)
            assert abs(np.linalg.norm(v[0]) - v_t * math.tanh(1.0)) < (dt / tau) * v_t
    speed = np.linalg.norm(v, axis=1)
    assert np.ptp(speed) < 1e-12 * v_t  # the sheet falls flat: equal forces per vertex
    assert abs(speed[0] - v_t) < 0.01 * v_t
    assert abs(v[:, :2]).max() < 1e-12 * v_t  # no lift when falling flat


# ---- 7. parameters


@pytest.mark.parametrize(
    "kw, name",
    [
        ({"density": 0.0}, "density"),
        ({"density": float("nan")}, "density"),
        ({"drag_coefficient": -1.0}, "drag_coefficient"),
        ({"lift_coefficient": -0.1}, "lift_coefficient"),
        ({"wind": (1.0, 2.0)}, "wind"),
        ({"wind": (1.0, float("inf"), 0.0)}, "wind"),
        ({"gust_amplitude": 1.5}, "gust_amplitude"),
        ({"gust_frequency": -2.0}, "gust_frequency"),
        ({"triangles": [[0, 1, 3]]}, "triangles"),
        ({"triangles": [[0, 1]]}, "triangles"),
        ({"triangles": np.zeros((0, 3), int)}, "triangles"),
        ({"particle_count": 2}, "particle_count"),
    ],
)
def test_parameter_errors(kw, name):
    args = {"particle_count": 3, "triangles": [[0, 1, 2]], **kw}
    with pytest.raises(ParameterError, match=name):
        AeroTriangles(args.pop("particle_count"), args.pop("triangles"), **args)


def test_settings_and_energy():
    aero = term(wind=(1.0, 0.0, 0.0), gust_amplitude=0.2, gust_frequency=1.0)
    assert aero.settings() == {
        "type": "aero_triangles",
        "count": 1,
        "wind": (1.0, 0.0, 0.0),
        "density": RHO,
        "drag_coefficient": CD,
        "lift_coefficient": CL,
        "gust_amplitude": 0.2,
        "gust_frequency": 1.0,
    }
    assert aero.has_energy is False and aero.arity == 3
    assert aero.energy(UNIT) == 0.0
