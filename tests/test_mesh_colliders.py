"""Triangle-mesh colliders: nothing ends inside a closed mesh in continuous mode at speeds that tunnel in
projection mode (checked with the winding number every step); a mesh box and a mesh quad give the
contacts of the analytic box and plane; cloth on a moving and on a deforming mesh; bad meshes raise."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.spatial import TriangleMesh, winding_number_np

MODES = ["projection", "backward"]


def icosphere(radius: float, subdivisions: int = 1):
    """(vertices, faces) of an icosphere of `radius` [m] at the origin, faces counter-clockwise outside."""
    p = (1.0 + 5.0**0.5) / 2.0
    v = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p)]
    v += [(0, -1, -p), (0, 1, -p), (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2)]
    f += [(10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5)]
    f += [(2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(x, float) / np.linalg.norm(x) for x in v]
    faces = f
    for _ in range(subdivisions):
        mid: dict = {}

        def middle(a, b, mid=mid):
            key = (min(a, b), max(a, b))
            if key not in mid:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                mid[key] = len(verts) - 1
            return mid[key]

        faces = [
            t
            for a, b, c in faces
            for t in ((a, middle(a, b), middle(c, a)), (b, middle(b, c), middle(a, b)),
                      (c, middle(c, a), middle(b, c)), (middle(a, b), middle(b, c), middle(c, a)))
        ]  # fmt: skip
    return np.array(verts) * radius, np.array(faces)


def box_mesh(lo, hi):
    """(vertices (8, 3), faces (12, 3)) of the box lo..hi [m], counter-clockwise seen from outside."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array(
        [[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]] for i in range(8)]
    )
    f = [(0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4)]
    f += [(2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5)]
    return v, np.array(f)


def test_box_mesh_is_closed_and_outward():
    v, f = box_mesh((0, 0, 0), (1, 2, 3))
    a, b, c = (v[f[:, k]] for k in range(3))
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0 == pytest.approx(6.0)  # the volume
    v, f = icosphere(1.0)
    a, b, c = (v[f[:, k]] for k in range(3))
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() > 0.0


def thrown(centre, count, speed, rng):
    """Points on a sphere of radius 0.5 m about `centre`, aimed through it at `speed` [m/s]."""
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    aim = rng.normal(scale=0.05, size=(count, 3))
    return centre + 0.5 * d, -speed * d + aim, d


# Both shapes under slow (36 s each): the default run keeps the closed-mesh contacts of the other tests here.
@pytest.mark.parametrize(
    "shape", [pytest.param("icosphere", marks=pytest.mark.slow), pytest.param("box", marks=pytest.mark.slow)]
)
def test_fast_particles_and_spheres_never_end_inside_a_closed_mesh_in_backward_mode(shape):
    # 60 m/s at dt = 1/60 s: 1 m per step, across the whole mesh (0.5 to 0.6 m wide) from 0.5 m away.
    # Projection sees only the end points, past the mesh: they tunnel. The swept test must stop every
    # one (points and hard spheres alike) at its first contact, for 20 steps of bouncing about.
    v, f = icosphere(0.3, 1) if shape == "icosphere" else box_mesh((-0.25, -0.2, -0.3), (0.25, 0.2, 0.3))
    thickness, radius, dt = 0.01, 0.02, 1.0 / 60.0
    rng = np.random.default_rng(3)
    xp, vp, _ = thrown(np.zeros(3), 60, 60.0, rng)
    xs, vs, _ = thrown(np.zeros(3), 30, 60.0, rng)
    query = TriangleMesh(v, f)
    ends = {}  # mode -> (positions, velocities) after the first step
    for mode in MODES:
        b = ta.Builder()
        points = b.add_particles(xp, vp)
        spheres = b.add_particles(xs, vs, radius=radius)
        b.add_sphere_contacts(restitution=0.5)
        b.add_collider_mesh((v, f), thickness=thickness, restitution=0.5)
        model = b.finalize()
        state = model.state()
        integ = ta.IntegratorSymplecticEuler(collision_mode=mode)
        for k in range(20):
            integ.step(model, state, dt)
            x = state.positions()
            if k == 0:
                ends[mode] = x, state.velocities()
            if mode == "backward":
                assert winding_number_np(v, f, x).max() < 0.5, f"a particle ended inside at step {k}"
                dist, _, _ = query.closest_points(x)
                assert dist[list(points)].min() >= thickness - 1e-9
                assert dist[list(spheres)].min() >= thickness + radius - 1e-9
    # Projection: after one step most points are on the far side of the mesh (they went through it).
    through = np.einsum("ij,ij->i", ends["projection"][0][list(points)], xp) < 0.0
    assert through.mean() > 0.8
    # Backward: every point, aimed at the mesh, was stopped by it within the first step (it bounced).
    assert np.all(np.linalg.norm(ends["backward"][1][list(points)] - vp, axis=1) > 1.0)


def rain(count, rng, lo, hi, height):
    """Points above the square lo..hi (x, z) [m] falling with small sideways speeds."""
    x = np.stack(
        [rng.uniform(lo, hi, count), height + rng.uniform(0, 0.3, count), rng.uniform(lo, hi, count)], 1
    )
    v = np.stack([rng.uniform(-0.3, 0.3, count), rng.uniform(-3, 0, count), rng.uniform(-0.3, 0.3, count)], 1)
    return x, v


# The backward variant compiles the mesh's swept test twice more (about a minute on CI): slow set; the
# default run covers backward mode against meshes in the fast-particle test.
@pytest.mark.slow  # 33 s per mode on 2 cores
@pytest.mark.parametrize("mode", ["projection", "backward"])
def test_mesh_box_and_quad_give_the_contacts_of_the_analytic_box_and_plane(mode):
    # On the faces (away from edges, where the analytic box's grown corners are square and the mesh's
    # round), the mesh's distance, normal and swept contact are the analytic ones: same trajectories to
    # round-off, restitution and friction included. An open quad is a two-sided shell: a point coming
    # from below bounces back down.
    rng = np.random.default_rng(0)
    xb, vb = rain(24, rng, -0.3, 0.3, 0.5)
    xq, vq = rain(24, rng, 1.7, 2.3, 0.3)
    below = np.array([[2.0, -0.2, 2.0]]), np.array([[0.1, 4.0, 0.0]])
    quad = (
        np.array([[1.5, 0.0, 1.5], [2.5, 0.0, 1.5], [2.5, 0.0, 2.5], [1.5, 0.0, 2.5]]),
        [[0, 2, 1], [0, 3, 2]],
    )
    runs = {}
    for kind in ("analytic", "mesh"):
        b = ta.Builder()
        b.add_force_gravity()
        b.add_particles(np.vstack([xb, xq]), np.vstack([vb, vq]), radius=0.01)
        if kind == "mesh":
            b.add_particles(*below, radius=0.01)
            b.add_collider_mesh(box_mesh((-0.5, 0.0, -0.5), (0.5, 0.3, 0.5)), restitution=0.5, friction=0.3)
            b.add_collider_mesh(quad, restitution=0.5, friction=0.3)
        else:
            b.add_collider_box((-0.5, 0.0, -0.5), (0.5, 0.3, 0.5), solid=True, restitution=0.5, friction=0.3)
            b.add_collider_plane((0, 1, 0), 0.0, restitution=0.5, friction=0.3)
        model = b.finalize()
        state = model.state()
        integ = ta.IntegratorSymplecticEuler(collision_mode=mode)
        xs, vs = [], []
        for _ in range(60):
            integ.step(model, state, 1.0 / 120.0)
            xs.append(state.positions())
            vs.append(state.velocities())
        runs[kind] = np.array(xs), np.array(vs)
    xa, xm = runs["analytic"][0], runs["mesh"][0][:, :48]
    assert np.all(np.abs(xa[:, :24, [0, 2]]) < 0.45) and np.all(np.abs(xa[:, 24:, [0, 2]] - 2.0) < 0.45)
    assert np.all(runs["analytic"][1][:, :, 1].max(axis=0) > 0.0)  # every point has bounced
    # In projection mode a step of a few cm carries points across the zero-thickness quad (a shell):
    # there only the closed box is compared.
    compared = slice(0, 48) if mode == "backward" else slice(0, 24)
    np.testing.assert_allclose(xm[:, compared], xa[:, compared], atol=1e-9)
    if mode == "backward":
        # The point from below hit the quad's underside (radius 0.01) and went back down.
        assert runs["mesh"][0][:, 48, 1].max() <= -0.01 + 1e-12
        assert runs["mesh"][1][:, 48, 1].min() < -1.0


@pytest.mark.slow  # ~60-110 s; the moving_mesh demo test carries a cloth on a moving mesh in the default run
def test_cloth_on_a_moving_and_on_a_deforming_mesh_never_has_a_vertex_inside_and_ends_supported():
    # Left: a box mesh that rises 0.2 m and turns 30 degrees about y between t = 0.2 and 1.2 s. Right: a
    # box mesh whose top face is raised 0.2 m over the same time (vertex keyframes). A cloth falls on
    # each; every step no cloth vertex is inside either mesh or nearer than thickness + radius to it, and
    # at the end each cloth lies still on its box's top.
    from scipy.spatial.transform import Rotation

    thickness, radius, dt = 0.005, 0.005, 1.0 / 60.0
    times = np.linspace(0.2, 1.2, 6)
    rise = 0.2 * (times - 0.2)
    turn = Rotation.from_euler("y", 30.0 * (times[:, None] - 0.2), degrees=True).as_quat()
    motion = ta.RigidMotion(times, np.stack([0 * times, rise, 0 * times], 1), turn)
    left = box_mesh((-0.4, -0.2, -0.4), (0.4, 0.0, 0.4))
    right = box_mesh((1.1, -0.2, -0.4), (1.9, 0.0, 0.4))
    top = right[0][:, 1] > -0.1
    frames = np.repeat(right[0][None], 2, axis=0)
    frames[1, top, 1] += 0.2
    b = ta.Builder()
    b.add_force_gravity()
    for x in (-0.25, 1.25):
        b.add_cloth_grid(origin=(x, 0.15, -0.25), size=(0.5, 0.5), resolution=(8, 8), thickness=radius)
    b.add_collider_mesh(left, thickness=thickness, restitution=0.0, friction=0.8, motion=motion)
    b.add_collider_mesh(
        right, thickness=thickness, restitution=0.0, friction=0.8, vertex_frames=([0.2, 1.2], frames)
    )
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorImplicitEuler(collision_mode="backward", tol=1e-6)
    reach = thickness + radius - 1e-9
    queries = TriangleMesh(*left), TriangleMesh(*right)
    for k in range(1, 121):
        integ.step(model, state, dt)
        x = state.positions()
        t = k * dt
        v_left = motion.apply(left[0], t)
        v_right = frames[0] + np.clip((t - 0.2) / 1.0, 0.0, 1.0) * (frames[1] - frames[0])
        for verts, faces, query in ((v_left, left[1], queries[0]), (v_right, right[1], queries[1])):
            assert winding_number_np(verts, faces, x).max() < 0.5, f"a vertex inside at step {k}"
            query.set_vertices(verts)
            dist, _, _ = query.closest_points(x)
            assert dist.min() >= reach, f"a vertex within the thickness at step {k}"
    v = state.velocities()
    np.testing.assert_allclose(x[:, 1], 0.2 + thickness + radius, atol=1e-6)  # both tops end at 0.2 m
    assert np.abs(v).max() < 1e-3


@pytest.mark.parametrize(
    "mesh, match",
    [
        ((np.zeros((0, 3)), np.zeros((0, 3), int)), "vertices is empty"),
        ((np.eye(3), np.zeros((0, 3), int)), "faces is empty"),
        ((np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), [[0, 1, 2]]), "non-finite"),
        ((np.eye(3), [[0, 1, 3]]), "outside"),
        ((np.eye(3), [[0, 1, -1]]), "outside"),
        ((np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]]), [[0, 1, 2], [0, 2, 1]]), "zero area"),
        ((np.eye(3), [[0.5, 1, 2]]), "integers"),
        ("/nonexistent/collider.ply", "not found"),
        (42, "expected an Open3D TriangleMesh"),
    ],
)
def test_bad_meshes_raise(mesh, match):
    with pytest.raises(ta.ParameterError, match=match):
        ta.Builder().add_collider_mesh(mesh)


def test_mesh_files_and_open3d_meshes_and_bad_options(tmp_path):
    import open3d as o3d

    v, f = box_mesh((0, 0, 0), (1, 1, 1))
    o3 = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
    path = tmp_path / "box.ply"
    assert o3d.io.write_triangle_mesh(str(path), o3)
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nthis is not a mesh\n\x00\x01")
    b = ta.Builder()
    b.add_particle((0.5, 2.0, 0.5))
    b.add_collider_mesh(str(path))
    b.add_collider_mesh(o3)
    b.add_collider_mesh(o3d.t.geometry.TriangleMesh.from_legacy(o3))
    b.add_collider_mesh((v, f[:, [0, 2, 1]]))  # inward faces: turned outwards
    b.add_collider_mesh((v, f[:10]))  # two faces missing: an open shell
    kinds = [c["closed"] for c in b.finalize().settings["colliders"]]
    assert kinds == [True, True, True, True, False]
    with pytest.raises(ta.ParameterError, match="garbage"):
        ta.Builder().add_collider_mesh(str(garbage))
    motion = ta.RigidMotion([0.0], [[0.0, 0.0, 0.0]])
    for options, match in [
        (dict(thickness=-0.1), "thickness"),
        (dict(restitution=2.0), "restitution"),
        (dict(friction=-1.0), "friction"),
        (dict(motion="spin"), "motion"),
        (dict(vertex_frames=([0.0, 1.0], np.zeros((2, 7, 3)))), "vertex_frames positions"),
        (dict(vertex_frames=([1.0, 0.0], np.zeros((2, 8, 3)))), "times must increase"),
        (dict(vertex_frames=[0.0]), "vertex_frames must be"),
        (dict(motion=motion, vertex_frames=([0.0], np.zeros((1, 8, 3)))), "not both"),
    ]:
        with pytest.raises(ta.ParameterError, match=match):
            ta.Builder().add_collider_mesh((v, f), **options)


@pytest.mark.slow  # ~1 min of demo frames; test_demos runs the moving_mesh demo by default
def test_moving_mesh_demo_carries_the_cloth_and_exports_the_ball(tmp_path):
    # The demo's ball (a UV-sphere mesh) rises 0.3 m and turns 120 degrees about +y between t = 0.5 and
    # 2.5 s. The cloth lying on it never gets inside it or within its thickness, is lifted with it and,
    # held by friction, turns with it (checked every 4th frame, 16 substeps); each frame exports the ball
    # where it is.
    from taichi_anim.io.export import read_triangle_mesh
    from taichi_anim.scenes import make_scene

    ta.init("cpu")  # the demo's single precision
    scene = make_scene("moving_mesh", resolution=16)
    v, f = scene.ball
    query = TriangleMesh(*scene.ball_now())
    thickness = scene.options["thickness"]

    def on_ball(x):
        centre = scene.ball_now()[0].mean(axis=0)
        near = np.linalg.norm(x - centre, axis=1) < scene.options["ball_radius"] + 0.02
        return np.arctan2(x[:, 2] - centre[2], x[:, 0] - centre[0]), near

    for frame in range(160):
        scene.advance_frame()
        x = scene.state.positions()
        if frame % 4 == 0:  # every 4th frame: the checks cost more than the steps
            ball = scene.ball_now()[0]
            assert winding_number_np(ball, f, x).max() < 0.5
            query.set_vertices(ball)
            assert query.closest_points(x)[0].min() >= thickness - 1e-5
        if frame == 29:  # t = 0.5 s: landed, the ball about to move
            top0, (angle0, near0) = x[:, 1].max(), on_ball(x)
    angle1, near1 = on_ball(x)
    both = near0 & near1
    turned = np.degrees(np.unwrap(np.stack([angle0[both], angle1[both]]), axis=0)[1] - angle0[both])
    assert both.sum() >= 10 and np.median(turned) < -100.0  # +y turns x towards -z: the angle falls
    assert x[:, 1].max() - top0 > 0.25
    ply = [p for p in scene.export_frame(tmp_path, 0) if "ball" in p.name]
    np.testing.assert_allclose(read_triangle_mesh(ply[0])["vertices"], scene.ball_now()[0], atol=1e-6)
