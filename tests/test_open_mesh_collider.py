"""An open triangle mesh at the default thickness 0 stops point particles in both collision modes
(collision/mesh_collider.py and response.py): a particle thrown at a table top (an open square of two
triangles, or a 4 x 4 grid) at 1, 10 and 100 m/s never passes below it. Before, it fell straight through
in both modes: the swept test took its normal from a contact vector of zero length, and projection never
finds a particle inside a surface with no inside."""

import numpy as np
import pytest

import taichi_anim as ta

SPEEDS = [1.0, 10.0, 100.0]


def table_top(n: int):
    """(vertices, faces) of the open square [-0.5, 0.5]^2 at y = 0, n x n vertices (n = 2: two
    triangles), faces wound both ways in checkerboard (an open mesh need not be oriented)."""
    s = np.linspace(-0.5, 0.5, n)
    v = np.array([(x, 0.0, z) for z in s for x in s])
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            a, b, c, d = j * n + i, j * n + i + 1, (j + 1) * n + i, (j + 1) * n + i + 1
            tris = [(a, c, b), (b, c, d)] if (i + j) % 2 else [(a, b, c), (b, d, c)]
            faces += tris
    return v, np.array(faces)


# One compile of the mesh's swept test takes ~30 s: the default run covers both modes in f32 on the grid
# top; the two-triangle top and f64 are in the slow set.
SLOW = pytest.mark.slow


@pytest.mark.parametrize(
    "mode, n, precision",
    [
        ("projection", 4, "f32"),
        ("backward", 4, "f32"),
        pytest.param("projection", 2, "f64", marks=SLOW),
        pytest.param("backward", 2, "f64", marks=SLOW),
    ],
)
def test_a_particle_thrown_at_a_table_top_stays_above_it(mode, n, precision):
    """Pass: three point particles, one per speed (1, 10, 100 m/s), thrown down and sideways at the
    table from 0.3 m above it under gravity, restitution 0 (so they stay on it), 90 steps of 1/120 s:
    after every step each is above the table plane (y >= -eps, eps = 1e-12 m in f64, 1e-6 m in f32) or
    off its edge; at the end every one rests on it (|y| <= eps and inside the square)."""
    ta.init("cpu", precision=precision)
    eps = 1e-12 if precision == "f64" else 1e-6
    b = ta.Builder()
    b.add_force_gravity()
    x0 = [[-0.2 + 0.2 * k, 0.3, 0.0] for k in range(3)]
    v0 = [[0.1 * s, -s, 0.05 * s] for s in SPEEDS]  # a 10 % sideways part: oblique impacts
    b.add_particles(x0, v0)
    b.add_collider_mesh(table_top(n), restitution=0.0, friction=0.5)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator("symplectic_euler", collision_mode=mode)
    for _ in range(90):
        integ.step(model, state, 1 / 120)
        x = state.positions()
        over = (np.abs(x[:, 0]) <= 0.5) & (np.abs(x[:, 2]) <= 0.5)
        assert np.all(x[over, 1] >= -eps), x
    x = state.positions()
    assert np.all(np.abs(x[:, 1]) <= eps) and np.all(np.abs(x[:, [0, 2]]) <= 0.5), x
