"""Cloth building and options: parameter errors name the value; a cloth rests on a box and a ball at its
thickness with Coulomb friction; the sphere collider's swept test; solves are deterministic."""

import numpy as np
import pytest

import taichi_anim as ta


def small_cloth(**options):
    b = ta.Builder()
    b.add_force_gravity()
    cloth = b.add_cloth_grid(resolution=(6, 6), **options)
    return b, cloth


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (dict(resolution=(1, 6)), "resolution"),
        (dict(size=(1.0, -1.0)), "size"),
        (dict(plane="yz"), "plane"),
        (dict(resolution=(6, 6), pinned=[36]), "pinned"),
        (dict(thickness=0.0), "thickness"),
        (dict(material="silk"), "material"),
    ],
)
def test_cloth_grid_rejects_bad_options(options, words):
    b = ta.Builder()
    with pytest.raises(ta.ParameterError, match=words):
        b.add_cloth_grid(**options)


def test_material_rejects_negative_values():
    with pytest.raises(ta.ParameterError, match="bend_stiffness"):
        ta.ClothMaterial(bend_stiffness=-1.0)
    with pytest.raises(ta.ParameterError, match="density"):
        ta.ClothMaterial(density=0.0)


def test_cloth_mesh_rejects_unused_vertex():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [5, 5, 5]], float)
    with pytest.raises(ta.ParameterError, match="vertex 3"):
        ta.Builder().add_cloth_mesh((v, np.array([[0, 2, 1]])))


def test_add_springs_rejects_self_spring_and_bad_index():
    b = ta.Builder()
    b.add_particles(np.eye(3))
    with pytest.raises(ta.ParameterError, match="itself"):
        b.add_springs([[1, 1]], stiffness=1.0)
    with pytest.raises(ta.ParameterError, match="pairs"):
        b.add_springs([[0, 3]], stiffness=1.0)
    with pytest.raises(ta.ParameterError, match="stiffness"):
        b.add_springs([[0, 1]], stiffness=-1.0)


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (dict(linear_solver="gauss"), "linear_solver"),
        (dict(tol=0.0), "tol"),
        (dict(max_iterations=0), "max_iterations"),
    ],
)
def test_implicit_rejects_bad_solver_options(options, words):
    with pytest.raises(ta.ParameterError, match=words):
        ta.IntegratorImplicitEuler(**options)


def test_cloth_masses_and_springs_from_the_material():
    mat = ta.ClothMaterial(density=0.5, stretch_stiffness=7.0, shear_stiffness=0.0, bend_stiffness=3.0)
    b = ta.Builder()
    b.add_cloth_grid(size=(2.0, 1.0), resolution=(5, 3), material=mat, pinned=[0])
    model = b.finalize()
    mass = model.particle_masses()
    # Lumped masses sum to density * area once the pinned vertex's share is added back.
    assert mass[0] == 0.0
    # Vertex 0 lies on the split diagonal: two triangles of 0.125 m^2, a third of each.
    assert mass.sum() + 2 * 0.5 * 0.125 / 3 == pytest.approx(0.5 * 2.0)
    # Shear stiffness 0 leaves the shear family out; stretch and bend keep their own stiffness.
    k = model.springs.stiffness
    assert set(np.unique(k)) == {3.0, 7.0}
    assert (k == 7.0).sum() == 4 * 3 + 5 * 2  # horizontal + vertical neighbours
    assert (k == 3.0).sum() == 3 * 3 + 5 * 1  # two apart horizontally + vertically


def settle(model, state, integ, steps, dt):
    for _ in range(steps):
        integ.step(model, state, dt)
    return state.positions(), state.velocities()


@pytest.mark.parametrize("mode", ["projection", "backward"])
def test_cloth_rests_on_a_solid_box_at_its_thickness(mode):
    # A 0.4 m cloth over a 1 m box top (y = 0.3): every vertex ends at y >= 0.3 + thickness, and it
    # comes to rest (friction and spring damping take out the impact).
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(origin=(-0.2, 0.5, -0.2), size=(0.4, 0.4), resolution=(8, 8), thickness=0.01)
    b.add_collider_box((-0.5, 0.0, -0.5), (0.5, 0.3, 0.5), solid=True, restitution=0.0, friction=0.5)
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorImplicitEuler(collision_mode=mode, tol=1e-6)
    x, v = settle(model, state, integ, 90, 1 / 60)
    assert x[:, 1].min() >= 0.31 - 1e-9
    assert x[:, 1].max() < 0.32
    assert np.abs(v).max() < 1e-3


def test_friction_holds_cloth_on_a_slope():
    # Coulomb: a cloth on a 20 degree slope stays put with mu = 0.6 > tan 20 = 0.36 and slides with mu = 0.
    angle = np.radians(20.0)
    normal = (-np.sin(angle), np.cos(angle), 0.0)
    travelled = []
    for mu in (0.6, 0.0):
        b = ta.Builder()
        b.add_force_gravity()
        vertices = np.array([[x, 0.0, z] for z in np.linspace(0, 0.2, 5) for x in np.linspace(0, 0.2, 5)])
        rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
        tri = [(j * 5 + i, (j + 1) * 5 + i + 1, j * 5 + i + 1) for j in range(4) for i in range(4)]
        tri += [(j * 5 + i, (j + 1) * 5 + i, (j + 1) * 5 + i + 1) for j in range(4) for i in range(4)]
        b.add_cloth_mesh((vertices @ rot.T + 0.01 * np.asarray(normal), np.array(tri)), thickness=0.01)
        b.add_collider_plane(normal, 0.0, restitution=0.0, friction=mu)
        model = b.finalize()
        state = model.state()
        x0 = state.positions()
        x, _ = settle(model, state, ta.IntegratorImplicitEuler(tol=1e-6), 60, 1 / 120)
        travelled.append(np.linalg.norm(x - x0, axis=1).mean())
    # Without friction it slides about g sin(20) t^2 / 2 = 0.42 m in 0.5 s; with friction ~0.
    assert travelled[0] < 0.01
    assert travelled[1] > 0.3


def test_sphere_sweep_stops_a_fast_particle_in_front_of_the_ball():
    # At 100 m/s and dt = 1/60 a particle jumps 1.67 m per step, across the whole 0.2 m ball: the swept
    # test in backward mode still stops it on the near side; projection alone lets it through.
    ends = {}
    for mode in ("backward", "projection"):
        b = ta.Builder()
        b.add_particle((-1.0, 0.0, 0.0), (100.0, 0.0, 0.0), radius=0.01)
        b.add_collider_sphere((0.0, 0.0, 0.0), 0.1, restitution=0.0)
        model = b.finalize()
        state = model.state()
        ta.IntegratorSymplecticEuler(collision_mode=mode).step(model, state, 1 / 60)
        ends[mode] = state.positions()[0]
    assert ends["backward"][0] == pytest.approx(-0.11, abs=1e-9)
    assert ends["projection"][0] > 0.5


def test_implicit_cloth_step_is_identical_on_one_and_two_threads():
    results = []
    for threads in (1, 2):
        ta.init("cpu", precision="f32", cpu_threads=threads)
        b = ta.Builder()
        b.add_force_gravity()
        b.add_cloth_grid(resolution=(40, 40), pinned=[0, 39])  # 10 blocks of 256 rows
        model = b.finalize()
        state = model.state()
        settle(model, state, ta.IntegratorImplicitEuler(tol=1e-5), 5, 1 / 60)
        results.append(state.positions())
    assert np.array_equal(results[0], results[1])
