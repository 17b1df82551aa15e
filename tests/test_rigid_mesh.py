"""Triangle-mesh bodies that collide as their own surface (Mesh(contact="triangles")): each triangle a
prism reaching inwards, the prisms in a tree of oriented boxes (obb_tree.py). Rest positions against the
mesh's own geometry (Open3D's distance queries, exact for the mesh), prisms and trees against their
definitions, and the tree's walk against a walk over AABBs alone on interlocked rings."""

import math

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.bodies.rigid.geometry import contact_geometry
from taichi_anim.bodies.rigid.obb_tree import STACK
from taichi_anim.errors import ParameterError

pytestmark = pytest.mark.usefixtures("size_buckets")

G = 9.81
DT = 1 / 240
R_RING, R_TUBE = 0.3, 0.08


def quat_about(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return (*(np.sin(angle / 2) * axis), np.cos(angle / 2))


def torus():
    """A torus about z (radius 0.3 m, tube 0.08 m): 576 triangles, a vertex ring every 15 degrees around
    the axis and every 30 degrees around the tube."""
    import open3d as o3d

    t = o3d.geometry.TriangleMesh.create_torus(
        torus_radius=R_RING, tube_radius=R_TUBE, radial_resolution=24, tubular_resolution=12
    )
    return np.asarray(t.vertices), np.asarray(t.triangles)


def scene(bodies, plane=False):
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    if plane:
        b.add_collider_plane((0, 1, 0), 0.0, friction=0.5, restitution=0.0)
    for shape, kw in bodies:
        b.add_rigid_body(shape, **kw)
    m = b.finalize()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(m)
    return m, m.state(), stepper


def distance_to(vertices, faces, points):
    """Each point's distance to the triangles (Open3D's RaycastingScene, in float32)."""
    import open3d as o3d

    s = o3d.t.geometry.RaycastingScene()
    s.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    return s.compute_distance(o3d.core.Tensor(np.asarray(points, dtype=np.float32))).numpy()


def test_prisms_reach_inwards_inside_the_mesh_and_the_tree_holds_them():
    v, f = torus()
    ring = ta.shapes.Mesh(v, f, contact="triangles")
    prisms = ring.contact_prisms()
    assert prisms.shape == (576, 6, 3)
    depth = np.linalg.norm(prisms[:, 3] - prisms[:, 0], axis=1)
    longest = np.linalg.norm(prisms[:, :3] - np.roll(prisms[:, :3], 1, axis=1), axis=2).max(axis=1)
    assert np.all(depth > 0.0) and np.all(depth <= longest + 1e-12)
    # half the way across the tube at most: every inner corner stays inside the tube
    inner = prisms[:, 3:].reshape(-1, 3)
    radial = np.hypot(inner[:, 0], inner[:, 1]) - R_RING
    assert np.all(np.hypot(radial, inner[:, 2]) < R_TUBE)
    # a set thickness: each corner moved that far along its triangle's inward normal
    thin = ta.shapes.Mesh(v, f, contact="triangles", thickness=0.01).contact_prisms()
    n = np.cross(thin[:, 1] - thin[:, 0], thin[:, 2] - thin[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(thin[:, 3:], thin[:, :3] - 0.01 * n[:, None, :], atol=1e-15)
    geo = contact_geometry(ring, np.zeros(3), np.eye(3))
    for g in geo["geoms"][::37]:
        # each face plane holds the prism (n . p <= d) and touches it (3 or 4 corners on it)
        on = g["points"] @ g["planes"][:, :3].T - g["planes"][:, 3]
        assert np.all(on <= 1e-12) and np.all((np.abs(on) < 1e-12).sum(axis=0) >= 3)
        assert len(g["planes"]) == 5 and len(g["edges"]) == 9
    # each vertex of the surface is a contact point once, no inner corner is one
    flags = np.concatenate([g["contact_points"] for g in geo["geoms"]]).reshape(-1, 6)
    assert not flags[:, 3:].any() and flags.sum() == len(np.unique(v, axis=0))
    tree = geo["tree"]
    nodes = len(tree["bound"])
    assert nodes == 2 * 576 - 1 and sorted(tree["geom"][tree["geom"] >= 0]) == list(range(576))
    # every part's box lies in the box of each node above it (what lets the walk drop a node)
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])
    parts = geo["geoms"]

    def leaves(n, depth):
        kids = tree["child"][n]
        if kids[0] < 0:
            g = parts[tree["geom"][n]]
            return [(signs * g["half_extents"]) @ g["rotation"].T + g["offset"]], depth
        below = [leaves(int(c), depth + 1) for c in kids]
        corners = np.concatenate([c for x in below for c in x[0]])
        local = (corners - tree["offset"][n]) @ tree["rotation"][n]
        assert np.all(np.abs(local) <= tree["half"][n] + 1e-12)
        assert tree["bound"][n] >= np.linalg.norm(tree["half"][n]) - 1e-12
        return [corners], max(x[1] for x in below)

    depth = leaves(0, 1)[1]
    assert depth == math.ceil(math.log2(576)) + 1 and 2 * depth < STACK


def test_prisms_of_a_small_mesh_far_from_the_origin_reach_half_way_through():
    # A 2 cm cube 100 m out: Open3D's rays run in float32 (steps of 8e-6 m there), and a ray that hit
    # its own triangle would make a prism flat. Each prism reaches half the cube's width, to float32.
    v, f = ta.shapes.Box((0.01, 0.01, 0.01)).triangles()
    prisms = ta.shapes.Mesh(np.asarray(v) + [100.0, 50.0, 0.0], f, contact="triangles").contact_prisms()
    np.testing.assert_allclose(np.linalg.norm(prisms[:, 3] - prisms[:, 0], axis=1), 0.01, atol=5e-5)


def test_a_mesh_refuses_a_bad_thickness():
    v, f = torus()
    with pytest.raises(ParameterError, match="thickness"):
        ta.shapes.Mesh(v, f, contact="triangles", thickness=-0.01)


def test_round_shapes_rest_on_a_ring_where_its_own_surface_says():
    # A ball of radius 0.3 in a ring lying flat, and a ring hung on a horizontal peg, both rings as their
    # triangles. The ball settles on the ring's axis where the mesh's distance to its centre is its
    # radius (Open3D's exact distance); the ring hangs with its centre straight below the peg, the
    # vertex at the top of its inner rim (R - r above its centre) on the peg's top.
    v, f = torus()
    ring = ta.shapes.Mesh(v, f, contact="triangles")
    flat = quat_about((1, 0, 0), -np.pi / 2)  # the ring's axis along y
    ball, peg, peg_y = ta.shapes.Sphere(0.3), ta.shapes.Capsule(0.03, 0.3), 1.0
    along_z = quat_about((1, 0, 0), np.pi / 2)
    m, s, stepper = scene(
        [
            (ring, dict(position=(0, 0, 0), orientation=flat, kinematic=True)),
            (ball, dict(position=(0, 0.6, 0))),
            (peg, dict(position=(3, peg_y, 0), orientation=along_z, kinematic=True)),
            (ring, dict(position=(3.0, peg_y - 0.18, 0))),  # its rim 1 cm above the peg
        ]
    )
    for _ in range(480):
        stepper.step(s, DT)
    snap = s.rigid_snapshot()
    heights = np.linspace(0.2, 0.3, 100001)
    turned = v @ ta.rotations.quat_to_matrix(np.array(flat)).T
    gap = distance_to(turned, f, np.stack([0 * heights, heights, 0 * heights], axis=1)) - 0.3
    want = heights[np.argmin(np.abs(gap))]
    assert snap.position[1][1] == pytest.approx(want, abs=2e-4)  # float32 distances: 1e-5 m
    np.testing.assert_allclose(snap.position[1][[0, 2]], 0.0, atol=1e-6)
    hung = snap.position[3]
    assert hung[0] == pytest.approx(3.0, abs=2e-3)
    assert hung[1] == pytest.approx(peg_y + 0.03 - (R_RING - R_TUBE), abs=2e-3)
    assert np.abs(snap.velocity[[1, 3]]).max() < 1e-2


def test_a_triangle_box_rests_on_its_corners_and_a_box_on_a_triangle_slab():
    # A box as its 12 triangles on the floor: one contact per bottom corner (a corner shared by three
    # triangles is a contact point once), at rest at its half height; a box on a slab that collides as
    # its triangles rests on the slab's top.
    box = ta.shapes.Box((0.2, 0.1, 0.15))
    as_triangles = ta.shapes.Mesh(*box.triangles(), contact="triangles")
    slab = ta.shapes.Mesh(*ta.shapes.Box((0.6, 0.05, 0.6)).triangles(), contact="triangles")
    m, s, stepper = scene(
        [
            (as_triangles, dict(position=(0, 0.3, 0))),
            (slab, dict(position=(3, 1.0, 0), kinematic=True)),
            (box, dict(position=(3.1, 1.3, -0.05), orientation=quat_about((0, 1, 0), 0.4))),
        ],
        plane=True,
    )
    for _ in range(360):
        stepper.step(s, DT)
    snap = s.rigid_snapshot()
    assert snap.position[0][1] == pytest.approx(0.1, abs=2e-3)
    assert snap.position[2][1] == pytest.approx(1.05 + 0.1, abs=2e-3)
    assert np.abs(snap.velocity[[0, 2]]).max() < 1e-2
    contacts = stepper.solver("rigid bodies").contacts
    n = contacts.count[None]
    on_floor = contacts.b.to_numpy()[:n] == -1
    assert on_floor.sum() == 4
    corners = contacts.point.to_numpy()[:n][on_floor]
    assert len(np.unique(np.round(corners, 6), axis=0)) == 4


@pytest.mark.slow  # exhaustive; covered by mesh bodies: the triangle box and slab, the sliding box, default
def test_interlocked_triangle_rings_the_obb_tree_halves_the_exact_tests_and_keeps_every_contact():
    # Two tori as their triangles, one hanging in the other: the walk down the trees of OBBs gives the
    # exact test to fewer than half the pairs of triangles a walk over AABBs alone gives it to (the
    # issue's bar for the cascade on interlocked meshes), and loses no contact: the AABBs' walk finds
    # the same ones, and at most a few speculative ones more (a gap along one axis within the margin,
    # between triangles that an OBB axis shows are farther apart).
    v, f = torus()
    link = ta.shapes.Mesh(v, f, contact="triangles")
    m, s, stepper = scene(
        [
            (link, dict(position=(0, 0, 0), kinematic=True)),  # in the xy plane
            (link, dict(position=(0.3, 0, 0), orientation=quat_about((1, 0, 0), np.pi / 2))),
        ]
    )
    for _ in range(120):
        stepper.step(s, DT)
    contacts = stepper.solver("rigid bodies").contacts
    assert contacts.cascade()["touching"] == 1
    assert s.rigid_snapshot().position[1][1] > -0.5  # caught by the other ring, not through it
    found = {}
    for skip_obb in (1, 0):
        assert contacts.cascade_pairs(m, s, DT, 4, skip_obb) == 1
        n = contacts.count[None]
        keys, sep = contacts.key.to_numpy()[:n], contacts.sep.to_numpy()[:n]
        found[skip_obb] = (contacts.cascade(), dict(zip(keys, sep, strict=True)))
        assert contacts.sep.to_numpy()[:n].min() > -0.01  # no deeper than the slop and a step's fall
    with_obb, aabb_only = found[0][0], found[1][0]
    assert 2 * with_obb["exact_tests"] <= aabb_only["exact_tests"]
    assert with_obb["part_spheres"] < aabb_only["part_spheres"]
    assert set(found[0][1]) <= set(found[1][1])
    more = [found[1][1][k] for k in set(found[1][1]) - set(found[0][1])]
    assert len(more) <= 0.01 * len(found[0][1]) and all(sep > 0.0 for sep in more)


def test_a_box_slides_over_a_flat_mesh_without_catching_on_its_triangles_edges():
    # A frictionless slab of 768 triangles (a box subdivided three times), a box and a ball sliding over
    # it at 2 m/s: the edges its triangles share with flat neighbours are inside the surface (no active
    # edges), so nothing catches on them: the speed, the height and the spin stay as they started. Where
    # contacts took a prism's side instead, the box slowed to 0.27 m/s and spun at 6 rad/s.
    import open3d as o3d

    grid = o3d.geometry.TriangleMesh.create_box(4.0, 0.2, 1.0).subdivide_midpoint(3)
    v, f = np.asarray(grid.vertices) - [2.0, 0.2, 0.5], np.asarray(grid.triangles)
    slab = ta.shapes.Mesh(v, f, contact="triangles")
    active = slab.contact_active_edges()
    assert len(f) == 768 and active.sum() == 2 * 12 * 8  # both sides of the box's 12 edges, 8 pieces each
    sliding = dict(velocity=(2.0, 0.0, 0.0), friction=0.0)
    m, s, stepper = scene(
        [
            (slab, dict(position=(0, 0, 0), kinematic=True, friction=0.0)),
            (ta.shapes.Box((0.1, 0.05, 0.1)), dict(position=(-1.5, 0.05, -0.25), **sliding)),
            (ta.shapes.Sphere(0.05), dict(position=(-1.5, 0.05, 0.25), **sliding)),
        ]
    )
    worst = np.zeros(3)
    for _ in range(240):  # 1 s: 2 m, over 16 rows of triangles
        stepper.step(s, DT)
        snap = s.rigid_snapshot()
        speed = np.abs(snap.velocity[1:, 0] - 2.0).max()
        rise = np.abs(snap.position[1:, 1] - 0.05).max()
        worst = np.maximum(worst, [speed, rise, np.abs(snap.angular_velocity[1:]).max()])
    assert worst[0] < 1e-3 and worst[1] < 1e-4 and worst[2] < 1e-3, worst
