"""Moving analytic colliders: keyframed rigid motions, impacts against moving surfaces (closed forms for
the velocity a frictionless impact gives), resting on a moving floor, continuous mode against a fast slab."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta

MODES = ["projection", "backward"]


def random_motion(rng, k=5):
    from scipy.spatial.transform import Rotation

    times = np.cumsum(rng.uniform(0.1, 0.5, k)) - 0.3
    quats = Rotation.random(k, random_state=rng).as_quat()  # (x, y, z, w)
    return times, rng.normal(size=(k, 3)), quats


def test_motion_pose_matches_slerp_and_linear_translation():
    from scipy.spatial.transform import Rotation, Slerp

    rng = np.random.default_rng(0)
    times, trans, quats = random_motion(rng)
    motion = ta.RigidMotion(times, trans, quats)
    ref = Slerp(times, Rotation.from_quat(quats))
    for t in np.concatenate([rng.uniform(times[0], times[-1], 50), times]):
        r, tr = motion.pose(t)
        np.testing.assert_allclose(r, ref(t).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(tr, [np.interp(t, times, trans[:, a]) for a in range(3)], atol=1e-12)
    # Held outside the keyframes.
    np.testing.assert_allclose(motion.pose(times[0] - 1.0)[0], Rotation.from_quat(quats[0]).as_matrix())
    np.testing.assert_allclose(motion.pose(times[-1] + 1.0)[1], trans[-1])
    # Matrices and quaternions describe the same motion; from_transform samples a callable.
    as_mats = ta.RigidMotion(times, trans, Rotation.from_quat(quats).as_matrix())
    sampled = ta.RigidMotion.from_transform(lambda t: motion.pose(t), times)
    for t in (0.1, 0.37):
        for other in (as_mats, sampled):
            np.testing.assert_allclose(other.pose(t)[0], motion.pose(t)[0], atol=1e-12)
            np.testing.assert_allclose(other.pose(t)[1], motion.pose(t)[1], atol=1e-12)


def test_motion_in_kernels_matches_python_and_finite_difference_velocity():
    rng = np.random.default_rng(1)
    times, trans, quats = random_motion(rng)
    motion = ta.RigidMotion(times, trans, quats)
    motion.allocate()
    n = 64
    ts = np.concatenate([rng.uniform(times[0] - 0.2, times[-1] + 0.2, n - 2), [times[1], times[-1]]])
    pts = rng.normal(size=(n, 3))
    tf, pf = ti.field(float, n), ti.Vector.field(3, float, n)
    world, local, vel = (ti.Vector.field(3, float, n) for _ in range(3))
    tf.from_numpy(ts)
    pf.from_numpy(pts)

    @ti.kernel
    def evaluate(m: ti.template()):
        for i in range(n):
            world[i] = m.to_world(pf[i], tf[i])
            local[i] = m.to_local(world[i], tf[i])
            vel[i] = m.velocity(world[i], tf[i])

    evaluate(motion)
    eps = 1e-5
    for i in range(n):
        p = pts[i : i + 1]
        np.testing.assert_allclose(world.to_numpy()[i], motion.apply(p, ts[i])[0], atol=1e-12)
        # v = d/dt (R(t) p + T(t)) for the material point p: a one-sided second-order difference (the rate
        # of the segment that t starts; error O(eps^2)).
        f0, f1, f2 = (motion.apply(p, ts[i] + j * eps)[0] for j in range(3))
        fd = (-3.0 * f0 + 4.0 * f1 - f2) / (2.0 * eps)
        inside = times[0] < ts[i] < times[-1]
        np.testing.assert_allclose(vel.to_numpy()[i], fd if inside else 0.0, atol=1e-6)
    np.testing.assert_allclose(local.to_numpy(), pts, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(times=[0.0, 0.0], translations=np.zeros((2, 3))), "times must increase"),
        (dict(times=[0.0, 1.0], translations=np.zeros((3, 3))), "translations"),
        (dict(times=[0.0, np.nan], translations=np.zeros((2, 3))), "times"),
        (dict(times=[0.0, 1.0], translations=[[0, 0, 0], [0, np.inf, 0]]), "translations"),
        (dict(times=[0.0, 1.0], translations=np.zeros((2, 3)), rotations=np.zeros((2, 4))), "quaternion"),
        (
            dict(times=[0.0, 1.0], translations=np.zeros((2, 3)), rotations=2 * np.eye(3)[None].repeat(2, 0)),
            "not a rotation",
        ),  # fmt: skip
        (dict(times=[0.0, 1.0], translations=np.zeros((2, 3)), rotations=np.zeros((2, 3))), "rotations"),
    ],
)
def test_motion_rejects_bad_keyframes(kwargs, match):
    with pytest.raises(ta.ParameterError, match=match):
        ta.RigidMotion(**kwargs)


def test_builder_rejects_a_motion_that_is_not_a_rigid_motion():
    with pytest.raises(ta.ParameterError, match="motion"):
        ta.Builder().add_collider_sphere((0, 0, 0), 1.0, motion=lambda t: t)


def linear_motion(velocity, t_end=10.0):
    """Translation at a constant velocity [m/s] from the origin at t = 0 until t_end."""
    return ta.RigidMotion([0.0, t_end], [[0.0, 0.0, 0.0], np.multiply(velocity, t_end)])


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("e", [0.0, 1.0])
def test_moving_ball_knocks_resting_particles_off_with_closed_form_velocity(mode, e):
    # A ball of radius R at speed U along x meets a resting point at height b off its path with normal
    # n = (sqrt(R^2 - b^2), b, 0) / R; frictionless, the point leaves with (1 + e) U n_x n (the ball is
    # not slowed: a collider has infinite mass).
    big_r, u, c0, dt, steps = 0.2, 2.0, -0.5, 1e-2, 50
    offsets = np.array([0.0, 0.05, 0.1, 0.15])
    b = ta.Builder()
    b.add_particles(np.stack([np.zeros(4), offsets, np.zeros(4)], axis=1))
    b.add_collider_sphere((c0, 0.0, 0.0), big_r, restitution=e, motion=linear_motion((u, 0.0, 0.0)))
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorSymplecticEuler(collision_mode=mode)
    for k in range(steps):
        integ.step(model, state, dt)
        centre = np.array([c0 + u * (k + 1) * dt, 0.0, 0.0])
        gap = np.linalg.norm(state.positions() - centre, axis=1) - big_r
        assert gap.min() >= -1e-12  # never inside the ball at the end of a step
    root = np.sqrt(big_r**2 - offsets**2)
    n = np.stack([root, offsets, np.zeros(4)], axis=1) / big_r
    v_expected = (1.0 + e) * u * n[:, :1] * n
    v = state.velocities()
    if mode == "backward":
        # The swept test finds the impact time exactly (the ball translates): velocities and positions
        # to round-off. Impact at t_hit = (-root - c0) / U, then straight flight.
        np.testing.assert_allclose(v, v_expected, atol=1e-9)
        t_hit = (-root - c0) / u
        x_expected = (
            np.stack([np.zeros(4), offsets, np.zeros(4)], axis=1) + v_expected * (steps * dt - t_hit)[:, None]
        )
        np.testing.assert_allclose(state.positions(), x_expected, atol=1e-9)
    else:
        # Projection takes the normal at the end point, up to U dt inside the ball: the normal is off by
        # an angle of order U dt / R for the points hit off-centre.
        np.testing.assert_allclose(v, v_expected, atol=(1.0 + e) * u * u * dt / big_r)


@pytest.mark.parametrize("mode", MODES)
def test_rising_floor_carries_particles_up_and_they_end_at_rest_on_it(mode):
    # A floor rising at 0.5 m/s for 1 s, then still; points dropped onto it (e = 0) ride it up.
    rise, dt = 0.5, 2e-3
    floor_motion = ta.RigidMotion([0.0, 1.0], [[0.0, 0.0, 0.0], [0.0, rise, 0.0]])
    b = ta.Builder()
    b.add_force_gravity()
    b.add_particles([[0.0, 0.2, 0.0], [0.3, 0.05, 0.1], [-0.2, 0.0, 0.4]])
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0, motion=floor_motion)
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorSymplecticEuler(collision_mode=mode)
    for k in range(1, 1001):
        integ.step(model, state, dt)
        floor = rise * min(k * dt, 1.0)
        y = state.positions()[:, 1]
        assert y.min() >= floor - 1e-12  # never below the floor at the end of a step
        if k == 400:  # t = 0.8 s: all have landed and ride at the floor's speed
            np.testing.assert_allclose(y, floor, atol=1e-12)
            np.testing.assert_allclose(state.velocities()[:, 1], rise, atol=1e-9)
    # After the floor stops each point flies up v^2 / 2g = 1.3 cm and lands again, then rests.
    np.testing.assert_allclose(state.positions()[:, 1], rise, atol=1e-12)
    np.testing.assert_allclose(state.velocities(), 0.0, atol=1e-12)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("e", [0.0, 1.0])
def test_rotating_paddle_hits_points_with_the_surface_normal_speed(mode, e):
    # A slab |y| <= d along +x turns about z at omega. Its upper face meets a resting point P at lever
    # arm r_a = sqrt(|P|^2 - d^2), where the face moves along its normal n at omega r_a; frictionless,
    # the point leaves with (1 + e) omega r_a n.
    from scipy.spatial.transform import Rotation

    omega, d, dt = 2.0, 0.02, 1e-3
    t_end = 2.0
    angles = np.linspace(0.0, omega * t_end, 9)
    rot = Rotation.from_euler("z", angles[:, None]).as_quat()
    motion = ta.RigidMotion(np.linspace(0.0, t_end, 9), np.zeros((9, 3)), rot)
    phis = np.array([0.3, 0.6, 0.9])
    radii = np.array([0.3, 0.5, 0.8])
    pts = np.stack([radii * np.cos(phis), radii * np.sin(phis), np.zeros(3)], axis=1)
    b = ta.Builder()
    b.add_particles(pts)
    b.add_collider_box((0.0, -d, -0.1), (1.0, d, 0.1), solid=True, restitution=e, motion=motion)
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorSymplecticEuler(collision_mode=mode)
    first = [None] * 3
    for k in range(1, 600):
        integ.step(model, state, dt)
        x, v = state.positions(), state.velocities()
        r, tr = motion.pose(k * dt)
        local = (x - tr) @ r  # R^T (x - T), row-wise
        lx, ly, lz = local.T
        depth = np.min([lx, 1.0 - lx, d - np.abs(ly), 0.1 - np.abs(lz)], axis=0)
        assert depth.max() <= 1e-12  # never inside the paddle at the end of a step
        for i in range(3):
            if first[i] is None and np.linalg.norm(v[i]) > 0.0:
                first[i] = v[i]
    r_a = np.sqrt(radii**2 - d**2)
    contact_angle = phis - np.arctan2(d, r_a)  # the slab's angle when its face reaches P
    n = np.stack([-np.sin(contact_angle), np.cos(contact_angle), np.zeros(3)], axis=1)
    expected = (1.0 + e) * omega * r_a[:, None] * n
    # Projection meets the face up to one step's turn omega h late: first order in omega h. The swept
    # test places the impact inside the step; what is left is second order (the face's arc over a step).
    speed = (1.0 + e) * omega * radii.max()
    tol = speed * omega * dt if mode == "projection" else 20.0 * speed * (omega * dt) ** 2
    np.testing.assert_allclose(np.array(first), expected, atol=tol)


@pytest.mark.parametrize("e", [0.0, 1.0])
def test_backward_mode_catches_a_fast_thin_slab_that_projection_misses(e):
    # A 1 cm slab falls at 100 m/s: 1 m per step, far more than its thickness. Its lower face (at 0.5 m at
    # t = 0) reaches the resting point at t = 5 ms, half the step; the point leaves at (1 + e) 100 m/s
    # downwards and flies the other 5 ms.
    dt, speed = 1e-2, 100.0
    ends = {}
    for mode in MODES:
        b = ta.Builder()
        b.add_particle((0.0, 0.0, 0.0))
        b.add_collider_box(
            (-1.0, 0.5, -1.0), (1.0, 0.51, 1.0), solid=True, restitution=e,
            motion=linear_motion((0.0, -speed, 0.0), t_end=1.0),
        )  # fmt: skip
        model = b.finalize()
        state = model.state()
        ta.IntegratorSymplecticEuler(collision_mode=mode).step(model, state, dt)
        ends[mode] = state.positions()[0], state.velocities()[0]
    x, v = ends["backward"]
    v_out = -(1.0 + e) * speed
    np.testing.assert_allclose(v, [0.0, v_out, 0.0], atol=1e-9)
    np.testing.assert_allclose(x, [0.0, v_out * 0.5 * dt, 0.0], atol=1e-9)
    assert x[1] <= 0.5 - speed * dt + 1e-12  # below the slab, whose lower face is at -0.5 m now
    # Projection sees only the end point, which the slab has already passed: the point stays put.
    np.testing.assert_allclose(ends["projection"][0], 0.0)
    np.testing.assert_allclose(ends["projection"][1], 0.0)


# The top corners of `hanging_cloth`: grid vertices (0, 7) and (7, 7) at origin + (i, j) * 0.5 m / 7.
PINS = np.array([[0.0, 1.0, 0.0], [0.5, 1.0, 0.0]])


def hanging_cloth():
    """A vertical 0.5 m cloth of 8 x 8 vertices hanging from its two top corners (pinned)."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_force_drag(0.002)
    cloth = b.add_cloth_grid(
        origin=(0.0, 0.5, 0.0), size=(0.5, 0.5), resolution=(8, 8), plane="xy", pinned=[56, 63]
    )
    return b, cloth


def circle_angle(t, omega, ramp):
    """Angle [rad] on the circle: the angular speed rises as a smoothstep from 0 to omega over `ramp` [s]
    (no jump in velocity or acceleration for the cloth to swing from), then stays."""
    u = np.minimum(t / ramp, 1.0)
    return omega * ramp * (u**3 - 0.5 * u**4) + omega * np.maximum(t - ramp, 0.0)


def test_cloth_follows_corners_moving_on_a_circle():
    # The two top corners go round a horizontal circle of radius rho (keyframes every 0.05 s, linear
    # between them). Each step ends with the corners exactly on the keyframed path, moving at the velocity
    # that got them there; the cloth follows: its centre of mass, ~0.25 m below the corners, moves as they
    # do (0.2 m across) up to the pendulum tilt that accelerations of ~0.25 m/s^2 give it (a / g rad,
    # ~6 mm) and the swing that tilt sets up (at most as much again), measured against the same cloth
    # hanging from fixed corners.
    rho, omega, dt, steps = 0.1, 2.0 * np.pi / 4.0, 1.0 / 60.0, 240
    times = np.linspace(0.0, steps * dt, 81)
    phi = circle_angle(times, omega, 1.0)
    offset = rho * np.stack([np.cos(phi) - 1.0, 0 * times, np.sin(phi)], axis=1)
    com = {}
    for moving in (False, True):
        b, cloth = hanging_cloth()
        x_pins = PINS
        if moving:
            b.add_attachment(cloth.pinned, times, x_pins[None] + offset[:, None])
        model = b.finalize()
        state = model.state()
        integ = ta.IntegratorImplicitEuler(tol=1e-6)
        m = model.particle_masses()
        track = []
        x_prev = state.positions()
        for k in range(1, steps + 1):
            integ.step(model, state, dt)
            x, v = state.positions(), state.velocities()
            if moving:
                target = x_pins + np.array([np.interp(k * dt, times, offset[:, a]) for a in range(3)])
                np.testing.assert_allclose(x[cloth.pinned], target, atol=1e-12)
                np.testing.assert_allclose(v[cloth.pinned], (target - x_prev[cloth.pinned]) / dt, atol=1e-9)
            x_prev = x
            track.append((m[:, None] * x).sum(0) / m.sum())
        com[moving] = np.array(track)
    t = np.arange(1, steps + 1) * dt
    moved = np.array([[np.interp(tk, times, offset[:, a]) for a in range(3)] for tk in t])
    assert np.abs(moved).max() > 1.9 * rho  # the corners went across the circle
    np.testing.assert_allclose(com[True] - com[False], moved, atol=0.02)


@pytest.mark.parametrize("mode", MODES)
def test_attachment_carried_by_a_rigid_motion_ends_each_step_on_it(mode):
    # Pinned points carried by a turn of 90 degrees about y and a lift of 0.3 m over 1 s; a free particle
    # next to them is not touched; a pinned one not attached keeps its velocity.
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("y", [[0.0], [90.0]], degrees=True).as_quat()
    motion = ta.RigidMotion([0.0, 1.0], [[0.0, 0.0, 0.0], [0.0, 0.3, 0.0]], rot)
    b = ta.Builder()
    b.add_force_gravity()
    rest = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 2.0], [-1.0, 1.0, 0.5]])
    attached = b.add_particles(rest, mass=0.0)
    free = b.add_particle((0.0, 2.0, 0.0))
    still = b.add_particle((5.0, 0.0, 0.0), (1.0, 0.0, 0.0), mass=0.0)
    b.add_attachment(list(attached), motion=motion)
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorSymplecticEuler(collision_mode=mode)
    dt = 0.05
    x_prev = rest
    for k in range(1, 25):  # past the last keyframe: held
        integ.step(model, state, dt)
        x, v = state.positions(), state.velocities()
        target = motion.apply(rest, k * dt)
        np.testing.assert_allclose(x[list(attached)], target, atol=1e-12)
        np.testing.assert_allclose(v[list(attached)], (target - x_prev) / dt, atol=1e-9)
        x_prev = target
    t = 24 * dt
    # Symplectic Euler: y_n = y0 - g dt^2 n (n + 1) / 2.
    assert x[free][1] == pytest.approx(2.0 - 9.81 * dt * dt * 24 * 25 / 2, abs=1e-9)
    np.testing.assert_allclose(x[still], [5.0 + t, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda b: b.add_attachment([2], [0.0], np.zeros((1, 1, 3))), "particle 2 is not pinned"),
        (lambda b: b.add_attachment([0, 1], [0.0, 1.0], np.zeros((2, 1, 3))), "positions must have shape"),
        (lambda b: b.add_attachment([0], [1.0, 0.5], np.zeros((2, 1, 3))), "times must increase"),
        (lambda b: b.add_attachment([0], [0.0, 1.0], np.full((2, 1, 3), np.nan)), "positions"),
        (lambda b: b.add_attachment([0], [0.0, np.inf], np.zeros((2, 1, 3))), "times"),
        (lambda b: b.add_attachment([0, 7], [0.0], np.zeros((1, 2, 3))), "particles must be indices"),
        (lambda b: b.add_attachment([0, 0], [0.0], np.zeros((1, 2, 3))), "twice"),
        (lambda b: b.add_attachment([0]), "needs times and positions"),
        (
            lambda b: b.add_attachment([0], [0.0], np.zeros((1, 1, 3)), motion=linear_motion((1, 0, 0))),
            "not both",
        ),
        (lambda b: b.add_attachment([0], motion="spin"), "motion must be a RigidMotion"),
    ],
)
def test_attachment_rejects_bad_input(call, match):
    b = ta.Builder()
    b.add_particles(np.eye(3)[:2], mass=0.0)
    b.add_particle((0.0, 0.0, 1.0), mass=1.0)
    with pytest.raises(ta.ParameterError, match=match):
        call(b)


def test_a_particle_is_attached_once():
    b = ta.Builder()
    b.add_particles(np.eye(3), mass=0.0)
    b.add_attachment([0, 1], [0.0], np.zeros((1, 2, 3)))
    with pytest.raises(ta.ParameterError, match="particle 1 is already attached"):
        b.add_attachment([1, 2], [0.0], np.zeros((1, 2, 3)))


def test_backward_mode_lets_a_particle_slide_along_a_surface():
    # A point sliding on a floor with friction: the swept test meets the floor at the start of every
    # step (gravity pushes into it); the rest of the step must slide, not stop. Symplectic Euler with
    # Coulomb friction: v_n = v0 - mu g n h, x_n = h (v_1 + ... + v_n), as in projection mode.
    mu, v0, h, steps = 0.3, 2.0, 1e-3, 100
    ends = {}
    for mode in MODES:
        b = ta.Builder()
        b.add_force_gravity()
        b.add_particle((0.0, 0.0, 0.0), (v0, 0.0, 0.0))
        b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0, friction=mu)
        model = b.finalize()
        state = model.state()
        integ = ta.IntegratorSymplecticEuler(collision_mode=mode)
        for _ in range(steps):
            integ.step(model, state, h)
        ends[mode] = state.positions()[0]
    n = np.arange(1, steps + 1)
    expected = h * np.sum(v0 - mu * 9.81 * n * h)
    for mode in MODES:
        np.testing.assert_allclose(ends[mode], [expected, 0.0, 0.0], atol=1e-12)
