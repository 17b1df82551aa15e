"""Each pointwise force term's Jacobian (df/dx, df/dv) against central finite differences of its force."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta


@ti.kernel
def force_and_jacobian(
    model: ti.template(),
    x: ti.template(),
    v: ti.template(),
    f: ti.template(),
    kx: ti.template(),
    kv: ti.template(),
):
    for i in range(x.shape[0]):
        f[i] = model.force(0, x[i], v[i], 0.0)
        kx[i], kv[i] = model.force_jacobian(0, x[i], v[i], 0.0)


def evaluate(model, xs, vs):
    n = len(xs)
    x, v, f = (ti.Vector.field(3, float, n) for _ in range(3))
    kx, kv = (ti.Matrix.field(3, 3, float, n) for _ in range(2))
    x.from_numpy(np.asarray(xs))
    v.from_numpy(np.asarray(vs))
    force_and_jacobian(model, x, v, f, kx, kv)
    return f.to_numpy(), kx.to_numpy(), kv.to_numpy()


SCENES = {
    "gravity": lambda b: b.add_force_gravity((0.3, -9.81, 0.1)),
    "drag": lambda b: b.add_force_drag(0.7),
    "wind": lambda b: b.add_force_wind((2.0, 0.0, -1.0), 0.4),
    "anchor_spring": lambda b: b.add_force_anchor_spring(
        0, (0.1, -0.2, 0.3), stiffness=50.0, rest_length=0.5
    ),
    # df/dx leaves out the damping force's dependence on x through the direction (Baraff & Witkin,
    # sec. 5), so the damped spring is checked on df/dv only, below.
    "anchor_spring_damped": lambda b: b.add_force_anchor_spring(
        0, (0.1, -0.2, 0.3), stiffness=50.0, rest_length=0.5, damping=2.0
    ),
}


@pytest.mark.parametrize("term", sorted(SCENES))
def test_jacobian_matches_finite_differences(term):
    b = ta.Builder()
    b.add_particle((0, 0, 0), mass=1.3)
    SCENES[term](b)
    model = b.finalize()
    rng = np.random.default_rng(1)
    x0, v0 = rng.normal(size=3), rng.normal(size=3)
    h = 1e-6
    xs = [x0] + [x0 + s * h * e for e in np.eye(3) for s in (1, -1)] + [x0] * 6
    vs = [v0] + [v0] * 6 + [v0 + s * h * e for e in np.eye(3) for s in (1, -1)]
    f, kx, kv = evaluate(model, xs, vs)
    # column j of df/dx is (f(x + h e_j) - f(x - h e_j)) / 2h
    fd_x = np.stack([(f[1 + 2 * j] - f[2 + 2 * j]) / (2 * h) for j in range(3)], axis=1)
    fd_v = np.stack([(f[7 + 2 * j] - f[8 + 2 * j]) / (2 * h) for j in range(3)], axis=1)
    if term != "anchor_spring_damped":
        np.testing.assert_allclose(kx[0], fd_x, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(kv[0], fd_v, rtol=1e-6, atol=1e-6)


def test_compressed_anchor_spring_jacobian_is_negative_semidefinite():
    # Under compression the exact df/dx has a positive transverse part; the clamped Jacobian keeps
    # -df/dx positive semi-definite so M - h^2 df/dx stays positive definite (Choi & Ko 2002).
    b = ta.Builder()
    b.add_particle((0, 0, 0))
    b.add_force_anchor_spring(0, (0, 0, 0), stiffness=100.0, rest_length=2.0)
    model = b.finalize()
    _, kx, _ = evaluate(model, [[0.5, 0.2, -0.1]], [[0, 0, 0]])
    assert np.linalg.eigvalsh(kx[0]).max() <= 1e-9
