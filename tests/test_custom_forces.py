"""A user's force terms, defined here (outside the package) and added with Builder.add_force: checked by
finite differences (ta.terms.check_term), run under explicit and implicit integrators against closed
forms, and bounded by the watchdog through their own energy and floor."""

import math

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta


@ti.data_oriented
class Magnet(ta.PointTerm):
    """Plummer-softened attraction to `pole`: E = -k m / s, f = -k m d / s^3, s = sqrt(|d|^2 + soft^2)."""

    energy_kind = "potential"

    def __init__(self, pole, k: float, soft: float, floor: bool = True):
        self.pole = tuple(float(c) for c in pole)
        self.k = float(k)
        self.soft = float(soft)
        self.floor = floor

    @ti.func
    def force(self, i, m, x, v, t):
        d = x - ti.Vector(self.pole, dt=float)
        s2 = d.norm_sqr() + self.soft * self.soft
        return -self.k * m * d / (s2 * ti.sqrt(s2))

    @ti.func
    def jacobian(self, i, m, x, v, t):
        d = x - ti.Vector(self.pole, dt=float)
        s2 = d.norm_sqr() + self.soft * self.soft
        s3 = s2 * ti.sqrt(s2)
        eye = ti.Matrix.identity(float, 3)
        return -self.k * m * (eye / s3 - 3.0 * d.outer_product(d) / (s2 * s3)), ti.Matrix.zero(float, 3, 3)

    def energy(self, x, masses):
        d = np.asarray(x, dtype=np.float64) - np.asarray(self.pole)
        return -self.k * float(np.sum(masses / np.sqrt((d * d).sum(axis=1) + self.soft**2)))

    def energy_floor(self, masses):
        return -self.k * float(np.sum(masses)) / self.soft if self.floor else 0.0


@ti.data_oriented
class ZeroLengthSprings(ta.ElementTerm):
    """f_a = -k (x_a - x_b), f_b = -f_a on each pair: linear, so one linearised implicit step is exact."""

    arity = 2
    energy_kind = "potential"

    def __init__(self, particle_count: int, pairs, k: float):
        super().__init__(particle_count, pairs)
        self.k = float(k)

    @ti.func
    def element_force(self, e, X, V, t):
        F = ti.Vector.zero(float, 6)
        for c in ti.static(range(3)):
            F[c] = -self.k * (X[c] - X[3 + c])
            F[3 + c] = -F[c]
        return F

    @ti.func
    def element_linear(self, e, X, V, t, h):
        S = ti.Matrix.zero(float, 6, 6)
        KV = ti.Vector.zero(float, 6)
        for a in ti.static(range(2)):
            for b in ti.static(range(2)):
                sign = ti.static(1.0 if a == b else -1.0)
                for c in ti.static(range(3)):
                    S[3 * a + c, 3 * b + c] = h * h * self.k * sign  # -h^2 dF/dX
                    KV[3 * a + c] += -self.k * sign * V[3 * b + c]
        return self.element_force(e, X, V, t), S, KV

    @ti.func
    def element_energy(self, e, X):
        d = ti.Vector([X[0] - X[3], X[1] - X[4], X[2] - X[5]])
        return 0.5 * self.k * d.norm_sqr()


def test_magnet_derivatives_match_finite_differences():
    x = np.random.default_rng(0).uniform(-1.0, 1.0, (8, 3))
    errors = ta.terms.check_term(Magnet((0.1, 0.0, 0.0), 1.0, 0.1), x, masses=np.full(8, 0.5))
    assert errors["jacobian_x"] < 1e-8 and errors["jacobian_v"] == 0.0 and errors["energy_gradient"] < 1e-8


def test_a_wrong_jacobian_is_caught_by_the_check():
    @ti.data_oriented
    class HalfJacobian(Magnet):
        @ti.func
        def jacobian(self, i, m, x, v, t):
            jx, jv = Magnet.jacobian(self, i, m, x, v, t)
            return 0.5 * jx, jv

    x = np.random.default_rng(0).uniform(-1.0, 1.0, (8, 3))
    assert ta.terms.check_term(HalfJacobian((0.0, 0.0, 0.0), 1.0, 0.1), x)["jacobian_x"] > 0.3


@pytest.mark.parametrize("method", ["symplectic_euler", "rk4", "implicit_euler"])
def test_magnet_orbit_closes(method):
    """A circular orbit of radius 1 m, speed sqrt(k r^2 / s^3): after one period (400 steps) the
    symplectic and RK4 orbits close to 2e-3 m; implicit Euler, which removes energy every step, ends
    inside with less energy than it started with."""
    magnet = Magnet((0.0, 0.0, 0.0), 1.0, 0.1)
    s = math.sqrt(1.0 + 0.01)
    speed = math.sqrt(1.0 / s**3)
    period = 2.0 * math.pi / speed
    b = ta.Builder()
    b.add_particles([[1.0, 0.0, 0.0]], [[0.0, 0.0, speed]], mass=0.5)
    b.add_force(magnet)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator(method)
    for _ in range(400):
        integ.step(model, state, period / 400)
    x, v = state.positions()[0], state.velocities()[0]
    radius = float(np.linalg.norm(x))
    if method == "implicit_euler":
        e0 = 0.25 * speed**2 - 0.5 / s
        e1 = 0.25 * float(v @ v) + magnet.energy(x[None], np.array([0.5]))
        assert radius < 1.0 and e1 < e0
    else:
        assert abs(radius - 1.0) < 2e-3
        np.testing.assert_allclose(x, [1.0, 0.0, 0.0], atol=0.05)  # back where it started


def test_magnet_energy_bounds_the_watchdog_and_a_missing_floor_is_named():
    """v_ref = sqrt(2 (E - E_floor) / m): the speed of a fall from r = 1 into the pole; with the
    default floor 0, above the magnet's negative potential, the first step names the term."""
    b = ta.Builder()
    b.add_particles([[1.0, 0.0, 0.0]], mass=0.5)
    b.add_force(Magnet((0.0, 0.0, 0.0), 1.0, 0.1))
    model = b.finalize()
    integ = ta.make_integrator("symplectic_euler")
    integ.step(model, model.state(), 1e-3)
    release = 0.5 * (1.0 / 0.1 - 1.0 / math.sqrt(1.01))
    assert integ.stepper_for(model).watchdog.derived["v_ref"] == pytest.approx(math.sqrt(2 * release / 0.5))

    b = ta.Builder()
    b.add_particles([[1.0, 0.0, 0.0]], mass=0.5)
    b.add_force(Magnet((0.0, 0.0, 0.0), 1.0, 0.1, floor=False))
    model = b.finalize()
    with pytest.raises(ta.ParameterError, match="Magnet: its energy .* is below its energy_floor"):
        ta.make_integrator("symplectic_euler").step(model, model.state(), 1e-3)


def test_element_term_under_implicit_euler_is_exact_backward_euler():
    """Two 1 kg particles on a zero-length spring k: the separation u obeys u'' = -2k u, and one
    linearised backward-Euler step of a linear force is exact backward Euler:
    v1 = (v0 - h w^2 u0) / (1 + h^2 w^2), u1 = u0 + h v1 (w^2 = 2k), to the CG tolerance."""
    b = ta.Builder()
    b.add_particles([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], mass=1.0)
    term = ZeroLengthSprings(b.particle_count, [[0, 1]], k=50.0)
    assert max(ta.terms.check_term(term, np.array([[0.0, 0.1, 0.0], [1.0, 0.0, 0.3]])).values()) < 1e-8
    b.add_force(term)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator("implicit_euler", tol=1e-12)
    h, w2 = 0.05, 100.0
    u, du = -1.0, 0.0  # x0 - x1 and its rate
    for _ in range(10):
        integ.step(model, state, h)
        du = (du - h * w2 * u) / (1.0 + h * h * w2)
        u = u + h * du
    x = state.positions()
    assert x[0, 0] - x[1, 0] == pytest.approx(u, rel=1e-8)
    assert x[0, 0] + x[1, 0] == pytest.approx(1.0, abs=1e-12)  # momentum: the centre stays
