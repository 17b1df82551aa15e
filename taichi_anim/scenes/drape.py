"""Drape: a square cloth falls onto a ball resting on the floor and drapes over it.

Mass-spring cloth (Provot 1995) stepped by the cheapest method stable at the frame's step
(integrator="auto", integrators/choice.py: symplectic Euler here) or the one named; the
ball and the floor are signed-distance colliders with Coulomb friction, which keep every vertex at least
the cloth's thickness from their surfaces. Each frame exports the cloth as a PLY mesh with vertex
normals."""

import numpy as np

from .. import Builder
from ..shapes import uv_sphere
from .base import Scene, frame_step
from .cloth import FRAME_DT, cloth_method, material_for, substeps_for


def build(
    *,
    seed: int = 0,
    integrator: str = "auto",
    bend_stiffness: float = 50.0,
    resolution: int = 64,
    size: float = 1.6,
    height: float = 1.0,
    ball_radius: float = 0.3,
    ball_friction: float = 0.3,
    floor_friction: float = 0.5,
    material: str = "springs",
    substeps: int | str | None = None,
) -> Scene:
    """A horizontal `size` [m] square cloth of `resolution` x `resolution` vertices, released at rest at
    `height` [m] above a ball of `ball_radius` [m] on the floor (y = 0), a little off the cloth's centre
    so the folds are not symmetric; frictions are Coulomb coefficients; bend_stiffness [N/m] as in the
    cloth demo; material: "springs" or "membrane" as in the cloth demo; substeps per 1/60 s frame: None (the
    cloth demo's rule), a count, or "auto" (the smallest stable count, Scene)."""
    n = int(resolution)
    material_name = material
    material = material_for(material, bend_stiffness)
    half = 0.5 * size
    center = (0.06, ball_radius, -0.04)
    b = Builder()
    b.add_force_gravity()
    b.add_cloth_grid(
        origin=(-half, height, -half),
        size=(size, size),
        resolution=(n, n),
        plane="xz",
        material=material,
        thickness=0.005,
    )
    b.add_collider_sphere(center, ball_radius, restitution=0.0, friction=ball_friction)
    b.add_collider_plane(normal=(0.0, 1.0, 0.0), offset=0.0, restitution=0.0, friction=floor_friction)
    model = b.finalize(seed=seed)
    vertex_mass = material.density * (size / (n - 1)) ** 2
    integ, substeps, choice = cloth_method(
        integrator, model, substeps, lambda: substeps_for(integrator, material, vertex_mass, size / (n - 1))
    )
    reach = half + 0.15
    lo, hi = (-reach, 0.0, -reach), (reach, 0.75 * height, reach)  # framed for the draped cloth
    floor = np.array([[-reach, 0.0, -reach], [reach, 0.0, -reach], [reach, 0.0, reach], [-reach, 0.0, reach]])
    # Drawn a hair smaller than the collider so the cloth (>= thickness away) always covers it.
    ball = uv_sphere(center, 0.985 * ball_radius)
    return Scene(
        name="drape",
        description="a cloth falling onto a ball on the floor",
        model=model,
        state=model.state(),
        integrator=integ,
        integrator_choice=choice,
        dt=frame_step(FRAME_DT, substeps),
        substeps=substeps,
        bounds=(lo, hi),
        point_radius=0.005,
        options={
            "resolution": n,
            "size": size,
            "height": height,
            "ball_center": list(center),
            "ball_radius": ball_radius,
            "ball_friction": ball_friction,
            "floor_friction": floor_friction,
            "thickness": 0.005,
            "bend_stiffness": bend_stiffness,
            "material": material_name,
        },
        frames=150,
        props=[ball],
        guides=(floor, np.roll(floor, -1, axis=0)),  # the floor's outline
        view=(0.55, 0.6, 1.0),
        zoom=1.15,
    )
