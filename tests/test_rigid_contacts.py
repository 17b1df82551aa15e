"""Rigid contacts against closed forms (bodies/rigid/contacts.py, narrow_phase.py): resting, Coulomb
friction on an incline, restitution, momentum in body-body impacts, a 20-box tower, and the cascade's
OBB test against an exact reference (linear programming)."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim.bodies.rigid.narrow_phase import obb_overlap

G = 9.81
BOX = ta.shapes.Box((0.2, 0.1, 0.2))


pytestmark = pytest.mark.usefixtures("size_buckets")  # conftest.py: kernels compiled once


def world(bodies, *, plane=None, gravity=True, contacts=None):
    """A model and state: bodies [(shape, add_rigid_body options)], an optional plane (normal, friction,
    restitution)."""
    b = ta.Builder()
    if gravity:
        b.add_force_gravity((0.0, -G, 0.0))
    if plane is not None:
        normal, friction, restitution = plane
        b.add_collider_plane(normal, 0.0, friction=friction, restitution=restitution)
    if contacts:
        b.set_rigid_contacts(**contacts)
    for shape, options in bodies:
        b.add_rigid_body(shape, **options)
    m = b.finalize()
    return m, m.state(), ta.make_integrator("symplectic_euler")


def advance(model, state, integ, seconds, dt=1 / 240):
    for _ in range(round(seconds / dt)):
        integ.step(model, state, dt)
    return state.rigid_snapshot()


def test_a_box_rests_on_the_floor_without_sinking_or_creeping():
    m, s, integ = world([(BOX, dict(position=(0.3, 0.1005, -0.2)))], plane=((0, 1, 0), 0.5, 0.0))
    snap = advance(m, s, integ, 2.0)
    # the penetration left is below the solver's slop (5 mm); nothing moves sideways or spins
    assert 0.1 - 0.005 <= snap.position[0][1] <= 0.1 + 1e-9
    np.testing.assert_allclose(snap.position[0][[0, 2]], [0.3, -0.2], atol=1e-5)  # 10 um
    assert np.abs(snap.velocity).max() < 1e-6 and np.abs(snap.angular_velocity).max() < 1e-6


# (tilt theta, friction mu) of the inclines: two below the friction angle, two above it.
STICKING = ((0.3, 0.5), (0.45, 0.5))
SLIDING = ((0.6, 0.5), (0.5, 0.2))


def test_boxes_stick_below_the_friction_angle_and_slide_at_coulombs_acceleration_above():
    # A box released at rest on each of four inclines, kinematic slabs tilted by theta about z, 3 m apart
    # (one scene, compiled once), box and slab of friction mu: below the friction angle (tan theta < mu)
    # it stays; above, it slides s(t) = a t^2 / 2 down the slope with a = g (sin theta - mu cos theta).
    slab = ta.shapes.Box((2.0, 0.1, 0.5))
    bodies, starts, downs = [], [], []
    for k, (theta, mu) in enumerate(STICKING + SLIDING):
        n = np.array([-np.sin(theta), np.cos(theta), 0.0])
        down = np.array([-np.cos(theta), -np.sin(theta), 0.0])
        turn = (0.0, 0.0, np.sin(theta / 2), np.cos(theta / 2))  # slab and box turned with the slope
        centre = np.array([0.0, 0.0, 3.0 * k])
        start = centre + 0.2 * n - 1.5 * down  # on the slab's top face, near its upper end
        bodies += [
            (slab, dict(position=tuple(centre), orientation=turn, kinematic=True, friction=mu)),
            (BOX, dict(position=tuple(start), orientation=turn, friction=mu)),
        ]
        starts.append(start)
        downs.append(down)
    m, s, integ = world(bodies)
    t = 1.0
    snap = advance(m, s, integ, t)
    slid = [(snap.position[2 * k + 1] - starts[k]) @ downs[k] for k in range(4)]
    for (theta, mu), distance in zip(STICKING, slid[:2], strict=True):
        assert np.tan(theta) < mu
        assert abs(distance) < 1e-3
    for (theta, mu), distance in zip(SLIDING, slid[2:], strict=True):
        expected = 0.5 * G * (np.sin(theta) - mu * np.cos(theta)) * t * t
        assert distance == pytest.approx(expected, rel=0.02)


@pytest.mark.slow  # exhaustive; covered by restitution and momentum: head-on spheres, default
def test_balls_bounce_at_e_times_their_impact_speed():
    # Dropped from 1 m above contact: impact speed sqrt(2 g h); rebound e times that. Three balls side by
    # side on one frictionless floor of restitution 0 (a contact takes the larger e of its two sides), e
    # = 0, 0.5 and 0.9: one scene, compiled once.
    restitutions = (0.0, 0.5, 0.9)
    ball = ta.shapes.Sphere(0.1)
    balls = [(ball, dict(position=(x, 1.1, 0), restitution=e)) for x, e in enumerate(restitutions)]
    m, s, integ = world(balls, plane=((0, 1, 0), 0.0, 0.0))
    impact = np.sqrt(2 * G * 1.0)
    dt = 1 / 240
    best = np.full(3, -np.inf)
    for _ in range(round(0.6 / dt)):  # lands at 0.45 s; the rebound peaks later
        integ.step(m, s, dt)
        best = np.maximum(best, s.rigid_snapshot().velocity[:, 1])
    np.testing.assert_allclose(best, np.multiply(restitutions, impact), atol=0.02 * impact)


def test_head_on_spheres_keep_momentum_and_part_at_e_times_their_approach():
    # Two spheres of different density, no gravity: after the impact
    # v1' - v2' = -e (v1 - v2) and m1 v1' + m2 v2' = m1 v1 + m2 v2 (Newton's law of restitution). Two
    # such pairs 5 m apart, e = 1 and 0.3, in one scene.
    pairs = []
    ball = ta.shapes.Sphere(0.1)
    for z, e in ((0.0, 1.0), (5.0, 0.3)):
        pairs += [
            (ball, dict(position=(-0.5, 0, z), velocity=(2.0, 0, 0), density=1000.0, restitution=e)),
            (ball, dict(position=(0.5, 0, z), velocity=(-1.0, 0, 0), density=3000.0, restitution=e)),
        ]
    m, s, integ = world(pairs, gravity=False, contacts=dict(bounce_speed=0.1))
    snap = advance(m, s, integ, 1.0)
    for k, e in ((0, 1.0), (2, 0.3)):
        m1, m2 = m.rigid_mass[k : k + 2]
        v1, v2 = snap.velocity[k : k + 2, 0]
        np.testing.assert_allclose(m1 * v1 + m2 * v2, m1 * 2.0 + m2 * -1.0, rtol=1e-12)
        assert v1 - v2 == pytest.approx(-e * 3.0, rel=0.01)
    np.testing.assert_allclose(snap.velocity[:, 1:], 0.0, atol=1e-12)


@pytest.mark.slow  # exhaustive; covered by stacking: the pyramid, default
def test_a_tower_of_twenty_boxes_stands_for_ten_seconds():
    boxes = [(BOX, dict(position=(0.0, 0.1 + 0.2 * k, 0.0))) for k in range(20)]
    m, s, integ = world(boxes, plane=((0, 1, 0), 0.5, 0.5))
    for _ in range(600):
        integ.step(m, s, 1 / 60, substeps=4)
    snap = s.rigid_snapshot()
    top = snap.position[-1]
    assert np.hypot(top[0], top[2]) < 0.01  # the bar: the top drifts less than 1 cm
    assert abs(top[1] - 3.9) < 0.01
    assert np.abs(snap.velocity).max() < 0.05


def test_the_cascade_counts_what_each_level_passes():
    # Three boxes: two far apart (the spheres reject them), two stacked (every level passes).
    bodies = [
        (BOX, dict(position=(0, 0.1, 0))),
        (BOX, dict(position=(0, 0.3, 0))),
        (BOX, dict(position=(5, 0.1, 0))),
    ]
    m, s, integ = world(bodies, plane=((0, 1, 0), 0.5, 0.0))
    integ.step(m, s, 1 / 240)
    cascade = integ.stepper_for(m).solver("rigid bodies").contacts.cascade()
    assert cascade == {
        **{"pairs": 3, "spheres": 1, "aabb": 1, "obb": 1, "touching": 1},
        **{"part_spheres": 1, "exact_tests": 1},  # one part each
    }


# exhaustive; covered by the OBB level: its exact reference and the cascade's counts, default
@pytest.mark.slow
def test_the_obb_level_rejects_crossed_rods_that_their_aabbs_pass():
    # Two thin rods turned 45 degrees about z, side by side 0.3 m apart along x: their AABBs overlap,
    # their OBBs do not. cascade_pairs (what benchmarks/rigid_cascade.py times) stops where asked, and
    # without the OBB level the exact test runs on the pair and finds no contact either.
    rod = ta.shapes.Box((0.5, 0.01, 0.01))
    turn = (0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8))
    m, s, integ = world(
        [
            (rod, dict(position=(0, 1, 0), orientation=turn)),
            (rod, dict(position=(0.3, 1, 0), orientation=turn)),
        ],
        gravity=False,
    )
    integ.step(m, s, 1 / 240)
    contacts = integ.stepper_for(m).solver("rigid bodies").contacts
    assert contacts.cascade() == {
        **{"pairs": 1, "spheres": 1, "aabb": 1, "obb": 0, "touching": 0},
        **{"part_spheres": 0, "exact_tests": 0},
    }
    passed = [contacts.cascade_pairs(m, s, 1 / 240, stop, 0) for stop in range(5)]
    assert passed == [1, 1, 1, 0, 0]
    assert contacts.cascade_pairs(m, s, 1 / 240, 3, 1) == 1  # AABB alone: the pair reaches the exact test
    assert contacts.cascade_pairs(m, s, 1 / 240, 4, 1) == 0


@ti.kernel
def _obb_batch(
    ha: ti.types.ndarray(), hb: ti.types.ndarray(), ra: ti.types.ndarray(), rb: ti.types.ndarray(),
    d: ti.types.ndarray(), out: ti.types.ndarray(),
):  # fmt: skip
    for i in range(out.shape[0]):
        a = ti.Vector([ha[i, 0], ha[i, 1], ha[i, 2]])
        b = ti.Vector([hb[i, 0], hb[i, 1], hb[i, 2]])
        ma = ti.Matrix([[ra[i, r, c] for c in range(3)] for r in range(3)])
        mb = ti.Matrix([[rb[i, r, c] for c in range(3)] for r in range(3)])
        out[i] = ti.i32(obb_overlap(a, b, ma, mb, ti.Vector([d[i, 0], d[i, 1], d[i, 2]]), 0.0))


def random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    from taichi_anim.bodies.rigid.quaternion import quat_to_matrix

    return quat_to_matrix(q)


def lp_overlap(ha, hb, ra, rb, d) -> bool:
    """Whether two boxes share a point: max s such that a point lies inside both boxes shrunk by s
    (a linear program); they overlap iff s >= 0."""
    from scipy.optimize import linprog

    # inside box k: |r_k^T (x - c_k)| <= h_k - s, six half-spaces each; unknowns (x, s), maximise s
    rows, rhs = [], []
    for r, h, c in ((ra, ha, np.zeros(3)), (rb, hb, d)):
        for j in range(3):
            for sign in (1.0, -1.0):
                rows.append(np.append(sign * r[:, j], 1.0))
                rhs.append(h[j] + sign * r[:, j] @ c)
    res = linprog(
        [0, 0, 0, -1.0], A_ub=np.array(rows), b_ub=np.array(rhs), bounds=[(None, None)] * 3 + [(None, 10)]
    )
    return -res.fun >= 0.0


@pytest.mark.parametrize(
    "pairs", [pytest.param(1500, id="1500"), pytest.param(10_000, marks=pytest.mark.slow, id="1e4")]
)
def test_the_obb_test_matches_an_exact_reference(pairs):
    rng = np.random.default_rng(11)
    ha, hb = rng.uniform(0.05, 1.0, (pairs, 3)), rng.uniform(0.05, 1.0, (pairs, 3))
    ra, rb = random_rotations(rng, pairs), random_rotations(rng, pairs)
    d = rng.uniform(-1.5, 1.5, (pairs, 3))
    out = np.zeros(pairs, dtype=np.int32)
    _obb_batch(ha, hb, ra, rb, d, out)
    reference = np.array([lp_overlap(ha[i], hb[i], ra[i], rb[i], d[i]) for i in range(pairs)])
    # the SAT adds 1e-9 to |R| against parallel axes: only pairs within ~1e-8 of touching could differ
    mismatched = np.flatnonzero(out.astype(bool) != reference)
    assert len(mismatched) == 0, mismatched[:10]
    assert 0.2 < reference.mean() < 0.8  # both outcomes well represented


@pytest.mark.slow  # exhaustive; covered by restitution: head-on spheres, default
def test_newtons_cradle_passes_the_momentum_to_the_last_ball():
    # Five equal balls in a row, the first arriving at 1 m/s with e = 1: it stops, the last leaves at
    # 1 m/s and the three between stay (momentum and energy through the row, Guendelman et al.'s
    # collision phase); the balls touch to 0.1 mm.
    r = 0.1
    balls = [(ta.shapes.Sphere(r), dict(position=(-0.5, 0, 0), velocity=(1.0, 0, 0), restitution=1.0))]
    balls += [
        (ta.shapes.Sphere(r), dict(position=((2 * r + 1e-4) * k, 0, 0), restitution=1.0)) for k in range(4)
    ]
    m, s, integ = world(balls, gravity=False, contacts=dict(bounce_speed=0.01))
    snap = advance(m, s, integ, 1.0)
    np.testing.assert_allclose(snap.velocity[:, 0], [0.0, 0.0, 0.0, 0.0, 1.0], atol=1e-9)


@pytest.mark.slow  # exhaustive; covered by stacking: the pyramid, default
def test_a_heavy_on_light_stack_stands():
    # Alternating 1 kg and 100 kg boxes (1:100): ten seconds later still stacked, within 5 mm.
    cube = ta.shapes.Box((0.1, 0.1, 0.1))
    rho = [10.0, 1000.0, 10.0, 1000.0]
    boxes = [(cube, dict(position=(0, 0.1 + 0.2 * k, 0), density=d, friction=0.6)) for k, d in enumerate(rho)]
    m, s, integ = world(boxes, plane=((0, 1, 0), 0.6, 0.0))
    for _ in range(600):
        integ.step(m, s, 1 / 60, substeps=4)
    snap = s.rigid_snapshot()
    expected = 0.1 + 0.2 * np.arange(4)
    assert np.abs(snap.position[:, 1] - expected).max() < 0.01
    assert np.hypot(snap.position[:, 0], snap.position[:, 2]).max() < 0.005


@pytest.mark.parametrize(
    "side", [pytest.param(10, id="10"), pytest.param(20, marks=pytest.mark.slow, id="20")]
)
def test_a_pyramid_of_boxes_stands_for_ten_seconds(side):
    # Rows of side, side - 1, ... 1 cubes of 0.2 m, 5 mm apart: after 10 s no box has moved 1 cm.
    h, start = 0.1, []
    for row in range(side):
        for i in range(side - row):
            start.append(((i - (side - row - 1) / 2) * 2.05 * h, h + 2 * h * row, 0.0))
    cube = ta.shapes.Box((h, h, h))
    m, s, integ = world([(cube, dict(position=p, friction=0.6)) for p in start], plane=((0, 1, 0), 0.6, 0.0))
    for _ in range(600):
        integ.step(m, s, 1 / 60, substeps=4)
    snap = s.rigid_snapshot()
    assert np.linalg.norm(snap.position - np.array(start), axis=1).max() < 0.01
    assert np.abs(snap.velocity).max() < 0.02


def test_a_fast_ball_does_not_pass_through_a_thin_plate():
    # 30 m/s against a 2 cm plate: 12.5 cm per step of 1/240 s, six times the plate's thickness. The
    # contact margin grows with the speeds, so the contact is found before the ball reaches the plate.
    ball = (ta.shapes.Sphere(0.02), dict(position=(-0.5, 0, 0), velocity=(30.0, 0, 0), density=100.0))
    plate = (ta.shapes.Box((0.01, 0.5, 0.5)), dict(position=(0, 0, 0), kinematic=True))
    m, s, integ = world([ball, plate], gravity=False)
    snap = advance(m, s, integ, 0.1)
    assert snap.position[0][0] < -0.01 - 0.02 + 0.005  # still on its side of the plate (within the slop)
    assert snap.velocity[0][0] <= 0.0


def test_a_box_rests_on_a_triangle_mesh_floor():
    # Bodies meet mesh colliders through the collider protocol like analytic ones.
    v = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]], float)
    f = np.array([[0, 2, 1], [0, 3, 2]])
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    b.add_collider_mesh((v, f), restitution=0.0, friction=0.5)
    b.add_rigid_body(BOX, position=(0.3, 0.3, 0.1))
    m = b.finalize()
    s = m.state()
    snap = advance(m, s, ta.make_integrator("symplectic_euler"), 1.5)
    thickness = m.colliders[0].thickness
    assert snap.position[0][1] == pytest.approx(0.1 + thickness, abs=0.006)
    assert np.abs(snap.velocity).max() < 1e-3


def test_a_keyframed_paddle_follows_its_keys_and_pushes_a_box():
    # A kinematic paddle keyed from x = -0.5 to x = 0.5 over 1 s (1 m/s) sweeps a free box resting on a
    # frictionless floor along: the paddle is exactly where its keys put it, the box ahead of it.
    motion = ta.RigidMotion([0.0, 1.0], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    paddle = (ta.shapes.Box((0.05, 0.2, 0.3)), dict(position=(-0.5, 0.2, 0.0), motion=motion))
    box = (ta.shapes.Box((0.1, 0.1, 0.1)), dict(position=(-0.2, 0.1, 0.0), friction=0.0))
    m, s, integ = world([paddle, box], plane=((0, 1, 0), 0.0, 0.0))
    for step in range(240):
        integ.step(m, s, 1 / 240)
        if step == 119:  # t = 0.5 s: halfway along the keys
            np.testing.assert_allclose(s.rigid_snapshot().position[0], [0.0, 0.2, 0.0], atol=1e-6)
    snap = s.rigid_snapshot()
    np.testing.assert_allclose(snap.position[0], [0.5, 0.2, 0.0], atol=1e-6)
    np.testing.assert_allclose(snap.orientation[0], [0.0, 0.0, 0.0, 1.0], atol=1e-9)
    assert snap.position[1][0] > 0.5 + 0.05 + 0.1 - 0.01  # pushed ahead of the paddle's face
    assert m.rigid_kinematic[0]
