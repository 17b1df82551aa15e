"""Cloth in the implicit solve and under every integrator: the spring Jacobian products against central
differences of the forces, the compressed system's definiteness, the linear solvers against a dense NumPy
solve, and explicit and implicit integration against a SciPy reference of the same ODE.

Forces are evaluated for many perturbed configurations at once on a model holding that many copies of
the cloth: each `model.forces` call compiles its kernel anew (~0.5 s), one call on the copies is one.
"""

import functools

import numpy as np
import pytest

import taichi_anim as ta

G = np.array([0.0, -9.81, 0.0])
DRAG = 0.01  # [kg/s]
NX, NY = 5, 4
SIZE = (0.4, 0.3)


def mesh_vertices_triangles():
    """A perturbed 5x4 grid with alternating quad diagonals: a general mesh (rest lengths all differ)."""
    rng = np.random.default_rng(3)
    dx, dz = SIZE[0] / (NX - 1), SIZE[1] / (NY - 1)
    i, j = np.meshgrid(np.arange(NX), np.arange(NY))
    v = np.stack([i.ravel() * dx, np.zeros(NX * NY), j.ravel() * dz], axis=1)
    v += rng.uniform(-0.15, 0.15, v.shape) * np.array([dx, 0.3 * dx, dz])
    tris = []
    for jj in range(NY - 1):
        for ii in range(NX - 1):
            v00, v10 = jj * NX + ii, jj * NX + ii + 1
            v01, v11 = v00 + NX, v10 + NX
            if (ii + jj) % 2 == 0:
                tris += [(v00, v11, v10), (v00, v01, v11)]
            else:
                tris += [(v00, v01, v10), (v10, v01, v11)]
    return v + np.array([0.0, 1.0, 0.0]), np.array(tris)


def build(scene, copies=1):
    """`copies` identical, independent cloths (same rest shape) with gravity and drag.

    "grid": a 5x4 grid pinned at two corners; "anchored": the same with a damped anchor spring on
    vertex 7; "mesh": the perturbed mesh above from add_cloth_mesh, pinned at vertex 0.
    """
    material = ta.ClothMaterial()  # stretch 1e3, shear 1e2, bend 10 N/m, all damped
    b = ta.Builder()
    for _ in range(copies):
        if scene in ("grid", "anchored"):
            cloth = b.add_cloth_grid(
                origin=(0, 1, 0), size=SIZE, resolution=(NX, NY), material=material, pinned=[0, NX - 1]
            )
            if scene == "anchored":
                b.add_force_anchor_spring(
                    cloth.particles[7], (0.1, 1.2, 0.05), stiffness=30.0, rest_length=0.05, damping=0.2
                )
        else:
            b.add_cloth_mesh(mesh_vertices_triangles(), material=material, pinned=[0])
    b.add_force_gravity(G)
    b.add_force_drag(DRAG)
    return b.finalize()


def masses(model):
    return model.particle_masses()


def spring_lengths(model, x):
    p = model.springs.pairs
    return np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=1)


def deformed(model, scale, seed=0):
    """Rest positions scaled by `scale` about their centroid plus a small random perturbation."""
    x0 = model.state().positions()
    c = x0.mean(axis=0)
    rng = np.random.default_rng(seed)
    return c + scale * (x0 - c) + 1e-3 * rng.normal(size=x0.shape) * SIZE[0] / NX


def forces_of_copies(scene, xs, vs):
    """model.forces for each configuration (xs[k], vs[k]) (K, N, 3), on one model of K cloth copies."""
    k, n = xs.shape[:2]
    model = build(scene, copies=k)
    return model.forces(xs.reshape(-1, 3), vs.reshape(-1, 3)).reshape(k, n, 3)


def spring_matrix(model, x, h):
    """Dense sum over springs of S_s = -(h df/dv + h^2 df/dx) on (3N, 3N) (Baraff & Witkin 1998, eq. 16,
    the damping's x-derivative left out): S = (h c + h^2 k) n n^T + h^2 k max(1 - L/l, 0) (I - n n^T),
    the transverse factor clamped at 0 under compression (Choi & Ko 2002, sec. 5)."""
    n = model.particle_count
    a = np.zeros((n, 3, n, 3))
    sp = model.springs
    d = x[sp.pairs[:, 0]] - x[sp.pairs[:, 1]]
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    transverse = np.maximum(1.0 - sp.rest_length / length, 0.0)
    for (i, j), k, c, tr, e in zip(sp.pairs, sp.stiffness, sp.damping, transverse, u, strict=True):
        nn = np.outer(e, e)
        s = (h * c + h * h * k) * nn + h * h * k * tr * (np.eye(3) - nn)
        a[i, :, i, :] += s
        a[j, :, j, :] += s
        a[i, :, j, :] -= s
        a[j, :, i, :] -= s
    return a.reshape(3 * n, 3 * n)


def dense_system(model, x, h):
    """A = M + h c_drag I + sum_s S_s (3N, 3N) for a model with springs, gravity and drag only (gravity
    has no Jacobian, drag's df/dv = -c_drag I)."""
    m = masses(model)
    return np.diag(np.repeat(m + h * DRAG, 3)) + spring_matrix(model, x, h)


def implicit_system(model, x, v, h, solver="pcg"):
    """The engine's implicit system of `model` assembled at (x, v) for step h (created by one step)."""
    integ = ta.IntegratorImplicitEuler(linear_solver=solver, tol=1e-10, max_iterations=2000)
    state = model.state()
    integ.step(model, state, h)
    integ.system.assemble(x, v, h)
    return integ.system


# ---------------------------------------------------------------- Jacobians against finite differences


@pytest.mark.parametrize("scene", ["anchored", "mesh"])
def test_implicit_matrix_and_rhs_match_central_differences_of_forces(scene):
    # A(h) p = M p - h (df/dv) p - h^2 (df/dx) p and b = h (f + h (df/dx) v) (Baraff & Witkin 1998,
    # eq. 6 and 15). df/dx p and df/dv p are the central differences (f(x + e p) - f(x - e p)) / 2e:
    # truncation O(e^2 f''') ~ 1e-12 k / L^2 and round-off ~ 1e-16 |f| / e, both far below 1e-7.
    model = build(scene)
    n = model.particle_count
    m = masses(model)
    free = m > 0
    x = deformed(model, 1.05)
    # Every spring stretched: the compression clamp is inactive and df/dx is the exact derivative;
    # v = 0 in the x-differences because the damping's x-derivative is left out of A.
    assert np.all(spring_lengths(model, x) > model.springs.rest_length)
    rng = np.random.default_rng(11)
    p = rng.normal(size=(n, 3))
    p[~free] = 0.0  # the solvers keep iterates 0 at pinned particles
    u = rng.normal(size=(n, 3))
    ex, ev = 1e-6, 1e-3  # f is linear in v, so a large v-step has no truncation error
    z = np.zeros((n, 3))
    xs = np.array([x + ex * p, x - ex * p, x, x, x, x + ex * u, x - ex * u])
    vs = np.array([z, z, ev * p, -ev * p, u, z, z])
    f = forces_of_copies(scene, xs, vs)
    fd_kx_p = (f[0] - f[1]) / (2 * ex)
    fd_kv_p = (f[2] - f[3]) / (2 * ev)
    f_xu = f[4]
    fd_kx_u = (f[5] - f[6]) / (2 * ex)

    h1, h2 = 1.0 / 60.0, 1.0 / 30.0
    system = implicit_system(model, x, z, h1)
    a1 = system.matvec(p)
    system.assemble(x, u, h2)
    a2 = system.matvec(p)
    b2 = system.rhs.to_numpy()[: len(x)]  # capacity rows under buckets

    # Two step sizes separate the stiffness and damping products: A(h) p - M p = -h Kv p - h^2 Kx p.
    r1, r2 = (a - m[:, None] * p for a in (a1, a2))
    det = h1 * h2**2 - h2 * h1**2
    kv_p = -(h2**2 * r1 - h1**2 * r2) / det
    kx_p = -(h2 * r1 - h1 * r2) / (h1**2 * h2 - h2**2 * h1)
    assert np.all(a1[~free] == 0) and np.all(a2[~free] == 0) and np.all(b2[~free] == 0)

    def close(actual, expected, rtol):
        err = np.linalg.norm(actual[free] - expected[free])
        assert err <= rtol * np.linalg.norm(expected[free]), (err, np.linalg.norm(expected[free]))

    close(kx_p, fd_kx_p, 1e-7)
    close(kv_p, fd_kv_p, 1e-7)
    close(a1, m[:, None] * p - h1 * fd_kv_p - h1**2 * fd_kx_p, 1e-8)
    close(b2, h2 * (f_xu + h2 * fd_kx_u), 1e-8)


# ---------------------------------------------------------------- compression: the definiteness fix


def test_compressed_cloth_system_is_symmetric_positive_definite():
    # At 0.8 x the rest shape every spring is compressed: the exact df/dx has a transverse part
    # -k (1 - L/l) (I - n n^T) = +0.25 k (I - n n^T), which makes M - h^2 df/dx indefinite at cloth
    # stiffness (h^2 k / 4 = 0.07 kg >> m = 1e-3 kg). The clamp (Choi & Ko 2002, sec. 5) keeps every
    # S_s positive semi-definite, so A = M + h c I + sum S_s >= m_min I.
    h = 1.0 / 60.0
    model = build("grid")
    n = model.particle_count
    m = masses(model)
    free = np.repeat(m > 0, 3)
    x = deformed(model, 0.8, seed=5)
    assert np.all(spring_lengths(model, x) < model.springs.rest_length)

    # The engine's A equals the dense clamped matrix on two random probes, and is symmetric.
    rng = np.random.default_rng(2)
    p, q = (rng.normal(size=(n, 3)) * (m > 0)[:, None] for _ in range(2))
    system = implicit_system(model, x, np.zeros((n, 3)), h)
    ap, aq = system.matvec(p).ravel(), system.matvec(q).ravel()
    a = dense_system(model, x, h)
    a[~free] = 0.0
    scale = np.abs(a).max()
    np.testing.assert_allclose(ap, a @ p.ravel(), rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(aq, a @ q.ravel(), rtol=0, atol=1e-13 * scale)
    assert abs(p.ravel() @ aq - q.ravel() @ ap) <= 1e-12 * scale * n

    aff = a[np.ix_(free, free)]
    assert np.linalg.eigvalsh(aff).min() >= m[m > 0].min() * (1 - 1e-9)

    # The exact Jacobian (central differences, no clamp) makes M - h df/dv - h^2 df/dx indefinite here,
    # so the bound above is the clamp's doing.
    e = 1e-6
    basis = np.eye(3 * n).reshape(3 * n, n, 3)[free]
    k = len(basis)
    xs = np.concatenate([x + e * basis, x - e * basis, np.repeat(x[None], 2 * k, axis=0)])
    vs = np.concatenate([0 * basis, 0 * basis, e * basis, -e * basis])
    f = forces_of_copies("grid", xs, vs).reshape(4 * k, -1)[:, free]
    kx = ((f[:k] - f[k : 2 * k]) / (2 * e)).T  # column j is df/dx_j (free block)
    kv = ((f[2 * k : 3 * k] - f[3 * k :]) / (2 * e)).T
    exact = np.diag(np.repeat(m, 3)[free]) - h * kv - h * h * kx
    assert np.linalg.eigvalsh(0.5 * (exact + exact.T)).min() < -10 * m.max()


# ---------------------------------------------------------------- linear solvers against a dense solve


def test_linear_solvers_match_dense_solve_and_report_true_residuals():
    # One stiff system (all spring families at 100x the default, k_stretch = 1e5 N/m, h = 1/60 s) for
    # every check, so it is assembled and compiled once. The solvers stop at |b - A x| <= tol |b|; the
    # forward error then obeys |x - x*| / |x*| <= cond(A) |b - A x| / |b| (any norm-consistent bound).
    tol = 1e-8
    material = ta.ClothMaterial(stretch_stiffness=1e5, shear_stiffness=1e4, bend_stiffness=1e3)
    b = ta.Builder()
    b.add_cloth_grid(origin=(0, 1, 0), size=(0.5, 0.5), resolution=(8, 8), material=material, pinned=[0, 7])
    b.add_force_gravity(G)
    b.add_force_drag(DRAG)
    model = b.finalize()
    n = model.particle_count
    h = 1.0 / 60.0
    m = masses(model)
    free = np.repeat(m > 0, 3)
    x = deformed(model, 1.03)
    v = 0.5 * np.random.default_rng(1).normal(size=(n, 3))
    solvers = {
        kind: ta.make_linear_solver(kind, tol=tol, max_iterations=20000, warm_start=True)
        for kind in ("pcg", "cg", "jacobi")
    }
    integ = ta.IntegratorImplicitEuler(linear_solver=solvers["pcg"])
    integ.step(model, model.state(), h)
    system = integ.system
    system.assemble(x, v, h)

    a = dense_system(model, x, h)
    probe = np.random.default_rng(4).normal(size=(n, 3)) * (m > 0)[:, None]
    np.testing.assert_allclose(
        system.matvec(probe).ravel()[free], (a @ probe.ravel())[free], rtol=0, atol=1e-12 * np.abs(a).max()
    )
    a = a[np.ix_(free, free)]
    rhs = system.rhs.to_numpy().ravel()
    assert np.all(rhs[~free] == 0)
    rhs = rhs[free]
    exact = np.linalg.solve(a, rhs)
    cond = np.linalg.cond(a)

    def true_residual(sol):
        return np.linalg.norm(rhs - a @ sol[free]) / np.linalg.norm(rhs)

    iterations = {}
    for kind, solver in solvers.items():
        system.solution.from_numpy(np.zeros((n, 3)))  # a warm start from 0 is a cold start
        result = solver.solve(system)
        sol = system.solution.to_numpy().ravel()
        iterations[kind] = result.iterations
        r = true_residual(sol)
        assert result.converged and result.residual <= tol, (kind, result)
        # The reported residual is |b - A x| / |b| of the returned x (CG's recursive residual drifts from
        # the true one by ~ eps cond |b| only).
        assert abs(result.residual - r) <= 1e-4 * r + 1e-15 * cond, (kind, result.residual, r)
        err = np.linalg.norm(sol[free] - exact) / np.linalg.norm(exact)
        assert err <= cond * r * (1 + 1e-6), (kind, err, cond, r)
        assert np.all(sol[~free] == 0.0), kind  # pinned rows stay exactly 0
        # Warm start from the dense solution: the first residual test passes, no iteration runs.
        system.solution.from_numpy(_unfree(exact, free, n))
        again = solver.solve(system)
        assert again.iterations == 0 and again.converged, (kind, again)
        np.testing.assert_array_equal(system.solution.to_numpy().ravel()[free], exact)

    # Block-Jacobi preconditioning removes the spread of masses and spring counts between vertices.
    assert iterations["pcg"] < 0.75 * iterations["cg"], iterations
    assert iterations["cg"] < iterations["jacobi"], iterations

    capped = ta.make_linear_solver("jacobi", tol=tol, max_iterations=7, warm_start=False)
    result = capped.solve(system)
    r = true_residual(system.solution.to_numpy().ravel())
    assert result.iterations == 7 and not result.converged and result.residual > tol, result
    assert abs(result.residual - r) <= 1e-9 * r, (result.residual, r)


def _unfree(values, free, n):
    """(N,3) array with `values` on the free components and 0 on pinned ones."""
    out = np.zeros(3 * n)
    out[free] = values
    return out.reshape(n, 3)


# ---------------------------------------------------------------- integrators on cloth

T = 0.2  # [s]
SOFT = ta.ClothMaterial(
    density=1.0,
    stretch_stiffness=20.0,
    stretch_damping=0.02,
    shear_stiffness=2.0,
    shear_damping=0.005,
    bend_stiffness=0.5,
    bend_damping=0.001,
)


def soft_cloth():
    """A 4x4 cloth (0.3 m, 0.01 kg per inner vertex, stiffest mode ~ 100 rad/s) pinned at two corners,
    falling from rest under gravity with drag: no collisions, a smooth solution."""
    b = ta.Builder()
    b.add_cloth_grid(origin=(0, 1, 0), size=(0.3, 0.3), resolution=(4, 4), material=SOFT, pinned=[0, 3])
    b.add_force_gravity(G)
    b.add_force_drag(DRAG)
    return b.finalize()


def numpy_forces(model, x, v):
    """f = m g - c v + sum of damped springs -(k (l - L) + c_s (v_i - v_j).n) n (Baraff & Witkin eq. 16)."""
    sp = model.springs
    f = masses(model)[:, None] * G - DRAG * v
    d = x[sp.pairs[:, 0]] - x[sp.pairs[:, 1]]
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    dv = v[sp.pairs[:, 0]] - v[sp.pairs[:, 1]]
    fs = -(sp.stiffness * (length - sp.rest_length) + sp.damping * np.sum(dv * u, axis=1))[:, None] * u
    np.add.at(f, sp.pairs[:, 0], fs)
    np.add.at(f, sp.pairs[:, 1], -fs)
    return f


@functools.cache
def soft_cloth_reference():
    """Positions at T from SciPy's DOP853 (rtol = atol = 1e-13) on the same ODE in NumPy; pinned
    vertices (mass 0) keep their zero velocity. Returns (x0, x(T)) (cached: NumPy arrays only, so the
    result outlives the Taichi runtime of the test that computed it)."""
    from scipy.integrate import solve_ivp

    model = soft_cloth()
    x0 = model.state().positions()
    n = len(x0)
    m = masses(model)
    inv_m = np.divide(1.0, m, out=np.zeros_like(m), where=m > 0)

    def rhs(_, y):
        x, v = y[: 3 * n].reshape(n, 3), y[3 * n :].reshape(n, 3)
        return np.concatenate([v.ravel(), (numpy_forces(model, x, v) * inv_m[:, None]).ravel()])

    y0 = np.concatenate([x0.ravel(), np.zeros(3 * n)])
    sol = solve_ivp(rhs, (0, T), y0, method="DOP853", rtol=1e-13, atol=1e-13)
    return x0, sol.y[: 3 * n, -1].reshape(n, 3)


def soft_cloth_error(integrator, model, state, steps):
    """Max vertex distance at T from the reference after `steps` steps; the state is reset to t = 0
    (the forces do not depend on t) so kernels compiled for it are reused."""
    x0, reference = soft_cloth_reference()
    state.particle_x.from_numpy(x0)
    state.particle_v.from_numpy(np.zeros_like(x0))
    for _ in range(steps):
        integrator.step(model, state, T / steps)
    x = state.positions()
    pinned = masses(model) == 0
    np.testing.assert_array_equal(x[pinned], x0[pinned])  # kinematic: velocity 0 kept
    return float(np.abs(x - reference).max())


def test_numpy_forces_are_the_model_forces():
    # The reference ODE is only a reference if its right-hand side is the engine's force.
    model = soft_cloth()
    rng = np.random.default_rng(9)
    x = model.state().positions() + 0.02 * rng.normal(size=(16, 3))
    v = rng.normal(size=(16, 3))
    np.testing.assert_allclose(model.forces(x, v), numpy_forces(model, x, v), rtol=0, atol=1e-13)


@pytest.mark.parametrize(
    "name, options, order, steps",
    [
        ("explicit_euler", {}, 1, (400, 800)),
        ("symplectic_euler", {}, 1, (200, 400)),
        ("implicit_euler", {"tol": 1e-12, "max_iterations": 1000}, 1, (200, 400)),
        ("midpoint", {}, 2, (50, 100)),
        ("rk4", {}, 4, (40, 80)),
    ],
    ids=["explicit_euler", "symplectic_euler", "implicit_euler", "midpoint", "rk4"],
)
def test_fixed_step_integrators_converge_on_cloth_at_their_order(name, options, order, steps):
    # Global error e(dt) = C dt^p + O(dt^(p+1)): halving dt divides it by 2^p (ratios allowed
    # 2^p x [0.8, 1.3]; the next term shifts them by O(dt)). With these steps every method is within
    # 1 mm of the reference on a 0.18 m fall, so they agree with each other.
    soft_cloth_reference()
    model = soft_cloth()
    state = model.state()
    integrator = ta.make_integrator(name, **options)
    errors = [soft_cloth_error(integrator, model, state, s) for s in steps]
    ratio = errors[0] / errors[1]
    print(f"{name}: errors {errors}, ratio {ratio:.3f}")
    assert 0.8 * 2**order <= ratio <= 1.3 * 2**order
    assert errors[1] < 1e-3
    assert errors[1] > 1e3 * np.finfo(float).eps  # the ratio measured truncation, not round-off


@pytest.mark.parametrize("name", ["rk45", "adaptive"])
def test_adaptive_integrators_meet_their_tolerance_on_cloth(name):
    # Error control keeps each step's local error below tol (on u = (x, v)); over T the global error
    # stays within a few tol here. 10 outer steps of 20 ms: the controllers pick the substeps.
    tol = 1e-8
    options = {"rtol": tol, "atol": tol} if name == "rk45" else {"tol": tol}
    model = soft_cloth()
    integrator = ta.make_integrator(name, **options)
    error = soft_cloth_error(integrator, model, model.state(), 10)
    print(f"{name}: error {error:.3g}")
    assert error <= 10 * tol


# ---------------------------------------------------------------- Newton on backward Euler


def be_residual(model, x0, v0, v1, h):
    """|g(v1)|_{M^-1} on the free particles, g = M (v1 - v0) - h f(x0 + h v1, v1) (Baraff & Witkin, eq. 4:
    the nonlinear backward-Euler step), from the model's forces."""
    m = masses(model)
    free = m > 0
    g = m[:, None] * (v1 - v0) - h * model.forces(x0 + h * v1, v1)
    return float(np.sqrt(np.sum(np.sum(g[free] ** 2, axis=1) / m[free])))


def one_implicit_step(model, x0, v0, h, **options):
    """v1 and x1 after one implicit Euler step from (x0, v0), and the integrator."""
    state = model.state()
    state.particle_x.from_numpy(x0)
    state.particle_v.from_numpy(v0)
    integ = ta.IntegratorImplicitEuler(tol=1e-12, max_iterations=2000, **options)
    integ.step(model, state, h)
    return state.velocities(), state.positions(), integ


@pytest.mark.parametrize("line_search", [False, True], ids=["plain", "line_search"])
def test_newton_solves_the_nonlinear_backward_euler_step(line_search):
    # A cloth stretched to 1.3x its rest size, released at h = 1/30 s (stiff: h w_max ~ 30). The
    # linearised step leaves a large residual of eq. 4 (rotating springs are nonlinear); Newton drives
    # it below newton_tol times the residual at v0, checked here with the model's own forces in NumPy
    # (the loop's own residual must be the same number), and x1 = x0 + h v1, pinned vertices keep v = 0.
    # The step overshoots into compression, where the springs' Hessian is projected (axial part only),
    # so Newton converges linearly there: a tolerance of 1e-3 takes 3 iterations, 1e-6 would stall.
    model = build("grid")
    h = 1.0 / 30.0
    x0 = deformed(model, 1.3)
    v0 = np.zeros_like(x0)
    start = be_residual(model, x0, v0, v0, h)
    v_lin, _, _ = one_implicit_step(model, x0, v0, h)
    v1, x1, integ = one_implicit_step(
        model, x0, v0, h, newton_iterations=30, newton_tol=1e-3, line_search=line_search
    )
    linear = be_residual(model, x0, v0, v_lin, h)
    newton = be_residual(model, x0, v0, v1, h)
    print(f"|g| at v0 {start:.3g}, linearised {linear:.3g}, Newton {newton:.3g}, {integ.last_newton}")
    assert linear > 1e-2 * start  # the nonlinearity matters here
    iterations, rel, converged = integ.last_newton
    assert converged and iterations >= 2
    assert newton <= 1e-3 * start
    np.testing.assert_allclose(newton / start, rel, rtol=1e-6)
    np.testing.assert_allclose(x1, x0 + h * v1, rtol=0, atol=1e-12)
    assert np.all(v1[masses(model) == 0] == 0.0)
    counts = integ.health.counts
    assert counts["newton_solves"] == 1 and counts["newton_iterations"] == iterations
    assert counts["linear_solves"] == iterations and counts["newton_unconverged"] == 0


def test_one_newton_iteration_is_the_linearised_step():
    # newton_iterations=1 (the default) is Baraff & Witkin's linearised step, bit for bit, and counts
    # one linear solve per step and no Newton loop.
    model = build("anchored")
    x0 = deformed(model, 1.1)
    v0 = 0.1 * np.random.default_rng(1).normal(size=x0.shape)
    v0[masses(model) == 0] = 0.0
    va, _, ia = one_implicit_step(model, x0, v0, 0.01)
    vb, _, ib = one_implicit_step(model, x0, v0, 0.01, newton_iterations=1, line_search=True)
    np.testing.assert_array_equal(va, vb)
    assert ib.health.counts["linear_solves"] == 1 and "newton_solves" not in ib.health.counts
    assert ib.last_newton is None


def test_linear_solve_at_its_cap_is_counted_and_reported():
    # max_iterations=3 cannot reach tol 1e-12 on the stretched cloth: the solve is counted as
    # unconverged with its iterations and true residual, warned once (SolverWarning), and raised as
    # ConvergenceError under the policy nonconvergence="raise".
    model = build("grid")
    x0 = deformed(model, 1.2)
    state = model.state()
    state.particle_x.from_numpy(x0)
    integ = ta.IntegratorImplicitEuler(tol=1e-12, max_iterations=3)
    with pytest.warns(ta.SolverWarning, match="stopped at its cap of 3 iterations at step 1"):
        integ.step(model, state, 0.02)
    first = integ.linear_solver.last
    state.particle_x.from_numpy(x0)
    integ.step(model, state, 0.02)
    health = integ.stepper_for(model).health
    assert health.counts["linear_solves"] == 2 and health.counts["linear_unconverged"] == 2
    assert health.counts["linear_iterations"] == 6
    event = health.events[0]
    assert event["kind"] == "linear_unconverged" and event["step"] == 1 and event["iterations"] == 3
    assert event["residual"] == first.residual > 1e-12 and not first.converged
    assert [e["step"] for e in health.events] == [1, 2]
    strict = ta.IntegratorImplicitEuler(tol=1e-12, max_iterations=3, policy={"nonconvergence": "raise"})
    state.particle_x.from_numpy(x0)
    with pytest.raises(ta.ConvergenceError, match="cap of 3 iterations"):
        strict.step(model, state, 0.02)
