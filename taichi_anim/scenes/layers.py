"""Layers: sheets stacked a few centimetres apart fall onto a ball on the floor and drape over it and
over each other, with cloth-cloth contact (implicit Euler + PCG).

Mass-spring cloth (Provot 1995) stepped by linearised backward Euler (Baraff & Witkin 1998, eq. 6); the
sheets keep a thickness apart through the self-contact solver (proximity constraints after Bridson,
Fedkiw & Anderson 2002, and per-vertex displacement bounds after Chen et al. 2024), so no step ends with
two triangles crossing. Each frame exports the sheets as one PLY mesh."""

import numpy as np

from .. import Builder, ClothMaterial
from .base import Scene
from .cloth import FRAME_DT, cloth_integrator
from .drape import uv_sphere

SUBSTEPS = 10  # dt = 1/600 s: contacts between layers resolve within a few millimetres of travel


def build_model(
    *,
    layers: int = 2,
    resolution: int = 33,
    size: float = 1.0,
    height: float = 0.6,
    gap: float = 0.03,
    ball_radius: float = 0.25,
    thickness: float = 0.005,
    self_contact: bool = True,
    material=None,
    friction: float = 0.3,
    guard: bool = True,
    broad_phase: str = "auto",
    pairs_per_vertex: int = 128,
    seed: int = 0,
):
    """The model of the scene: `layers` horizontal `size` [m] sheets of `resolution`^2 vertices, the lowest
    at `height` [m] and each next one `gap` [m] above, over a ball of `ball_radius` [m] resting on the floor
    at the origin; guard=False: self-contact without its displacement bounds; broad_phase: its box
    structure. Returns the model."""
    material = ClothMaterial(density=0.2) if material is None else material
    half = 0.5 * size
    b = Builder()
    b.add_force_gravity()
    for k in range(layers):
        b.add_cloth_grid(
            origin=(-half, height + k * gap, -half),
            size=(size, size),
            resolution=(resolution, resolution),
            plane="xz",
            material=material,
            thickness=thickness,
        )
    b.add_collider_sphere((0.0, ball_radius, 0.0), ball_radius, restitution=0.0, friction=friction)
    b.add_collider_plane(normal=(0.0, 1.0, 0.0), offset=0.0, restitution=0.0, friction=friction)
    if self_contact:
        b.add_cloth_self_contact(
            thickness=thickness,
            friction=friction,
            guard=guard,
            broad_phase=broad_phase,
            pairs_per_vertex=pairs_per_vertex,
        )
    return b.finalize(seed=seed)


def build(
    *,
    seed: int = 0,
    integrator: str = "implicit_euler",
    layers: int = 3,
    resolution: int = 33,
    self_contact: bool = True,
) -> Scene:
    """`layers` 1 m sheets of `resolution`^2 vertices (0.2 kg/m^2, 3 cm apart, the lowest at 0.6 m) falling
    onto a 0.25 m ball on the floor; self_contact=False shows them passing through each other."""
    model = build_model(layers=layers, resolution=resolution, self_contact=self_contact, seed=seed)
    reach = 0.7
    floor = np.array([[-reach, 0.0, -reach], [reach, 0.0, -reach], [reach, 0.0, reach], [-reach, 0.0, reach]])
    return Scene(
        name="layers",
        description="cloth sheets stacked on a ball, with cloth-cloth contact (implicit Euler, PCG)",
        model=model,
        state=model.state(),
        integrator=cloth_integrator(integrator),
        dt=FRAME_DT / SUBSTEPS,
        substeps=SUBSTEPS,
        bounds=((-reach, 0.0, -reach), (reach, 0.75, reach)),
        point_radius=0.005,
        options={"layers": layers, "resolution": resolution, "self_contact": self_contact},
        frames=120,
        props=[uv_sphere((0.0, 0.25, 0.0), 0.985 * 0.25)],
        guides=(floor, np.roll(floor, -1, axis=0)),
        view=(0.55, 0.6, 1.0),
        zoom=1.15,
    )
