"""Moving mesh: a cloth falls onto a ball (a triangle mesh) that then rises and turns, carrying the cloth.

The ball is a triangle-mesh collider (collision/mesh_collider.py) moved by keyframes (collision/motion.py):
still for 0.5 s while the cloth lands on it, then rising 0.3 m and turning 120 degrees about the vertical
over 2 s, then still. Coulomb friction on the ball makes the cloth follow its turn; the floor is a plane.
Mass-spring cloth (Provot 1995) stepped by linearised backward Euler (Baraff & Witkin 1998, eq. 6), with
continuous (swept) collision tests. Each frame exports the cloth and the ball at that time as PLY meshes.
"""

from dataclasses import dataclass

import numpy as np

from .. import Builder, RigidMotion, make_integrator
from ..content import Mesh
from .base import PROP_COLOR, Scene
from .cloth import FRAME_DT, material_for, substeps_for
from .drape import uv_sphere

BALL_FRAMES = 9  # keyframes of the ball's motion (slerp between them)


def ball_motion(*, start: float = 0.5, duration: float = 2.0, rise: float = 0.3, turn_deg: float = 120.0):
    """The ball's RigidMotion: still until `start` [s], then rising `rise` [m] and turning `turn_deg`
    about +y over `duration` [s] (eased in and out: a smoothstep), then still."""
    times = start + np.linspace(0.0, duration, BALL_FRAMES)
    u = np.linspace(0.0, 1.0, BALL_FRAMES)
    ease = u * u * (3.0 - 2.0 * u)
    half = 0.5 * np.radians(turn_deg) * ease
    quats = np.stack([0 * half, np.sin(half), 0 * half, np.cos(half)], axis=1)  # about +y, (x, y, z, w)
    return RigidMotion(times, np.stack([0 * u, rise * ease, 0 * u], axis=1), quats)


@dataclass
class MovingMeshScene(Scene):
    """A Scene whose prop, the ball, moves: each frame exports it as `<name>_ball_NNNN.ply` too, and
    the picture draws it where it is."""

    ball: tuple = ()  # (vertices (V, 3) in the ball's frame [m], faces (F, 3))
    motion: RigidMotion | None = None

    def ball_now(self):
        """(vertices (V, 3) [m], faces (F, 3)) of the ball at the state's time."""
        v, f = self.ball
        return self.motion.apply(v, self.state.time), f

    def frame_content(self) -> list:
        """The cloth (Scene.frame_content) and the ball where it is now (`<name>_ball_NNNN.ply`)."""
        v, f = self.ball_now()
        normals = v - v.mean(axis=0)  # a ball: radial normals
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        ball = Mesh("ball", v, f, normals, tuple(PROP_COLOR), role="collider", animated=True, export=True)
        return [*super().frame_content(), ball]


def build(
    *,
    seed: int = 0,
    integrator: str = "implicit_euler",
    resolution: int = 40,
    size: float = 1.2,
    ball_radius: float = 0.3,
    friction: float = 0.6,
    bend_stiffness: float = 50.0,
) -> Scene:
    """A `size` [m] square cloth of `resolution` x `resolution` vertices released at rest 0.35 m above a
    ball mesh of `ball_radius` [m] resting on the floor; friction: Coulomb coefficient on the ball."""
    n = int(resolution)
    material = material_for("springs", bend_stiffness)
    half = 0.5 * size
    thickness = 0.005
    centre = (0.0, ball_radius, 0.0)
    vertices, faces = uv_sphere((0.0, 0.0, 0.0), ball_radius, rings=16, segments=32)
    motion = ball_motion()
    shifted = RigidMotion(motion.times, motion.translations + np.asarray(centre), motion.rotations)
    b = Builder()
    b.add_force_gravity()
    b.add_cloth_grid(
        origin=(-half, 2.0 * ball_radius + 0.35, -half),
        size=(size, size),
        resolution=(n, n),
        material=material,
        thickness=thickness,
    )
    b.add_collider_mesh((vertices, faces), thickness=0.0, restitution=0.0, friction=friction, motion=shifted)
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0, friction=0.5)
    model = b.finalize(seed=seed)
    vertex_mass = material.density * (size / (n - 1)) ** 2
    substeps = substeps_for(integrator, material, vertex_mass, size / (n - 1))
    if integrator == "implicit_euler":
        integ = make_integrator(
            integrator, linear_solver="pcg", tol=1e-4, max_iterations=200, collision_mode="backward"
        )
    else:
        integ = make_integrator(integrator, check_every=20, collision_mode="backward")
    reach = half + 0.2
    floor = np.array([[-reach, 0.0, -reach], [reach, 0.0, -reach], [reach, 0.0, reach], [-reach, 0.0, reach]])
    return MovingMeshScene(
        name="moving_mesh",
        description="a cloth carried by a rising, turning ball mesh (implicit Euler, swept mesh contacts)",
        model=model,
        state=model.state(),
        integrator=integ,
        dt=FRAME_DT / substeps,
        substeps=substeps,
        bounds=((-reach, 0.0, -reach), (reach, 2.0 * ball_radius + 0.45, reach)),
        point_radius=thickness,
        options={
            "resolution": n,
            "size": size,
            "ball_radius": ball_radius,
            "friction": friction,
            "thickness": thickness,
            "bend_stiffness": bend_stiffness,
            "ball_motion": {"start_s": 0.5, "duration_s": 2.0, "rise_m": 0.3, "turn_deg": 120.0},
        },
        frames=210,
        guides=(floor, np.roll(floor, -1, axis=0)),
        view=(0.55, 0.6, 1.0),
        zoom=1.1,
        ball=(vertices, faces),
        motion=shifted,
    )
