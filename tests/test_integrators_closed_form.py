"""Integrators against closed forms: free fall, the undamped and damped linear oscillator."""

import numpy as np
import pytest

import taichi_anim as ta

from .helpers import run, spring_energy, spring_particle

G = np.array([0.0, -9.81, 0.0])
X0 = np.array([0.3, 10.0, -0.2])
V0 = np.array([1.0, 2.0, 0.5])


def free_fall(name, dt, k):
    b = ta.Builder()
    b.add_particle(X0, V0)
    b.add_force_gravity(G)
    model = b.finalize()
    state = model.state()
    run(model, state, ta.make_integrator(name), dt, k)
    return state.positions()[0]


@pytest.mark.parametrize("name", sorted(ta.INTEGRATORS))
def test_free_fall_closed_form(name):
    dt, k = 0.02, 25
    x = free_fall(name, dt, k)
    if name == "explicit_euler":
        # x_k = x0 + k dt v0 + k(k-1)/2 dt^2 g
        expected = X0 + k * dt * V0 + k * (k - 1) / 2 * dt**2 * G
    elif name in ("implicit_euler", "symplectic_euler"):
        # x_k = x0 + k dt v0 + k(k+1)/2 dt^2 g (both use the new velocity for the position)
        expected = X0 + k * dt * V0 + k * (k + 1) / 2 * dt**2 * G
    else:
        # Second order and higher integrate a quadratic exactly: x = x0 + t v0 + t^2 g / 2
        expected = X0 + k * dt * V0 + 0.5 * (k * dt) ** 2 * G
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-11)


@pytest.mark.parametrize("h_omega", [0.01, 0.3, 2.0])
def test_explicit_euler_energy_grows_every_step_for_any_dt(h_omega):
    # Undamped oscillator, explicit Euler: E_{n+1} = (1 + (h w)^2) E_n exactly (amplification matrix
    # [[1, h], [-h w^2, 1]] has det 1 + (h w)^2 and maps the energy ellipse onto a scaled copy).
    k, m = 100.0, 1.0
    w = np.sqrt(k / m)
    model, state = spring_particle(k=k, m=m)
    # Stop before the amplitude (0.5 m, growing) reaches the anchor 10 m away, where the spring is no
    # longer linear.
    steps = min(40, int(2 * np.log(18) / np.log(1 + h_omega**2)))
    xs, vs = run(model, state, ta.IntegratorExplicitEuler(), h_omega / w, steps, record=True)
    e = spring_energy(xs, vs, k, m, 10.0)
    np.testing.assert_allclose(e[1:] / e[:-1], 1 + h_omega**2, rtol=1e-9)


@pytest.mark.parametrize("h_omega", [0.01, 1.0, 100.0])
def test_implicit_euler_energy_never_grows(h_omega):
    # Backward Euler on the undamped oscillator: E_{n+1} = E_n / (1 + (h w)^2), for every step size.
    k, m = 100.0, 1.0
    w = np.sqrt(k / m)
    model, state = spring_particle(k=k, m=m)
    steps = min(40, int(10 / np.log10(1 + h_omega**2)))  # stop while E > 1e-10 E0 (round-off)
    xs, vs = run(model, state, ta.IntegratorImplicitEuler(), h_omega / w, steps, record=True)
    e = spring_energy(xs, vs, k, m, 10.0)
    assert np.all(np.diff(e) <= 1e-12 * e[0])
    np.testing.assert_allclose(e[1:] / e[:-1], 1 / (1 + h_omega**2), rtol=1e-9)


def test_symplectic_euler_energy_bounded_below_two_over_omega_and_explodes_above():
    k, m = 100.0, 1.0
    w = np.sqrt(k / m)
    periods = 50
    for h_omega, bounded in [(0.1, True), (1.0, True), (1.9, True), (2.1, False)]:
        dt = h_omega / w
        steps = int(periods * 2 * np.pi / w / dt)
        model, state = spring_particle(k=k, m=m)
        integ = ta.IntegratorSymplecticEuler()
        integ.stepper_for(model).watchdog.disable()  # the explosion above 2/w is what is measured
        xs, vs = run(model, state, integ, dt, steps, record=True)
        e = spring_energy(xs, vs, k, m, 10.0)
        if bounded:
            # The modified energy x^2 w^2 + v^2 - h w^2 x v is conserved, so E stays within
            # E0 / (1 - h w / 2) of its start and shows no trend (Hairer-Lubich-Wanner, sec. IX.8).
            assert e.max() <= e[0] / (1 - h_omega / 2) * (1 + 1e-9)
            n = len(e) // 5
            assert e[-n:].max() <= e[:n].max() * (1 + 1e-4)  # sampled phases differ slightly
        else:
            assert e[-1] > 1e6 * e[0]


def test_explicit_euler_damped_stability_bound():
    # m x'' = -k x - c x'. Explicit Euler's amplification matrix [[1, h], [-h k/m, 1 - h c/m]] has,
    # for complex eigenvalues (c^2 < 4 k m), |lambda|^2 = det = 1 - h c/m + h^2 k/m < 1  <=>  h < c / k.
    k, m, c = 400.0, 1.0, 8.0  # zeta = c / (2 sqrt(k m)) = 0.2
    bound = c / k
    # 1000 steps: |lambda|^2 = 0.986 decays E by 5e-7; 300 steps: |lambda|^2 = 1.018 grows it 186-fold
    # (few enough steps that the oscillation stays inside the spring's linear range).
    for factor, stable, steps in [(0.9, True, 1000), (1.1, False, 300)]:
        model, state = spring_particle(k=k, m=m, c=c)
        integ = ta.IntegratorExplicitEuler()
        integ.stepper_for(model).watchdog.disable()  # the growth above c/k is what is measured
        xs, vs = run(model, state, integ, factor * bound, steps, record=True)
        e = spring_energy(xs, vs, k, m, 10.0)
        assert (e[-1] < 1e-3 * e[0]) if stable else (e[-1] > 10 * e[0])


def test_implicit_euler_solves_linear_system_exactly():
    # u' = A u + b with u = (x, v), A = [[0, 1], [-k/m, -c/m]], b = (0, k L0 / m):
    # backward Euler is u_{n+1} = (I - h A)^{-1} (u_n + h b); the linearised step must match it exactly.
    k, m, c, rest, h = 900.0, 2.0, 3.0, 1.0, 0.1
    model, state = spring_particle(k=k, m=m, c=c, rest=rest, x0=1.7)
    xs, vs = run(model, state, ta.IntegratorImplicitEuler(), h, 30, record=True)
    a = np.array([[0.0, 1.0], [-k / m, -c / m]])
    b = np.array([0.0, k * rest / m])
    u = np.array([1.7, 0.0])
    step = np.linalg.inv(np.eye(2) - h * a)
    for n in range(1, 31):
        u = step @ (u + h * b)
        np.testing.assert_allclose([xs[n, 0, 0], vs[n, 0, 0]], u, rtol=1e-12, atol=1e-12)
