"""Compound shapes (ta.shapes.Compound): mass properties against closed forms, and contacts part by
part, where a concave body made of convex parts rests as itself and not as its convex hull."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.errors import ParameterError

G = 9.81
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def quat_about(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return (*(np.sin(angle / 2) * axis), np.cos(angle / 2))


def test_two_boxes_side_by_side_weigh_as_the_box_they_make():
    half = ta.shapes.Box((0.1, 0.2, 0.3))
    pair = ta.shapes.Compound([(half, (-0.1, 0, 0), IDENTITY), (half, (0.1, 0, 0), IDENTITY)])
    whole = ta.shapes.Box((0.2, 0.2, 0.3))
    got, want = pair.mass_properties(700.0), whole.mass_properties(700.0)
    assert got.mass == pytest.approx(want.mass, rel=1e-12)
    np.testing.assert_allclose(got.com, want.com, atol=1e-15)
    np.testing.assert_allclose(got.inertia, want.inertia, rtol=1e-12)


def test_a_turned_and_moved_part_carries_its_inertia():
    box = ta.shapes.Box((0.3, 0.1, 0.05))
    q = quat_about((1, 2, 3), 0.7)
    one = ta.shapes.Compound([(box, (0.5, -0.2, 0.1), q)]).mass_properties(1000.0)
    r = ta.rotations.quat_to_matrix(np.array(q))
    ref = box.mass_properties(1000.0)
    np.testing.assert_allclose(one.com, [0.5, -0.2, 0.1], atol=1e-15)
    np.testing.assert_allclose(one.inertia, r @ ref.inertia @ r.T, rtol=1e-12, atol=1e-15)


def test_a_dumbbell_has_the_parallel_axis_inertia():
    r, d, rho = 0.1, 0.4, 500.0
    ball = ta.shapes.Sphere(r)
    bell = ta.shapes.Compound([(ball, (0, 0, -d), IDENTITY), (ball, (0, 0, d), IDENTITY)]).mass_properties(
        rho
    )
    m = rho * 4 / 3 * np.pi * r**3
    own = 0.4 * m * r * r
    np.testing.assert_allclose(bell.inertia, np.diag([2 * (own + m * d * d)] * 2 + [2 * own]), rtol=1e-12)


@pytest.mark.parametrize(
    "parts, match",
    [
        ([], "1..4096 parts"),
        ([(ta.shapes.Box((1, 1, 1)), (0, 0, 0))], "parts\\[0\\] must be"),
        ([(ta.shapes.Mesh(*ta.shapes.Box((1, 1, 1)).triangles()), (0, 0, 0), IDENTITY)], "convex part"),
        ([(ta.shapes.Box((1, 1, 1)), (0, 0, 0), (0, 0, 0, 2))], "unit quaternion"),
        ([(ta.shapes.Box((1, 1, 1)), (0, np.nan, 0), IDENTITY)], "position"),
    ],
)
def test_bad_parts_are_refused_with_the_part_named(parts, match):
    with pytest.raises(ParameterError, match=match):
        ta.shapes.Compound(parts)


def settle(bodies, seconds, *, floor=True, dt=1 / 240):
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    if floor:
        b.add_collider_plane((0, 1, 0), 0.0, friction=0.5)
    for shape, options in bodies:
        b.add_rigid_body(shape, **options)
    m = b.finalize()
    s, integ = m.state(), ta.make_integrator("symplectic_euler")
    for _ in range(round(seconds / dt)):
        integ.step(m, s, dt)
    return s.rigid_snapshot()


def test_a_table_stands_on_its_four_legs():
    # a top 1 x 0.04 x 0.6 m on four legs 0.5 m long: its frame at the floor, its top 0.52 m up
    leg = ta.shapes.Box((0.03, 0.25, 0.03))
    parts = [(ta.shapes.Box((0.5, 0.02, 0.3)), (0, 0.52, 0), IDENTITY)]
    parts += [(leg, (x, 0.25, z), IDENTITY) for x in (-0.45, 0.45) for z in (-0.25, 0.25)]
    table = ta.shapes.Compound(parts)
    snap = settle([(table, dict(position=(0, 0.002, 0)))], 2.0)
    # its frame (the legs' feet) on the floor, within the solver's 5 mm slop; level; at rest
    assert -0.005 <= snap.position[0][1] <= 1e-6
    np.testing.assert_allclose(np.abs(snap.orientation[0][:3]).max(), 0.0, atol=1e-4)
    assert np.abs(snap.velocity[0]).max() < 1e-4


@pytest.mark.slow  # exhaustive; covered by parts, not hulls: the ring over the peg, default
def test_a_cap_rests_on_a_pillar_inside_it_not_on_its_hull():
    # A cap (a plate on four walls, open below) lowered over a thin pillar rests with its plate on the
    # pillar's top; its convex hull would have stopped with the walls' lower edges at the top instead.
    pillar = ta.shapes.Box((0.05, 0.5, 0.05))
    wall_x = ta.shapes.Box((0.02, 0.15, 0.2))
    wall_z = ta.shapes.Box((0.2, 0.15, 0.02))
    cap = ta.shapes.Compound(
        [
            (ta.shapes.Box((0.2, 0.02, 0.2)), (0, 0.02, 0), IDENTITY),  # the plate, from 0 to 0.04
            (wall_x, (-0.18, -0.15, 0), IDENTITY),
            (wall_x, (0.18, -0.15, 0), IDENTITY),
            (wall_z, (0, -0.15, -0.18), IDENTITY),
            (wall_z, (0, -0.15, 0.18), IDENTITY),
        ]
    )
    snap = settle(
        [
            (pillar, dict(position=(0, 0.5, 0), kinematic=True)),
            (cap, dict(position=(0, 1.0 + 0.01, 0))),
        ],
        1.5,
        floor=False,
    )
    # the cap's frame (the plate's underside) on the pillar's top
    assert 1.0 - 0.006 <= snap.position[1][1] <= 1.0 + 1e-6
    np.testing.assert_allclose(snap.position[1][[0, 2]], [0.0, 0.0], atol=1e-4)


def test_compound_bodies_collide_with_each_other_part_by_part():
    # Two dumbbells stacked parallel: the upper one rests ball on ball on the lower one (its centre two
    # radii above), its bar clear of the other's.
    ball = ta.shapes.Sphere(0.1)
    bar = ta.shapes.Capsule(0.02, 0.2)
    along_x = quat_about((0, 0, 1), np.pi / 2)
    bell = ta.shapes.Compound(
        [(ball, (-0.3, 0, 0), IDENTITY), (ball, (0.3, 0, 0), IDENTITY), (bar, (0, 0, 0), along_x)]
    )
    snap = settle(
        [(bell, dict(position=(0, 0.1, 0))), (bell, dict(position=(0, 0.31, 0)))],
        1.5,
    )
    assert 0.1 - 0.005 <= snap.position[0][1] <= 0.1 + 1e-6
    assert 0.3 - 0.011 <= snap.position[1][1] <= 0.3 + 1e-6
    np.testing.assert_allclose(snap.position[1][[0, 2]], [0.0, 0.0], atol=1e-3)


def torus(radius=0.3, tube=0.08):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_torus(
        torus_radius=radius, tube_radius=tube, radial_resolution=24, tubular_resolution=12
    )
    return np.asarray(m.vertices), np.asarray(m.triangles)


# The hull case (15 s on 2 cores) is slow: the parts case runs the same scene through the cascade.
@pytest.mark.parametrize("contact", ["parts", pytest.param("hull", marks=pytest.mark.slow)])
def test_a_ring_drops_over_a_peg_only_as_convex_parts(contact):
    # A torus (hole radius 0.22 m) dropped flat over a peg 0.1 m wide: as CoACD's convex parts it slides
    # down around the peg to the floor, its centre a tube radius up; as its convex hull (a disc) it
    # stays on the peg's top, 1 m up, its centre a tube radius above.
    v, f = torus()
    ring = ta.shapes.Mesh(v, f, contact=contact)
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    b.add_collider_plane((0, 1, 0), 0.0, friction=0.5, restitution=0.0)
    b.add_rigid_body(ta.shapes.Box((0.05, 0.5, 0.05)), position=(0, 0.5, 0), kinematic=True)
    b.add_rigid_body(ring, position=(0, 1.3, 0), orientation=quat_about((1, 0, 0), np.pi / 2))
    m = b.finalize()
    s, integ = m.state(), ta.make_integrator("symplectic_euler")
    for _ in range(360):
        integ.step(m, s, 1 / 240)
    x = s.rigid_snapshot().position[1]
    if contact == "parts":
        assert len(ring.contact_parts()) > 4  # a ring needs several convex pieces
        assert abs(x[1] - 0.08) < 0.01 and np.hypot(x[0], x[2]) < 0.22 - 0.05  # on the floor, round the peg
    else:
        assert abs(x[1] - 1.08) < 0.01


def test_a_mesh_refuses_an_unknown_contact_model():
    v, f = torus()
    with pytest.raises(ParameterError, match="contact"):
        ta.shapes.Mesh(v, f, contact="voxels")
    with pytest.raises(ParameterError, match="threshold"):
        ta.shapes.Mesh(v, f, contact="parts", threshold=0.0)
    with pytest.raises(ParameterError, match="part_vertices"):
        ta.shapes.Mesh(v, f, contact="parts", part_vertices=3)


@pytest.mark.slow  # exhaustive; covered by compound against compound: part by part, default
def test_the_cascade_goes_on_between_parts_and_loses_no_contact():
    # Two tori interlocked as chain links, one hanging in the other, each as CoACD's convex parts in a
    # tree of OBBs: its walk leaves fewer exact tests than a walk over AABBs alone, fewer than every pair
    # of parts, and the same contacts.
    v, f = torus()
    link = ta.shapes.Mesh(v, f, contact="parts")
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    b.add_rigid_body(link, position=(0, 0, 0), kinematic=True)  # in the xy plane
    b.add_rigid_body(link, position=(0.3, 0, 0), orientation=quat_about((1, 0, 0), np.pi / 2))
    m = b.finalize()
    s, integ = m.state(), ta.make_integrator("symplectic_euler")
    stepper = integ.stepper_for(m)
    for _ in range(240):
        stepper.step(s, 1 / 240)
    contacts = stepper.solver("rigid bodies").contacts
    assert contacts.cascade()["touching"] == 1  # hanging in the other
    found = {}
    for skip_obb in (1, 0):
        assert contacts.cascade_pairs(m, s, 1 / 240, 4, skip_obb) == 1
        n = contacts.count[None]
        found[skip_obb] = (contacts.cascade(), np.sort(contacts.key.to_numpy()[:n]))
    parts = len(link.contact_parts())
    with_obb, aabb_only = found[0][0], found[1][0]
    assert with_obb["part_spheres"] <= aabb_only["part_spheres"]  # pairs of nodes
    assert 0 < with_obb["exact_tests"] < aabb_only["exact_tests"] < parts * parts
    np.testing.assert_array_equal(found[0][1], found[1][1])
