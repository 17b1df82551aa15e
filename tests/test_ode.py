"""ta.ode: general ODE systems u' = F(t, u) against closed forms, with tolerances tied to dt and the
method's order; the Taichi and NumPy paths against each other within the precision's round-off."""

import math

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta

ode = ta.ode
FIXED = ("explicit_euler", "midpoint", "rk4", "implicit_euler")
ORDER = {"explicit_euler": 1, "midpoint": 2, "rk4": 4, "implicit_euler": 1}
G = -9.81


# --- systems ---------------------------------------------------------------------------------------
@ti.func
def free_fall(t, u):
    return ti.Vector([u[1], G])


@ti.func
def wrong_dim(t, u):  # dim=2 is declared: one component is missing
    return ti.Vector([u[1]])


def free_fall_np(t, u):
    return np.stack([u[:, 1], np.full(len(u), G)], axis=1)


# u' = A u + b, a stable 3x3 A (eigenvalues -1, -2 +- 1.5i) and constant b.
A = np.array([[-1.0, 0.0, 0.0], [0.5, -2.0, 1.5], [0.0, -1.5, -2.0]])
B = np.array([1.0, 0.0, 2.0])
A_ROWS, B_LIST = A.tolist(), B.tolist()  # plain lists: the Taichi functions read them as constants


@ti.func
def linear(t, u):
    return ti.Matrix(A_ROWS) @ u + ti.Vector(B_LIST)


@ti.func
def linear_jacobian(t, u):
    return ti.Matrix(A_ROWS)


def linear_exact(u0, t):
    """u(t) = e^{At} (u0 + A^-1 b) - A^-1 b."""
    from scipy.linalg import expm

    w = np.linalg.solve(A, B)
    return expm(A * t) @ (u0 + w) - w


# Lotka–Volterra x' = a x - b x y, y' = d x y - c y; V = d x - c ln x + b y - a ln y is invariant.
LV = (2.0 / 3.0, 4.0 / 3.0, 1.0, 1.0)  # a, b, c, d


@ti.func
def lotka_volterra(t, u):
    a, b, c, d = LV
    return ti.Vector([a * u[0] - b * u[0] * u[1], d * u[0] * u[1] - c * u[1]])


def lotka_volterra_np(t, u):
    a, b, c, d = LV
    x, y = u[:, 0], u[:, 1]
    return np.stack([a * x - b * x * y, d * x * y - c * y], axis=1)


def lv_invariant(u):
    a, b, c, d = LV
    return d * u[..., 0] - c * np.log(u[..., 0]) + b * u[..., 1] - a * np.log(u[..., 1])


# RC circuit charging from V_s through R: V' = (V_s - V) / RC, V(t) = V_s (1 - e^{-t/RC}) from V(0) = 0.
V_S = 5.0


def rc_system(rc):
    return ode.System.numpy(
        lambda t, u: (V_S - u) / rc, 1, jacobian=lambda t, u: np.full((len(u), 1, 1), -1 / rc)
    )


# --- free fall: x(t) = x0 + v0 t + g t^2 / 2 ------------------------------------------------------
@pytest.mark.parametrize("backend", ["taichi", "numpy"])
def test_free_fall_closed_forms(backend):
    system = (
        ode.System(free_fall, 2, split=1)
        if backend == "taichi"
        else ode.System.numpy(free_fall_np, 2, split=1)
    )
    u0, t, dt = np.array([10.0, 3.0]), 1.0, 0.01
    x_exact = u0[0] + u0[1] * t + 0.5 * G * t**2
    v_exact = u0[1] + G * t
    for method in ("midpoint", "rk4"):  # exact for a quadratic x(t): RK2 and RK4 up to round-off
        r = ode.solve(system, u0, (0.0, t), method=method, dt=dt)
        assert r.u == pytest.approx([x_exact, v_exact], abs=1e-12)
    # explicit Euler: x_n = x0 + v0 t + g dt^2 n(n-1)/2, i.e. the closed form minus g t dt / 2
    r = ode.solve(system, u0, (0.0, t), method="explicit_euler", dt=dt)
    assert r.u[0] - x_exact == pytest.approx(-0.5 * G * t * dt, abs=1e-12)
    assert r.u[1] == pytest.approx(v_exact, abs=1e-12)
    # symplectic and implicit Euler use the new velocity: x_n = ... + g dt^2 n(n+1)/2, plus g t dt / 2
    for method in ("symplectic_euler", "implicit_euler"):
        r = ode.solve(system, u0, (0.0, t), method=method, dt=dt)
        assert r.u[0] - x_exact == pytest.approx(0.5 * G * t * dt, abs=1e-10), method
        assert r.u[1] == pytest.approx(v_exact, abs=1e-10), method


# --- u' = A u + b against the matrix exponential: error ~ dt^p and the convergence order -----------
@pytest.mark.parametrize("method", FIXED)
def test_linear_system_order_against_expm(method):
    system = ode.System(linear, 3, jacobian=linear_jacobian)
    u0, t = np.array([1.0, -1.0, 0.5]), 1.0
    exact = linear_exact(u0, t)
    errors = []
    for dt in (0.02, 0.01):
        r = ode.solve(system, u0, (0.0, t), method=method, dt=dt)
        errors.append(np.abs(r.u - exact).max())
        assert errors[-1] < 2.0 * dt ** ORDER[method]  # |A| ~ 2.5, t = 1: the constant is O(1)
    order = math.log2(errors[0] / errors[1])
    assert abs(order - ORDER[method]) < 0.3, (method, errors, order)


@pytest.mark.parametrize(
    "method, options", [("rk45", {"rtol": 1e-10, "atol": 1e-12}), ("adaptive", {"k_max": 1e-11})]
)
def test_adaptive_methods_meet_their_tolerance_against_expm(method, options):
    system = ode.System.numpy(lambda t, u: u @ A.T + B, 3)
    u0, t = np.array([1.0, -1.0, 0.5]), 2.0
    r = ode.solve(system, u0, (0.0, t), method=method, **options)
    # Global error <= accepted steps x the local tolerance (errors decay: A is stable).
    local = options.get("k_max", options.get("rtol", 0) * 2)
    assert np.abs(r.u - linear_exact(u0, t)).max() < r.steps * local
    assert r.steps > 5 and r.evaluations >= r.steps * (7 if method == "rk45" else 12)


def test_implicit_euler_finite_differences_match_the_jacobian_and_count_evaluations():
    u0, t, dt = np.array([1.0, -1.0, 0.5]), 0.5, 0.05
    steps = round(t / dt)
    exact_j = ode.solve(
        ode.System(linear, 3, jacobian=linear_jacobian), u0, (0, t), method="implicit_euler", dt=dt
    )
    fd = ode.solve(ode.System(linear, 3), u0, (0, t), method="implicit_euler", dt=dt)
    # Backward Euler of a linear system: u1 = (I - hA)^-1 (u0 + h b) per step.
    u = u0.copy()
    for _ in range(steps):
        u = np.linalg.solve(np.eye(3) - dt * A, u + dt * B)
    assert exact_j.u == pytest.approx(u, abs=1e-12)
    assert fd.u == pytest.approx(u, abs=1e-8)  # sqrt(eps)-accurate columns, then Newton corrects
    # A linear problem: one Newton iteration, then the residual check (2 evaluations of F per step);
    # finite differences add dim = 3 evaluations per iteration.
    assert exact_j.newton_iterations == steps and exact_j.evaluations == 2 * steps
    assert fd.evaluations >= 5 * steps


# --- Lotka–Volterra: the invariant's drift falls with the method's order --------------------------
def test_lotka_volterra_invariant_drift_decreases_with_order():
    system = ode.System.numpy(lotka_volterra_np, 2)
    u0, t, dt = np.array([1.5, 1.0]), 10.0, 0.01
    v0 = lv_invariant(u0)
    drift = {}
    for method in ("explicit_euler", "midpoint", "rk4"):
        r = ode.solve(system, u0, (0.0, t), method=method, dt=dt, t_eval=np.linspace(1, t, 10))
        drift[method] = np.abs(lv_invariant(r.u_eval) - v0).max()
    r = ode.solve(system, u0, (0.0, t), method="rk45", rtol=1e-9, atol=1e-12)
    drift["rk45"] = abs(lv_invariant(r.u) - v0)
    assert drift["explicit_euler"] > 10 * drift["midpoint"] > 100 * drift["rk4"]
    assert drift["explicit_euler"] < 0.1 and drift["rk4"] < 1e-7 and drift["rk45"] < 1e-7


# --- RC circuit: accuracy, and stability of the stiff case ----------------------------------------
def test_rc_circuit_closed_form():
    rc, t = 0.5, 2.0
    for method, dt, tol in (("rk4", 0.05, 1e-6), ("midpoint", 0.01, 1e-4), ("implicit_euler", 1e-3, 1e-2)):
        r = ode.solve(rc_system(rc), [0.0], (0.0, t), method=method, dt=dt)
        assert r.u[0] == pytest.approx(V_S * (1 - math.exp(-t / rc)), abs=tol), method


def test_stiff_rc_explicit_euler_blows_up_implicit_euler_stays_bounded():
    rc = 1e-3
    dt = 2.5 * rc  # beyond explicit Euler's limit dt < 2 RC: the error grows by |1 - dt/RC| = 1.5 a step
    times = np.arange(1, 41) * dt
    explicit = ode.solve(rc_system(rc), [0.0], (0.0, times[-1]), method="explicit_euler", dt=dt, t_eval=times)
    implicit = ode.solve(rc_system(rc), [0.0], (0.0, times[-1]), method="implicit_euler", dt=dt, t_eval=times)
    assert abs(explicit.u[0] - V_S) == pytest.approx(V_S * 1.5**40, rel=1e-9)
    assert np.all((implicit.u_eval >= 0.0) & (implicit.u_eval <= V_S))  # V_S - V shrinks by 1/(1 + dt/RC)
    assert implicit.u[0] == pytest.approx(V_S, rel=1e-12)
    with pytest.raises(ta.DivergenceError, match="system 0 became non-finite"):
        ode.solve(rc_system(rc), [0.0], (0.0, 5000 * dt), method="explicit_euler", dt=dt)


# --- the two paths, precision, batches ------------------------------------------------------------
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_taichi_and_numpy_paths_agree_within_the_precision(precision):
    ta.init("cpu", precision=precision)
    u0, t, dt = np.array([[1.5, 1.0], [0.8, 1.2]]), 2.0, 0.01
    for method, opts in (("rk4", {}), ("rk45", {"rtol": 1e-6, "atol": 1e-9}), ("implicit_euler", {})):
        if precision == "f32" and method == "rk45":
            opts = {"rtol": 1e-4, "atol": 1e-6}
        rt = ode.solve(ode.System(lotka_volterra, 2), u0, (0, t), method=method, dt=dt, **opts)
        rn = ode.solve(ode.System.numpy(lotka_volterra_np, 2), u0, (0, t), method=method, dt=dt, **opts)
        assert rt.dtype == ("float64" if precision == "f64" else "float32")
        eps = np.finfo(rt.dtype).eps
        # Round-off accumulates ~ eps per step (the solution is O(1)); adaptive runs may also take
        # different steps where an error estimate sits at the threshold: then within the tolerance.
        tol = 100 * eps * rt.steps.max() + (10 * opts["rtol"] if method == "rk45" else 0.0)
        assert np.abs(rt.u - rn.u).max() < tol, (method, rt.u, rn.u)


def test_batch_of_oscillators_each_matches_its_closed_form():
    """u = (x, v, w) with x'' = -w^2 x and w' = 0: x(t) = x0 cos wt + v0 / w sin wt, per system."""

    @ti.func
    def oscillator(t, u):
        return ti.Vector([u[1], -(u[2] ** 2) * u[0], 0.0])

    n = 2000
    w = np.linspace(0.5, 5.0, n)
    u0 = np.stack([np.ones(n), np.linspace(-1, 1, n), w], axis=1)
    t, dt = 1.0, 0.01
    x_exact = u0[:, 0] * np.cos(w * t) + u0[:, 1] / w * np.sin(w * t)
    system = ode.System(oscillator, 3)
    r = ode.solve(system, u0, (0.0, t), method="rk4", dt=dt)
    assert np.abs(r.u[:, 0] - x_exact).max() < 0.1 * (w.max() * dt) ** 4
    assert r.stats()["evaluations"] == 4 * n * round(t / dt)
    # Each system controls its own step: the fastest oscillators need the most steps.
    r = ode.solve(system, u0[::100], (0.0, t), method="rk45", rtol=1e-8, atol=1e-10)
    assert np.abs(r.u[:, 0] - x_exact[::100]).max() < 1e-6
    assert r.steps[-1] > r.steps[0] and np.all(np.diff(r.steps) >= -1)


def test_samples_at_requested_times():
    system = ode.System(linear, 3)
    u0, times = np.array([1.0, -1.0, 0.5]), np.array([0.0, 0.3, 0.75, 1.0])
    r = ode.solve(system, u0, (0.0, 1.5), method="rk4", dt=0.01, t_eval=times)
    assert r.u_eval.shape == (4, 3) and r.t == 1.5
    for k, te in enumerate(times):
        assert r.u_eval[k] == pytest.approx(linear_exact(u0, te), abs=1e-8)  # RK4: ~0.2 dt^4
    assert r.u == pytest.approx(linear_exact(u0, 1.5), abs=1e-8)


# --- step doubling: the course's K_min / K_max rule ------------------------------------------------
def test_step_doubling_follows_k_min_and_k_max():
    system = ode.System.numpy(lambda t, u: u @ A.T + B, 3)
    u0 = np.array([1.0, -1.0, 0.5])
    # k_min = 0: the step never doubles; a first step well inside k_max is never halved either.
    r = ode.solve(system, u0, (0.0, 1.0), method="adaptive", dt=0.01, k_max=1e-3, k_min=0.0)
    assert (r.steps, r.rejected, r.evaluations) == (100, 0, 100 * 3 * 4)
    # The default k_min = k_max / 2^(p+1) lets the step grow: fewer steps for the same k_max.
    grown = ode.solve(system, u0, (0.0, 1.0), method="adaptive", dt=0.01, k_max=1e-3)
    assert grown.steps < 50
    # A first step far above k_max is halved until the error fits.
    r = ode.solve(system, u0, (0.0, 1.0), method="adaptive", dt=1.0, k_max=1e-9)
    assert r.rejected >= 3 and np.abs(r.u - linear_exact(u0, 1.0)).max() < r.steps * 1e-9


def test_adaptive_failure_raises_convergence_error():
    blow_up = ode.System.numpy(lambda t, u: u**2, 1)  # u = 1 / (1 - t) leaves every bound at t = 1
    with pytest.raises(ta.ConvergenceError, match="rk45: system 0"):
        ode.solve(blow_up, [1.0], (0.0, 2.0), method="rk45", max_steps=2000)


# --- bad input --------------------------------------------------------------------------------------
def test_bad_input_raises_parameter_error_naming_it():
    system = ode.System.numpy(free_fall_np, 2)
    cases = [
        (dict(u0=[1.0, 2.0, 3.0]), "u0 must have shape"),
        (dict(u0=[[1.0, np.nan]]), "u0 contains 1 non-finite"),
        (dict(dt=0.0), "dt must be a finite number > 0"),
        (dict(dt=-1.0), "dt must be"),
        (dict(dt=None), "give dt > 0"),
        (dict(method="rk3"), "unknown method 'rk3'"),
        (dict(t_span=(1.0, 0.0)), "t_end > t_start"),
        (dict(t_span=(0.0, np.inf)), r"t_span\[1\] must be a finite"),
        (dict(t_eval=[0.5, 2.0]), "t_eval must increase strictly within"),
        (dict(method="rk45", rtol=-1.0), "rtol must be"),
        (dict(method="rk4", rtol=1e-3), "takes no options"),
        (dict(method="adaptive", base="rk45"), "unknown base 'rk45'"),
        (dict(method="symplectic_euler"), "needs a split system"),
    ]
    for change, message in cases:
        args = {"u0": [0.0, 1.0], "t_span": (0.0, 1.0), "method": "rk4", "dt": 0.1, **change}
        with pytest.raises(ta.ParameterError, match=message):
            ode.solve(system, args.pop("u0"), args.pop("t_span"), **args)
    with pytest.raises(ta.ParameterError, match="f must return an array of shape"):
        ode.solve(ode.System.numpy(lambda t, u: u[:, :1], 2), [0.0, 1.0], (0, 1), dt=0.1)
    with pytest.raises(ta.ParameterError, match="Taichi could not compile"):
        ode.solve(ode.System(wrong_dim, 2), [0.0, 1.0], (0, 1), dt=0.1)
    with pytest.raises(ta.ParameterError, match="f must be a @ti.func"):
        ode.System(free_fall_np, 2)
    with pytest.raises(ta.ParameterError, match="dim must be an integer"):
        ode.System.numpy(free_fall_np, 0)


@pytest.mark.slow
def test_a_million_oscillators_in_one_call():
    @ti.func
    def harmonic(t, u):
        return ti.Vector([u[1], -u[0]])

    n, t, dt = 10**6, 1.0, 0.01
    u0 = np.stack([np.linspace(-1, 1, n), np.zeros(n)], axis=1)
    for system in (
        ode.System(harmonic, 2),
        ode.System.numpy(lambda t, u: np.stack([u[:, 1], -u[:, 0]], 1), 2),
    ):
        r = ode.solve(system, u0, (0.0, t), method="rk4", dt=dt)
        assert np.abs(r.u[:, 0] - u0[:, 0] * math.cos(t)).max() < 1e-9
        assert r.stats()["evaluations"] == 4 * n * 100
