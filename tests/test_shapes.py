"""Rigid shapes' mass properties against closed forms and Monte Carlo integration (shapes.py)."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.errors import ParameterError

RHO = 750.0


def monte_carlo(inside, lo, hi, n=400_000, seed=1):
    """(mass, com, inertia about com, standard errors of mass and of the inertia's entries) of the
    solid `inside(points) -> bool` at density RHO, from n uniform samples of the box [lo, hi]."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(lo, hi, size=(n, 3))
    w = inside(p).astype(np.float64) * RHO * np.prod(np.subtract(hi, lo))  # mass per sample, times n
    mass = w.mean()
    com = (w[:, None] * p).mean(axis=0) / mass
    d = p - com
    outer = np.einsum("ni,nj->nij", d, d)
    density = w[:, None, None] * (np.einsum("ni,ni->n", d, d)[:, None, None] * np.eye(3) - outer)
    inertia = density.mean(axis=0)
    return mass, com, inertia, w.std() / np.sqrt(n), density.std(axis=0) / np.sqrt(n)


def assert_matches_monte_carlo(props, reference, sigmas=5.0):
    mass, com, inertia, mass_err, inertia_err = reference
    assert abs(props.mass - mass) < sigmas * mass_err
    np.testing.assert_allclose(props.com, com, atol=sigmas * mass_err / mass * 1.0 + 1e-12)
    assert np.all(np.abs(props.inertia - inertia) < sigmas * inertia_err + 1e-12)


def test_box_mesh_integrals_equal_the_closed_form():
    # A box of half extents (a, b, c): m = 8 rho a b c, I = m/3 diag(b^2 + c^2, a^2 + c^2, a^2 + b^2).
    box = ta.shapes.Box((0.1, 0.2, 0.35))
    v, f = box.triangles()
    exact = box.mass_properties(RHO)
    assert exact.mass == pytest.approx(8 * RHO * 0.1 * 0.2 * 0.35, rel=1e-14)
    mesh = ta.shapes.Mesh(v, f).mass_properties(RHO)
    assert mesh.mass == pytest.approx(exact.mass, rel=1e-12)
    np.testing.assert_allclose(mesh.com, 0.0, atol=1e-14)
    np.testing.assert_allclose(mesh.inertia, exact.inertia, rtol=1e-12, atol=1e-15)


def test_a_moved_and_turned_mesh_carries_its_mass_properties():
    # com moves with the mesh; the inertia about it turns as R I R^T (and does not move).
    rng = np.random.default_rng(3)
    hull = ta.shapes.ConvexHull(rng.normal(size=(40, 3)))
    base = hull.mass_properties(RHO)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    r = np.eye(3) + np.sin(0.7) * k + (1 - np.cos(0.7)) * k @ k
    shift = np.array([1.5, -2.0, 0.25])
    moved = ta.shapes.Mesh(hull.vertices @ r.T + shift, hull.faces).mass_properties(RHO)
    assert moved.mass == pytest.approx(base.mass, rel=1e-12)
    np.testing.assert_allclose(moved.com, r @ base.com + shift, atol=1e-12)
    np.testing.assert_allclose(moved.inertia, r @ base.inertia @ r.T, atol=1e-11 * np.abs(base.inertia).max())


def test_a_convex_hull_matches_monte_carlo():
    rng = np.random.default_rng(7)
    points = rng.normal(size=(60, 3)) * [0.4, 0.2, 0.3] + [0.5, 0.1, -0.2]
    hull = ta.shapes.ConvexHull(points)
    v, f = hull.vertices, hull.faces
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    offsets = np.einsum("fi,fi->f", normals, v[f[:, 0]])

    def inside(p):
        return np.all(p @ normals.T <= offsets, axis=1)

    reference = monte_carlo(inside, v.min(axis=0), v.max(axis=0))
    assert_matches_monte_carlo(hull.mass_properties(RHO), reference)


@pytest.mark.parametrize("shape", ["sphere", "capsule"])
def test_round_shapes_match_monte_carlo(shape):
    r, h = 0.3, 0.45
    if shape == "sphere":
        s = ta.shapes.Sphere(r)

        def inside(p):
            return np.einsum("ni,ni->n", p, p) <= r * r

        lo, hi = [-r] * 3, [r] * 3
    else:
        s = ta.shapes.Capsule(r, h)

        def inside(p):
            y = np.clip(p[:, 1], -h, h)  # the closest point of the axis segment
            return p[:, 0] ** 2 + (p[:, 1] - y) ** 2 + p[:, 2] ** 2 <= r * r

        lo, hi = [-r, -h - r, -r], [r, h + r, r]
    assert_matches_monte_carlo(s.mass_properties(RHO), monte_carlo(inside, lo, hi))


def test_the_capsule_is_a_cylinder_and_two_caps():
    # A capsule with a vanishing cylinder is a ball: m = 4/3 pi r^3 rho, I = 2/5 m r^2.
    ball = ta.shapes.Sphere(0.2).mass_properties(RHO)
    nearly = ta.shapes.Capsule(0.2, 1e-9).mass_properties(RHO)
    assert nearly.mass == pytest.approx(ball.mass, rel=1e-7)
    np.testing.assert_allclose(nearly.inertia, ball.inertia, rtol=1e-7)


@pytest.mark.parametrize(
    "make, word",
    [
        (lambda: ta.shapes.Sphere(-1.0), "radius"),
        (lambda: ta.shapes.Box((0.1, 0.0, 0.1)), "half_extents"),
        (lambda: ta.shapes.Capsule(0.1, float("nan")), "half_length"),
        (lambda: ta.shapes.ConvexHull(np.zeros((10, 3))), "points span no volume"),
        (lambda: ta.shapes.ConvexHull([[0, 0, 0], [1, 0, 0]]), "points"),
        (lambda: ta.shapes.Mesh(*_open_box()), "closed"),
        (lambda: ta.shapes.Mesh(*_inside_out_box()), "clockwise"),
        (lambda: ta.shapes.Sphere(0.1).mass_properties(0.0), "density"),
    ],
)
def test_bad_shapes_are_refused_with_the_parameter_named(make, word):
    with pytest.raises(ParameterError, match=word):
        make()


def _open_box():
    v, f = ta.shapes.Box((1, 1, 1)).triangles()
    return v, f[:-1]


def _inside_out_box():
    v, f = ta.shapes.Box((1, 1, 1)).triangles()
    return v, f[:, ::-1]
