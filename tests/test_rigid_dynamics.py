"""Rigid bodies in flight against closed forms (bodies/rigid/dynamics.py): free fall per the method's own
closed form, a constant torque, torque-free tumbling (L kept, energy to the method's order, the
intermediate-axis flip), kinematic bodies, poses given and read back."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.bodies.rigid.quaternion import quat_to_matrix
from taichi_anim.errors import DivergenceError, ParameterError

G = np.array([0.0, -9.81, 0.0])
METHODS = ["explicit_euler", "symplectic_euler", "midpoint", "rk4", "implicit_euler"]
# x_n = x0 + n h v0 + beta(n) h^2 g: the position weight of a constant acceleration per method
BETA = {
    "explicit_euler": lambda n: n * (n - 1) / 2,
    "symplectic_euler": lambda n: n * (n + 1) / 2,
    "implicit_euler": lambda n: n * (n + 1) / 2,
    "midpoint": lambda n: n * n / 2,
    "rk4": lambda n: n * n / 2,
}
# a box with three distinct moments: I = m/3 (b^2 + c^2, a^2 + c^2, a^2 + b^2)
TUMBLER = ta.shapes.Box((0.05, 0.1, 0.2))


pytestmark = pytest.mark.usefixtures("size_buckets")  # conftest.py: kernels compiled once


def scene(*bodies, gravity=True):
    b = ta.Builder()
    if gravity:
        b.add_force_gravity(tuple(G))
    for shape, options in bodies:
        b.add_rigid_body(shape, **options)
    m = b.finalize()
    return m, m.state()


def run(model, state, method, dt, steps):
    integ = ta.make_integrator(method)
    for _ in range(steps):
        integ.step(model, state, dt)
    return state.rigid_snapshot()


def energy_and_momentum(model, snap):
    """(kinetic energy [J], world angular momentum [kg m^2/s]) of body 0."""
    r = quat_to_matrix(snap.orientation[0])
    inertia = r @ model.rigid_inertia[0] @ r.T
    w, v = snap.angular_velocity[0], snap.velocity[0]
    return 0.5 * model.rigid_mass[0] * v @ v + 0.5 * w @ inertia @ w, inertia @ w


@pytest.mark.parametrize("method", METHODS)
def test_free_fall_is_the_methods_closed_form(method):
    v0, x0, h, n = np.array([1.0, 2.0, -0.5]), np.array([0.3, 5.0, -1.0]), 0.01, 37
    m, s = scene((ta.shapes.Capsule(0.1, 0.2), dict(position=x0, velocity=v0, angular_velocity=(3, 1, 2))))
    snap = run(m, s, method, h, n)
    expected = x0 + n * h * v0 + BETA[method](n) * h * h * G
    np.testing.assert_allclose(snap.com[0], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(snap.velocity[0], v0 + n * h * G, rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", METHODS)
def test_a_constant_torque_about_a_principal_axis_accelerates_at_tau_over_i(method):
    # From rest, torque tau along principal axis k: w(t) = tau t / I_k exactly (L = tau t for every method).
    m, s = scene((TUMBLER, dict(orientation=(0.0, np.sin(0.3), 0.0, np.cos(0.3)))), gravity=False)
    axis = quat_to_matrix(s.rigid_snapshot().orientation[0])[:, 2]  # the box's z axis: its smallest moment
    s.set_rigid_force(0, torque=2.5 * axis)
    h, n = 0.005, 40
    snap = run(m, s, method, h, n)
    expected = 2.5 * n * h / m.rigid_inertia[0][2, 2] * axis
    np.testing.assert_allclose(snap.angular_velocity[0], expected, atol=1e-10)
    np.testing.assert_allclose(snap.velocity[0], 0.0, atol=1e-14)


def test_a_force_off_the_centre_of_mass_pushes_and_turns():
    # F at r from the com: a = F / m and L = (r x F) t, from rest, semi-implicit (L exact, v exact).
    m, s = scene((ta.shapes.Sphere(0.2), dict(position=(1.0, 0.0, 0.0))), gravity=False)
    f = np.array([0.0, 3.0, 0.0])
    s.set_rigid_force(0, f, point=(1.2, 0.0, 0.0))
    h, n = 0.01, 10
    snap = run(m, s, "symplectic_euler", h, n)
    np.testing.assert_allclose(snap.velocity[0], f / m.rigid_mass[0] * n * h, atol=1e-12)
    torque = np.cross([0.2, 0.0, 0.0], f)
    expected = torque * n * h / m.rigid_inertia[0][0, 0]
    np.testing.assert_allclose(snap.angular_velocity[0], expected, atol=1e-12)


@pytest.mark.parametrize("method", METHODS)
def test_torque_free_tumbling_keeps_the_angular_momentum(method):
    m, s = scene((TUMBLER, dict(angular_velocity=(1.0, 4.0, 0.5))), gravity=False)
    _, start = energy_and_momentum(m, s.rigid_snapshot())
    _, end = energy_and_momentum(m, run(m, s, method, 0.01, 200))
    np.testing.assert_allclose(end, start, rtol=1e-11, atol=1e-14)


def tumble(method, h, t_end=2.0):
    """(relative energy error, rotation matrix, angular velocity) after t_end of torque-free tumbling."""
    m, s = scene((TUMBLER, dict(angular_velocity=(1.0, 4.0, 0.5))), gravity=False)
    e0, _ = energy_and_momentum(m, s.rigid_snapshot())
    snap = run(m, s, method, h, round(t_end / h))
    e1, _ = energy_and_momentum(m, snap)
    return (e1 - e0) / e0, quat_to_matrix(snap.orientation[0]), snap.angular_velocity[0]


def energy_error(method, h, t_end=2.0):
    return tumble(method, h, t_end)[0]


# (method, step [s], order): the steps are in each method's asymptotic range on this tumbler
ORDERS = [("explicit_euler", 2e-3, 1), ("symplectic_euler", 2e-2, 2), ("midpoint", 1e-2, 2), ("rk4", 2e-2, 4)]


def test_tumbling_converges_at_each_methods_order():
    # The pose and angular velocity after 2 s against RK4 at a 64x smaller step: halving h divides the
    # error by 2^p; the semi-implicit splitting is of order 2. The energy error shrinks at least as fast
    # (faster for some: a method's error can be orthogonal to the energy's gradient to leading order).
    _, r_ref, w_ref = tumble("rk4", 2e-2 / 64)
    for method, h, p in ORDERS:
        errors = []
        for step in (h, h / 2):
            e, r, w = tumble(method, step)
            errors.append((np.abs(r - r_ref).max() + np.abs(w - w_ref).max(), abs(e)))
        (state_h, energy_h), (state_h2, energy_h2) = errors
        assert 0.8 * 2**p < state_h / state_h2 < 1.25 * 2**p, (method, state_h / state_h2)
        assert energy_h / energy_h2 > 0.8 * 2**p, (method, energy_h / energy_h2)


def test_the_explicit_formulation_gains_energy_and_the_splitting_does_not_drift():
    # Explicit Euler integrates w x L explicitly: the energy grows every step. The splitting's error is
    # bounded: the same after 20 s as after 2 s, at a step where explicit Euler has gained 20 %.
    assert energy_error("explicit_euler", 0.01) > 0.05
    short = abs(energy_error("symplectic_euler", 0.01, 2.0))
    long = abs(energy_error("symplectic_euler", 0.01, 20.0))
    assert long < 3e-3 and long < 3.0 * max(short, 1e-6)


def axis_alignment(method, axis, t_end=6.0, h=0.005):
    """cos of the angle between body axis `axis` and L over a spin mostly about it, per step."""
    w = np.array([0.01, 0.01, 0.01])
    w[axis] = 5.0
    m, s = scene((TUMBLER, dict(angular_velocity=w)), gravity=False)
    integ = ta.make_integrator(method)
    cosines = []
    for _ in range(round(t_end / h)):
        integ.step(m, s, h)
        snap = s.rigid_snapshot()
        _, mom = energy_and_momentum(m, snap)
        cosines.append(quat_to_matrix(snap.orientation[0])[:, axis] @ mom / np.linalg.norm(mom))
    return np.array(cosines)


# RK4 (16 s on 2 cores) is slow: test_tumbling_converges_at_each_methods_order runs every scheme.
@pytest.mark.parametrize("method", ["symplectic_euler", pytest.param("rk4", marks=pytest.mark.slow)])
def test_the_intermediate_axis_flips_and_the_others_stay(method):
    # Dzhanibekov: a spin about the intermediate axis (y, I_y between I_x and I_z here) reverses it
    # periodically; spins about the largest (x) and smallest (z) moments stay within a few degrees.
    assert axis_alignment(method, 1).min() < -0.99
    assert axis_alignment(method, 0).min() > 0.99
    assert axis_alignment(method, 2).min() > 0.99


def test_kinematic_bodies_move_at_their_velocities_whatever_acts():
    v, w = np.array([0.5, 0.0, -1.0]), np.array([0.0, 2.0, 0.0])
    m, s = scene((ta.shapes.Box((0.5, 0.1, 0.5)), dict(velocity=v, angular_velocity=w, kinematic=True)))
    s.set_rigid_force(0, (0.0, 100.0, 0.0), torque=(5.0, 0.0, 0.0))
    snap = run(m, s, "rk4", 0.01, 50)
    np.testing.assert_allclose(snap.position[0], 0.5 * v, atol=1e-12)
    angle = 2.0 * 0.5
    turned = [0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)]
    np.testing.assert_allclose(snap.orientation[0], turned, atol=1e-12)
    np.testing.assert_allclose(snap.angular_velocity[0], w, atol=1e-15)


def test_a_pose_is_read_back_as_given_for_an_off_centre_mesh():
    # A hull whose com is off its origin and whose inertia is not diagonal: the snapshot gives back the
    # shape's origin and orientation, and the com where the frame puts it.
    rng = np.random.default_rng(5)
    hull = ta.shapes.ConvexHull(rng.normal(size=(30, 3)) + [2.0, 0.0, 0.0])
    q = np.array([0.2, -0.4, 0.1, 0.9]) / np.linalg.norm([0.2, -0.4, 0.1, 0.9])
    m, s = scene((hull, dict(position=(1.0, 2.0, 3.0), orientation=q)))
    snap = s.rigid_snapshot()
    np.testing.assert_allclose(snap.position[0], [1.0, 2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(snap.orientation[0] * np.sign(snap.orientation[0][3]), q, atol=1e-12)
    com = m.rigid_com[0]
    np.testing.assert_allclose(snap.com[0], [1.0, 2.0, 3.0] + quat_to_matrix(q) @ com, atol=1e-12)
    assert abs(m.rigid_inertia[0][0, 1]) > 1e-3  # not a principal frame: the model keeps the shape's


def test_state_save_copies_the_bodies():
    m, s = scene((TUMBLER, dict(velocity=(1, 2, 3), angular_velocity=(0.5, 0.1, 0.2))))
    run(m, s, "symplectic_euler", 0.01, 3)
    copy = m.state()
    s.save(copy)
    a, b = s.rigid_snapshot(), copy.rigid_snapshot()
    for name in ("position", "orientation", "velocity", "angular_velocity"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_a_non_finite_body_stops_the_run():
    m, s = scene((TUMBLER, {}))
    s.set_rigid_force(0, (0.0, 1e308, 0.0))
    integ = ta.make_integrator("symplectic_euler")
    integ.step(m, s, 0.01)
    s.set_rigid_force(0, (0.0, 0.0, 0.0), torque=(1e308, 1e308, 0.0))
    with pytest.raises(DivergenceError, match="rigid body 0"):
        for _ in range(3):
            integ.step(m, s, 1e10)


def test_bad_bodies_are_refused_with_the_parameter_named():
    b = ta.Builder()
    with pytest.raises(ParameterError, match="orientation"):
        b.add_rigid_body(TUMBLER, orientation=(0, 0, 0, 0))
    with pytest.raises(ParameterError, match="density"):
        b.add_rigid_body(TUMBLER, density=-1.0)
    with pytest.raises(ParameterError, match="shape"):
        b.add_rigid_body("box")
    with pytest.raises(ParameterError, match="velocity"):
        b.add_rigid_body(TUMBLER, velocity=(np.nan, 0, 0))


@pytest.mark.parametrize("method", ["symplectic_euler", "rk4"])
def test_damping_decays_the_velocities_exponentially(method):
    # dv/dt = -c v: v(t) = v0 e^(-c t), exactly per step for the semi-implicit kick (e^(-c h) each step),
    # to RK4's order for the tableau. A spin about a principal axis decays the same way.
    m, s = scene(
        (
            TUMBLER,
            dict(velocity=(2.0, 0, 0), angular_velocity=(0, 0, 3.0), linear_damping=0.5, angular_damping=2.0),
        ),
        gravity=False,
    )
    snap = run(m, s, method, 0.01, 100)
    tol = 1e-12 if method == "symplectic_euler" else 1e-9
    np.testing.assert_allclose(snap.velocity[0], [2.0 * np.exp(-0.5), 0, 0], atol=tol)
    np.testing.assert_allclose(snap.angular_velocity[0], [0, 0, 3.0 * np.exp(-2.0)], atol=tol)
