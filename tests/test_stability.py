"""Stability guard: the highest-frequency estimate against dense eigenvalues, each explicit method's step
limit against its closed form and against simulation, the guard's caching and automatic substeps."""

import math
import warnings

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim import stability
from taichi_anim.scenes import make_scene

IGNORE = {"stability": "ignore"}


def spring_pair(m1, m2, k, c=0.0):
    b = ta.Builder()
    b.add_particles(np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]), None, mass=[m1, m2])
    b.add_springs([[0, 1]], stiffness=k, damping=c)
    return b.finalize()


def small_cloth(material, n=6, drag=0.0, anchor=False):
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(
        origin=(0.0, 1.0, 0.0), size=(1.0, 1.0), resolution=(n, n), plane="xz", material=material, pinned=[0]
    )
    if drag:
        b.add_force_drag(drag)
    if anchor:  # a stiff anchor spring on the far corner, stretched by 1 cm
        b.add_force_anchor_spring(n * n - 1, (1.0, 1.01, 1.0), stiffness=5e3, rest_length=0.0, damping=0.02)
    return b.finalize()


def dense_matrices(model, x, eps=1e-6):
    """K = -df/dx and C = -df/dv (3N x 3N) by central differences of the model's total force at (x, 0)."""
    n3 = 3 * model.particle_count
    k = np.zeros((n3, n3))
    c = np.zeros((n3, n3))
    v0 = np.zeros_like(x)
    for j in range(n3):
        dx = np.zeros(n3)
        dx[j] = eps
        dx = dx.reshape(-1, 3)
        k[:, j] = -(model.forces(x + dx, v0) - model.forces(x - dx, v0)).ravel() / (2 * eps)
        c[:, j] = -(model.forces(x, v0 + dx) - model.forces(x, v0 - dx)).ravel() / (2 * eps)
    return k, c


def dense_top(model, x):
    """(omega_max, zeta of the top mode) from numpy.linalg.eigvals of M^-1 K over the free dofs."""
    m = np.repeat(model.particle_masses(), 3)
    free = m > 0
    k, c = dense_matrices(model, x)
    k, c, m = k[free][:, free], c[free][:, free], m[free]
    lam, vec = np.linalg.eig(k / m[:, None])
    top = int(np.argmax(lam.real))
    u = vec[:, top].real
    u /= math.sqrt(u @ (m * u))  # unit in the mass metric
    omega = math.sqrt(lam[top].real)
    return omega, float(u @ c @ u) / (2 * omega)


def test_two_particle_spring():
    # omega = sqrt(k (1/m1 + 1/m2)); with particle 0 pinned (mass 0), sqrt(k / m2).
    for m1, expected in ((0.02, math.sqrt(1e5 * (1 / 0.02 + 1 / 0.01))), (0.0, math.sqrt(1e5 / 0.01))):
        model = spring_pair(m1, 0.01, 1e5)
        est = stability.state_frequency(model, model.state())
        assert est.omega == pytest.approx(expected, rel=1e-9)
        assert expected * (1 - 1e-12) <= est.bound <= 2 * expected


def fabric():
    return ta.FabricMaterial(density=0.2, youngs_modulus=2e3, poisson_ratio=0.3, bending_stiffness=1e-3)


def rayleigh_springs(beta):
    return ta.ClothMaterial(
        stretch_stiffness=1e3,
        stretch_damping=1e3 * beta,
        shear_stiffness=1e2,
        shear_damping=1e2 * beta,
        bend_stiffness=10.0,
        bend_damping=10.0 * beta,
    )


@pytest.mark.parametrize(
    "case",
    [
        "springs",
        "springs_drag_anchor",
        "springs_stretched",
        "membrane",
        # The membrane and bending kernels compile for seconds: the second membrane case runs with -m slow.
        pytest.param("membrane_stretched", marks=pytest.mark.slow),
    ],
)
def test_frequency_against_dense_eigenvalues(case):
    # Reference: numpy.linalg.eigvals of the dense M^-1 K, K by central differences of the engine's total
    # force (independent of the element blocks the estimate uses). At rest and under uniform stretch the
    # terms' projected Hessians are exact, so the two must agree. Lanczos: within [1 - 2e-3, 1.05] of the
    # reference; block Gershgorin: an upper bound within 2x. Springs use their blocks by default; the
    # membrane cloth uses differences of the force by default (checked at rest) and its element blocks
    # with blocks=True (stretched, -m slow: those kernels compile for long).
    material = fabric() if case.startswith("membrane") else rayleigh_springs(5e-5)
    model = small_cloth(material, drag=0.002 if "drag" in case else 0.0, anchor="anchor" in case)
    x = model.state().positions()
    if case.endswith("stretched"):
        x = x * 1.1  # every spring and triangle stretched by 10%: transverse and stress stiffness appear
    ref, zeta_ref = dense_top(model, x)
    est = stability.frequency(model, x, blocks=True if case == "membrane_stretched" else None)
    assert ref * (1 - 2e-3) <= est.omega <= 1.05 * ref
    if case == "membrane":
        assert math.isnan(est.bound)
    else:
        assert ref * (1 - 1e-6) <= est.bound <= 2.0 * ref
    assert est.zeta == pytest.approx(zeta_ref, rel=0.05, abs=1e-4)


def test_rayleigh_damping_ratio():
    # Springs with c = beta k in every family: C = beta K, so every mode has zeta = beta omega / 2.
    beta = 2e-4
    model = small_cloth(rayleigh_springs(beta))
    est = stability.state_frequency(model, model.state())
    assert est.zeta == pytest.approx(beta * est.omega / 2, rel=1e-3)


def test_limits_closed_form():
    w = 1000.0
    rate = math.log1p(stability.GROWTH)
    lim = stability.stability_limit
    assert lim("symplectic_euler", w) == pytest.approx(2 / w, rel=1e-6)  # h w < 2
    zeta = 0.1  # damped oscillator: h w < 2 (sqrt(1 + zeta^2) - zeta)
    damped = 2 * (math.sqrt(1 + zeta**2) - zeta) / w
    assert lim("symplectic_euler", w, zeta) == pytest.approx(damped, rel=1e-6)
    assert lim("rk4", w) == pytest.approx(2 * math.sqrt(2) / w, rel=1e-5)  # |R(iy)| <= 1 for y <= 2 sqrt 2
    # Explicit Euler, undamped: ln |R(i h w)|^2 = ln(1 + h^2 w^2) <= rate h -> h = rate / w^2 (first order).
    assert lim("explicit_euler", w) == pytest.approx(rate / w**2, rel=1e-3)
    # Damped (c = 2 zeta w at the top): |1 + h lambda|^2 = 1 - 2 zeta w h + h^2 w^2 -> h <= 2 zeta / w.
    assert lim("explicit_euler", w, zeta) == pytest.approx(2 * zeta / w, rel=1e-3)
    # Midpoint, undamped: |R(iy)|^2 = 1 + y^4 / 4 -> h^3 w^4 / 4 = rate.
    assert lim("midpoint", w) == pytest.approx((4 * rate / w**4) ** (1 / 3), rel=1e-3)
    assert lim("implicit_euler", w) == math.inf
    assert lim("rk45", w) is None and lim("adaptive_rk4", w) is None
    assert lim(ta.make_integrator("rk4"), w) == lim("rk4", w)  # an integrator object works too
    assert lim("symplectic_euler", 0.0) == math.inf  # nothing stiff: no limit


def amplitude_growth(name, model, dt, steps):
    """For a pair started 1 mm stretched: (largest |x1 - x1(0)| over the last quarter of the run / over
    the first quarter, largest over the run / 1 mm). Symplectic Euler near its limit keeps a bounded but
    eccentric orbit, so boundedness compares the amplitude with itself; growth compares with the start
    (a growing run saturates where the spring passes through its anchor)."""
    state = model.state()
    x = state.positions()
    x[1, 0] += 1e-3
    state.particle_x.from_numpy(x)
    integ = ta.make_integrator(name, policy=IGNORE, check_every=10**9)
    d = np.zeros(steps)
    for s in range(steps):
        integ.step(model, state, dt)
        d[s] = abs(state.positions()[1, 0] - 0.1)
        if not math.isfinite(d[s]) or d[s] > 1.0:
            return math.inf, math.inf
    return d[-steps // 4 :].max() / d[: steps // 4].max(), d.max() / 1e-3


@pytest.mark.parametrize(
    "name, c, below, above",
    [("symplectic_euler", 0.0, 0.99, 1.02), ("rk4", 0.0, 0.99, 1.02), ("explicit_euler", 0.5, 0.9, 1.2)],
)
def test_limit_against_simulation(name, c, below, above):
    # One free particle (m = 0.01 kg) on a spring to a pinned one: the predicted limit separates bounded
    # from growing motion (2000 steps): below it the amplitude of the last quarter is within 1.01x of the
    # first quarter's, above it the amplitude grows past 3x its start.
    model = spring_pair(0.0, 0.01, 1e3, c)
    est = stability.state_frequency(model, model.state())
    limit = stability.stability_limit(name, est.omega, est.zeta)
    assert amplitude_growth(name, model, below * limit, 2000)[0] <= 1.01
    assert amplitude_growth(name, model, above * limit, 2000)[1] > 3.0


def test_guard_estimates_once_per_stepper(monkeypatch):
    # The estimate is paid when the first dt is checked, not per step nor per new dt.
    calls = []
    real = stability.state_frequency
    monkeypatch.setattr(stability, "state_frequency", lambda *a: calls.append(1) or real(*a))
    model = spring_pair(0.0, 0.01, 1e3)
    state = model.state()
    integ = ta.make_integrator("symplectic_euler")
    for dt in (1e-4, 1e-4, 2e-4, 1e-4):
        integ.step(model, state, dt)
    assert len(calls) == 1
    # The limit is computed once too: a later dt change costs a comparison only.
    limits = []
    real_limit = stability.stability_limit
    monkeypatch.setattr(stability, "stability_limit", lambda *a, **k: limits.append(1) or real_limit(*a, **k))
    for dt in (3e-4, 1e-4):
        integ.step(model, state, dt)
    assert limits == []
    assert integ.stepper_for(model).health.counts["unstable_step"] == 0


def test_auto_substeps_counts():
    # n = ceil(frame_dt / (safety limit)): the step frame_dt / n is within the safety margin, and n - 1
    # steps would not be.
    model = small_cloth(rayleigh_springs(5e-5))
    integ = ta.make_integrator("symplectic_euler")
    n, record = stability.auto_substeps(model, integ, 1 / 60)
    limit = record["limit"]
    assert 1 / 60 / n <= stability.AUTO_SAFETY * limit < 1 / 60 / (n - 1)
    assert record["substeps"] == n and record["omega"] > 0
    for name in ("implicit_euler", "rk45"):
        assert stability.auto_substeps(model, ta.make_integrator(name), 1 / 60)[0] == 1
    # Explicit Euler on an undamped stiff spring would need ~10^8 substeps: refused with the reason.
    with pytest.raises(ta.ParameterError, match="substeps='auto'"):
        stability.auto_substeps(spring_pair(0.0, 0.01, 1e5), ta.make_integrator("explicit_euler"), 1 / 60)
    with pytest.raises(ta.ParameterError, match="safety"):
        stability.auto_substeps(model, integ, 1 / 60, safety=1.5)


def test_scene_auto_substeps_recorded():
    # substeps="auto" in a scene: the frame is 1/60 s, the count is auto_substeps' and lands in settings
    # (so in run.json); stepping a frame raises no stability warning.
    scene = make_scene("cloth", integrator="symplectic_euler", resolution=10, substeps="auto")
    record = scene.settings()["substeps_auto"]
    assert record["substeps"] == scene.substeps
    assert scene.dt * scene.substeps == pytest.approx(1 / 60, rel=1e-12)
    assert scene.dt <= stability.AUTO_SAFETY * record["limit"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", ta.StabilityWarning)
        scene.advance_frame()
    with pytest.raises(ta.ParameterError, match="substeps"):
        make_scene("cloth", integrator="symplectic_euler", resolution=10, substeps=0)


def test_pointwise_kernel_matches_numpy():
    # The kernel fallback for pointwise terms (model.force_jacobian) gives the NumPy blocks of drag and
    # anchor springs to rounding.
    model = small_cloth(rayleigh_springs(5e-5), drag=0.002, anchor=True)
    x = model.state().positions() * 1.05
    v = np.zeros_like(x)
    k_np, c_np = stability._point_blocks(model, x, v, 0.0)
    k_ti, c_ti = stability._PointJacobians(model).blocks(x, v, 0.0)
    np.testing.assert_allclose(k_ti, k_np, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(c_ti, c_np, rtol=1e-10, atol=1e-12)


def test_guard_margin_message():
    # A step between GUARD_SAFETY x limit and the limit is reported as close to it, not as beyond it.
    model = spring_pair(0.0, 0.01, 1e3)
    integ = ta.make_integrator("symplectic_euler")
    limit = stability.stability_limit("symplectic_euler", math.sqrt(1e3 / 0.01))
    with pytest.warns(ta.StabilityWarning, match="is within 5% of the stability limit"):
        integ.step(model, model.state(), 0.98 * limit)


def test_guard_skips_models_it_cannot_linearise(monkeypatch):
    # A term the estimate does not know: the run goes on, one "stability_unchecked" event says why.
    def unknown(*args):
        raise ta.ParameterError("the stability estimate does not know element term Foo")

    monkeypatch.setattr(stability, "_element_blocks", unknown)
    model = spring_pair(0.0, 0.01, 1e3)
    state = model.state()
    integ = ta.make_integrator("symplectic_euler")
    integ.step(model, state, 1.0)
    integ.step(model, state, 0.5)
    health = integ.stepper_for(model).health
    assert health.counts["stability_unchecked"] == 1 and health.counts["unstable_step"] == 0
