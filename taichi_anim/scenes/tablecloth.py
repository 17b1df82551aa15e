"""Tablecloth: a square cloth falls onto a table (a triangle-mesh collider), drapes over its edge and
folds onto itself on the floor, with self-contact (implicit Euler + PCG).

Mass-spring cloth (Provot 1995) stepped by linearised backward Euler (Baraff & Witkin 1998, eq. 6); the
table is a closed triangle mesh (a top and four legs) queried through a bounding volume hierarchy; the
cloth keeps a thickness from itself through the self-contact solver (proximity constraints after
Bridson, Fedkiw & Anderson 2002, displacement bounds after Chen et al. 2024). Each frame exports the
cloth as a PLY mesh."""

import numpy as np

from .. import Builder, ClothMaterial
from ..geometry import box_mesh, merge_meshes
from .base import Scene
from .cloth import FRAME_DT, cloth_integrator

SUBSTEPS = 10  # dt = 1/600 s


def table_mesh(
    *, width: float = 0.9, depth: float = 0.6, height: float = 0.5, top: float = 0.04, leg: float = 0.05
):
    """A table of `width` x `depth` [m] whose top (`top` [m] thick) is at `height` [m], centred over the
    origin, on four square legs of side `leg` [m]: one (vertices, triangles) of five closed boxes."""
    hw, hd = 0.5 * width, 0.5 * depth
    parts = [box_mesh((-hw, height - top, -hd), (hw, height, hd))]
    for sx in (-1, 1):
        for sz in (-1, 1):
            cx, cz = sx * (hw - leg), sz * (hd - leg)
            parts.append(
                box_mesh(
                    (cx - 0.5 * leg, 0.0, cz - 0.5 * leg), (cx + 0.5 * leg, height - top, cz + 0.5 * leg)
                )
            )
    return merge_meshes(parts)


def build(
    *,
    seed: int = 0,
    integrator: str = "implicit_euler",
    resolution: int = 48,
    width: float = 1.6,
    height: float = 1.0,
    thickness: float = 0.004,
    self_contact: bool = True,
) -> Scene:
    """A `width` x `height` [m] cloth of `resolution` vertices across (and as many per metre up), released
    hanging straight down (vertical, in the plane z = 0) 6 cm above a 0.9 x 0.6 m table whose top is at
    0.5 m, its left 0.65 m over the table and the rest past the table's edge: the part over the table
    lands on it edge first and folds onto itself there, the rest falls past the edge to the floor and
    folds onto itself on the floor."""
    n = int(resolution)
    rows = max(2, round(n * height / width))
    table = table_mesh()
    b = Builder()
    b.add_force_gravity()
    b.add_cloth_grid(
        origin=(-0.2, 0.56, 0.0),
        size=(width, height),
        resolution=(n, rows),
        plane="xy",
        material=ClothMaterial(density=0.2, bend_stiffness=20.0),
        thickness=thickness,
    )
    b.add_collider_mesh(table, thickness=0.0, restitution=0.0, friction=0.4)
    b.add_collider_plane(normal=(0.0, 1.0, 0.0), offset=0.0, restitution=0.0, friction=0.6)
    if self_contact:
        b.add_cloth_self_contact(thickness=thickness, friction=0.3)
    model = b.finalize(seed=seed)
    reach = 1.2
    floor = np.array([[-reach, 0.0, -reach], [reach, 0.0, -reach], [reach, 0.0, reach], [-reach, 0.0, reach]])
    return Scene(
        name="tablecloth",
        description="a cloth falling on a table mesh and folding onto itself on the floor (implicit Euler)",
        model=model,
        state=model.state(),
        integrator=cloth_integrator(integrator),
        dt=FRAME_DT / SUBSTEPS,
        substeps=SUBSTEPS,
        bounds=((-0.6, 0.0, -0.6), (1.6, 1.6, 0.6)),
        point_radius=thickness,
        options={
            "resolution": [n, rows],
            "width": width,
            "height": height,
            "thickness": thickness,
            "self_contact": self_contact,
        },
        frames=150,
        props=[table],
        guides=(floor, np.roll(floor, -1, axis=0)),
        view=(0.8, 0.6, 1.0),
        zoom=1.5,
    )
