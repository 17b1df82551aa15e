"""Dominoes: a row of 30 dominoes on a floor, the first one tipped; each knocks over the next.

Rigid boxes (bodies/rigid/) with Coulomb friction between them and with the floor, stepped semi-
implicitly (kick, sequential impulses with warm starting, drift and the torque-free turn of each body's
angular momentum); contacts found through the cascade of bounding spheres, AABBs and OBBs. Each frame
exports the dominoes as one mesh."""

import numpy as np

from .. import Builder, make_integrator, shapes
from .base import Scene, floor_outline, frame_step

FRAME_DT = 1 / 60  # [s]


def build(
    *,
    seed: int = 0,
    integrator: str = "symplectic_euler",
    count: int = 30,
    spacing: float = 0.22,
    height: float = 0.4,
    width: float = 0.2,
    thickness: float = 0.04,
    friction: float = 0.4,
    push: float = 1.5,
    substeps: int = 4,
) -> Scene:
    """`count` dominoes of `height` x `width` x `thickness` [m] (density 700 kg/m^3, wood), `spacing`
    [m] apart along x on a floor with friction `friction`; the first is spun forward at `push` [rad/s]
    about its bottom edge's axis. 1/60 s frames of `substeps` substeps."""
    b = Builder()
    b.add_force_gravity()
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0, friction=friction)
    half = (0.5 * thickness, 0.5 * height, 0.5 * width)
    for k in range(count):
        spin = (0.0, 0.0, -push) if k == 0 else (0.0, 0.0, 0.0)
        # spinning about its centre at w moves the centre at w x r about the bottom edge: given too
        velocity = np.cross(spin, (0.5 * thickness, 0.5 * height, 0.0)) if k == 0 else (0.0, 0.0, 0.0)
        b.add_rigid_body(
            shapes.Box(half),
            density=700.0,
            position=(k * spacing, 0.5 * height, 0.0),
            velocity=velocity,
            angular_velocity=spin,
            friction=friction,
        )
    model = b.finalize(seed=seed)
    length = (count - 1) * spacing
    lo, hi = (-0.3, 0.0, -0.6), (length + 0.5, height + 0.1, 0.6)
    return Scene(
        name="dominoes",
        description=f"a row of {count} dominoes falling in turn",
        model=model,
        state=model.state(),
        integrator=make_integrator(integrator),
        dt=frame_step(FRAME_DT, substeps),
        substeps=substeps,
        bounds=(lo, hi),
        point_radius=0.01,
        options={
            "count": count,
            "spacing": spacing,
            "height": height,
            "width": width,
            "thickness": thickness,
            "friction": friction,
            "push": push,
        },
        frames=240,
        guides=floor_outline(lo, hi),
        view=(0.3, 0.35, 1.0),
        zoom=1.5,
    )
