"""Contacts the exact narrow phase (bodies/rigid/gjk.py, sat.py) gives in scenes that had none before,
against closed forms: two boxes meeting edge on edge, a capsule lying across a beam and across another
capsule, capsules whose cores meet, boxes resting on faces that only clipping finds in contact (and the
four corners a 4-point manifold keeps), a sphere beside a box's edge at its exact distance, a plank on a
ridge, a capsule pushed out of a wall the short way."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.rotations import quat_to_matrix

G = 9.81


def drop(bodies, seconds, dt=1 / 240, gravity=True):
    """Step bodies [(shape, options)] under gravity (or none); the snapshots every step."""
    b = ta.Builder()
    if gravity:
        b.add_force_gravity((0.0, -G, 0.0))
    for shape, options in bodies:
        b.add_rigid_body(shape, **options)
    m = b.finalize()
    s, integ = m.state(), ta.make_integrator("symplectic_euler")
    snaps = []
    for _ in range(round(seconds / dt)):
        integ.step(m, s, dt)
        snaps.append(s.rigid_snapshot())
    return snaps


def quat_about(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return (*(np.sin(angle / 2) * axis), np.cos(angle / 2))


def test_two_boxes_meet_edge_on_edge():
    # A cube turned 45 degrees about z shows an edge along z on top; a cube turned 45 degrees about x,
    # dropped on it, meets it with an edge along x: no vertex of either is inside the other, the contact
    # is the two edges' crossing. The upper cube stops there (its centre 2 h sqrt(2) above the lower's).
    h = 0.25
    cube = ta.shapes.Box((h, h, h))
    top = h * np.sqrt(2)
    snaps = drop(
        [
            (cube, dict(position=(0, 0, 0), orientation=quat_about((0, 0, 1), np.pi / 4), kinematic=True)),
            (cube, dict(position=(0, 2 * top + 0.01, 0), orientation=quat_about((1, 0, 0), np.pi / 4))),
        ],
        0.3,
    )
    heights = np.array([s.position[1][1] for s in snaps])
    assert heights.min() > 2 * top - 0.006  # within the solver's slop (5 mm), not through
    assert abs(heights[-1] - 2 * top) < 0.006


@pytest.mark.slow  # exhaustive; covered by a capsule across another and through a wall's top, default
def test_a_capsule_rests_across_a_beam_narrower_than_its_core():
    # The capsule's end points hang past both sides of the beam: only its core's middle touches.
    beam = ta.shapes.Box((0.05, 0.1, 1.0))
    capsule = ta.shapes.Capsule(0.1, 0.5)
    along_x = quat_about((0, 0, 1), np.pi / 2)  # the capsule's y axis turned onto x
    snaps = drop(
        [
            (beam, dict(position=(0, 0, 0), kinematic=True)),
            (capsule, dict(position=(0, 0.1 + 0.1 + 0.01, 0), orientation=along_x)),
        ],
        1.0,
    )
    y = np.array([s.position[1][1] for s in snaps])
    assert y.min() > 0.2 - 0.006 and abs(y[-1] - 0.2) < 0.006


# A capsule of radius 0.1 m and core 1 m, turned to lie along x or along z.
CAPSULE = ta.shapes.Capsule(0.1, 0.5)
ALONG_X = quat_about((0, 0, 1), np.pi / 2)
ALONG_Z = quat_about((1, 0, 0), np.pi / 2)


def test_a_capsule_rests_across_another():
    snaps = drop(
        [
            (CAPSULE, dict(position=(0, 0, 0), orientation=ALONG_X, kinematic=True)),
            (CAPSULE, dict(position=(0, 0.21, 0), orientation=ALONG_Z)),
        ],
        1.0,
    )
    y = np.array([s.position[1][1] for s in snaps])
    assert y.min() > 0.2 - 0.006 and abs(y[-1] - 0.2) < 0.006
    # and it stays across: nothing pushes it sideways
    assert np.abs(snaps[-1].position[1][[0, 2]]).max() < 1e-6


@pytest.mark.slow  # exhaustive; covered by capsule cores: a capsule across another, default
def test_capsules_whose_cores_meet_part_along_their_common_normal():
    # Cores that meet have no closest-point direction (GJK's distance is 0), and neither capsule's end
    # points touch the other. Crossed at right angles, at one height: they part across both cores (y),
    # until the cores are the two radii apart. End to end on one line, overlapping by 0.2 m: they part
    # along it, to touching ends.
    snaps = drop(
        [
            (CAPSULE, dict(position=(0, 0, 0), orientation=ALONG_X, kinematic=True)),
            (CAPSULE, dict(position=(0, 0, 0), orientation=ALONG_Z)),
            (CAPSULE, dict(position=(5, 0, 0), orientation=ALONG_X, kinematic=True)),
            (CAPSULE, dict(position=(5 + 1.0, 0, 0), orientation=ALONG_X)),
        ],
        0.5,
        gravity=False,
    )
    crossed, in_line = snaps[-1].position[1], snaps[-1].position[3]
    assert abs(crossed[1]) == pytest.approx(0.2, abs=0.006)  # within the slop
    np.testing.assert_allclose(crossed[[0, 2]], 0.0, atol=1e-9)
    assert in_line[0] - 5 == pytest.approx(1.0 + 0.2, abs=0.006)
    np.testing.assert_allclose(in_line[1:], 0.0, atol=1e-9)


@pytest.mark.parametrize("gap", [pytest.param(0.08, marks=pytest.mark.slow), 0.06])  # one gap by default
def test_a_sphere_beside_a_boxs_edge_meets_it_at_its_exact_distance(gap):
    # Centre `gap` past both faces at a box's edge: the exact distance is gap sqrt(2), the faces' planes
    # give only gap (a lower bound). At 0.08 the sphere (r = 0.1) is 13 mm clear of the edge and nothing
    # may push it (the planes would see 20 mm of penetration); at 0.06 it is 15 mm into the edge and is
    # pushed out along the edge's normal, the diagonal (a plane would push along one face's normal).
    r = 0.1
    start = np.array([0.5 + gap, 0.5 + gap, 0.0])
    snaps = drop(
        [
            (ta.shapes.Box((0.5, 0.5, 0.5)), dict(position=(0, 0, 0), kinematic=True)),
            (ta.shapes.Sphere(r), dict(position=tuple(start))),
        ],
        0.5,
        gravity=False,
    )
    moved = snaps[-1].position[1] - start
    if gap * np.sqrt(2) > r:
        assert np.abs(moved).max() < 1e-12
    else:
        assert moved[0] > 0.005 and moved[0] == pytest.approx(moved[1], rel=1e-9)
        assert abs(moved[2]) < 1e-12
        # out to the edge's distance r, less at most the slop the solver leaves (5 mm)
        assert r - 0.005 - 1e-9 <= np.hypot(*(start + moved)[:2] - 0.5) <= r + 1e-3


OCTAGON = 0.5 * (np.sqrt(2) - 1)  # where a square turned by 45 degrees crosses an equal one's sides
CLIPPED_SCENES = {
    # two beams crossed at right angles: the square where they cross
    "crossed beams": (
        ta.shapes.Box((1.0, 0.05, 0.1)),
        ta.shapes.Box((0.1, 0.05, 1.0)),
        (0, 0, 0, 1),
        [(sx * 0.1, sz * 0.1) for sx in (-1, 1) for sz in (-1, 1)],
    ),
    # a box turned by 45 degrees about y on an equal one: the regular octagon where they overlap
    "turned box": (
        ta.shapes.Box((0.5, 0.05, 0.5)),
        ta.shapes.Box((0.5, 0.05, 0.5)),
        (0, np.sin(np.pi / 8), 0, np.cos(np.pi / 8)),
        [(sx * u, sz * v) for sx in (-1, 1) for sz in (-1, 1) for u, v in ((0.5, OCTAGON), (OCTAGON, 0.5))],
    ),
}


@pytest.mark.parametrize("name", CLIPPED_SCENES)
def test_a_box_rests_on_another_on_their_clipped_faces(name):
    # No corner of either lies over the other's face: only face clipping finds the contact polygon, whose
    # corners are where their edges cross (before it, the top body fell through).
    below, above, turn, corners = CLIPPED_SCENES[name]
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    b.add_rigid_body(below, position=(0, 0, 0), kinematic=True)
    b.add_rigid_body(above, position=(0, 0.1005, 0), orientation=turn)
    m = b.finalize()
    s, integ = m.state(), ta.make_integrator("symplectic_euler")
    stepper = integ.stepper_for(m)
    for _ in range(240):
        stepper.step(s, 1 / 240)
    snap = s.rigid_snapshot()
    assert 0.1 - 0.005 <= snap.position[1][1] <= 0.1005
    assert np.abs(snap.position[1][[0, 2]]).max() < 1e-5 and np.abs(snap.angular_velocity).max() < 1e-6
    contacts = stepper.solver("rigid bodies").contacts
    points = contacts.point.to_numpy()[: contacts.count[None]]
    # the polygon's corners, each found from both bodies (to the top body's drift, 10 um)
    nearest = np.linalg.norm(points[:, None, [0, 2]] - np.array(corners)[None], axis=2)
    assert nearest.min(axis=1).max() < 1e-5 and (nearest < 1e-5).sum(axis=0).tolist() == [2] * len(corners)
    normals = contacts.normal.to_numpy()[: len(points)]
    np.testing.assert_allclose(normals, [[0, -1, 0]] * len(points), atol=1e-4)  # from the top body down


def polygon_area(points):
    """Area of the convex polygon through 2-D `points` (any order)."""
    centre = points.mean(axis=0)
    p = points[np.argsort(np.arctan2(*(points - centre).T[::-1]))]
    return 0.5 * abs(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1)))


@pytest.mark.parametrize("name", CLIPPED_SCENES)
def test_four_point_manifolds_keep_the_corners_that_span_the_polygon_most(name):
    # manifold_points=4: of the polygon's corners (each found twice), four distinct ones whose quadrilateral
    # is the largest the polygon holds (the whole square; in the regular octagon, a square of 1/sqrt(2)
    # its area), the same contacts (keys) from step to step, and the top body rests as on all of them.
    below, above, turn, corners = CLIPPED_SCENES[name]
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    b.set_rigid_contacts(manifold_points=4)
    b.add_rigid_body(below, position=(0, 0, 0), kinematic=True)
    b.add_rigid_body(above, position=(0, 0.1005, 0), orientation=turn)
    m = b.finalize()
    s, integ = m.state(), ta.make_integrator("symplectic_euler")
    stepper = integ.stepper_for(m)
    contacts = stepper.solver("rigid bodies").contacts
    keys = set()
    for k in range(240):
        stepper.step(s, 1 / 240)
        if k >= 10:  # landed
            keys.add(tuple(contacts.key.to_numpy()[: contacts.count[None]]))
    assert len(keys) == 1 and len(next(iter(keys))) == 4
    snap = s.rigid_snapshot()
    assert 0.1 - 0.005 <= snap.position[1][1] <= 0.1005
    assert np.abs(snap.position[1][[0, 2]]).max() < 1e-5 and np.abs(snap.angular_velocity).max() < 1e-6
    points = contacts.point.to_numpy()[:4][:, [0, 2]]
    nearest = np.linalg.norm(points[:, None] - np.array(corners)[None], axis=2)
    assert nearest.min(axis=1).max() < 1e-5 and len(set(nearest.argmin(axis=1))) == 4
    full = polygon_area(np.array(corners))
    best = 1.0 if len(corners) == 4 else 1.0 / np.sqrt(2.0)
    assert polygon_area(points) == pytest.approx(best * full, rel=1e-4)


def test_manifold_points_are_0_or_4():
    with pytest.raises(ta.ParameterError, match="manifold_points"):
        ta.Builder().set_rigid_contacts(manifold_points=3)


def test_a_plank_on_a_tilted_boxs_ridge_tips_to_the_side_of_its_centre():
    # The plank rests on one edge (the ridge) of a cube turned 30 degrees about z, its centre 0.3 m to
    # the ridge's left: it must tip to the left. Clipping against the tilted cube's planes (not a face
    # whose normal is the contact axis) once held it level on points in the air.
    c, s_ = np.cos(np.pi / 12), np.sin(np.pi / 12)
    ridge = 0.5 * np.array([np.cos(np.pi / 6) - 0.5, 0.5 + np.cos(np.pi / 6)])  # the cube's top edge
    snaps = drop(
        [
            (
                ta.shapes.Box((0.5, 0.5, 0.5)),
                dict(position=(0, 0, 0), orientation=(0, 0, s_, c), kinematic=True),
            ),
            (ta.shapes.Box((1.5, 0.05, 0.2)), dict(position=(ridge[0] - 0.3, ridge[1] + 0.051, 0))),
        ],
        1.0,
    )
    q = snaps[-1].orientation[1]
    turned = 2 * np.arcsin(q[2])  # about z: positive is counter-clockwise, the left end down is positive
    assert turned > 0.2


def test_a_capsule_through_a_walls_top_is_pushed_out_the_short_way():
    # A capsule lying across a kinematic wall, its core 5 cm below the wall's top and both ends far outside
    # it: neither end point nor the cores' closest points (they meet) give a contact. The core's depth
    # along the wall's top normal (segment_axis, EPA's answer) does: the capsule rises until it lies on the
    # top (y = top + radius, within the slop), still across the wall. Before, nothing held it and it
    # stayed inside the wall.
    top, radius = 0.5, 0.05
    snaps = drop(
        [
            (ta.shapes.Box((0.02, top, 0.5)), dict(position=(0, 0, 0), kinematic=True)),
            (
                ta.shapes.Capsule(radius, 0.5),
                dict(position=(0, top - 0.05, 0), orientation=quat_about((0, 0, 1), np.pi / 2)),
            ),
        ],
        0.5,
        gravity=False,
    )
    x = snaps[-1].position[1]
    assert top + radius - 0.005 - 1e-6 <= x[1] <= top + radius + 0.02
    assert abs(x[0]) < 0.01 and abs(x[2]) < 1e-9  # nothing pushes it along z (symmetric)
    axis = quat_to_matrix(snaps[-1].orientation[1])[:, 1]  # the capsule's core, along its y
    assert abs(axis[0]) > np.cos(np.radians(1.0))
