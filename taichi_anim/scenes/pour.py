"""Pour: water poured from a nozzle into a glass (a closed triangle mesh, a static collider) that holds a
little water already (a closed mesh filled), with a wooden box dropped on it that floats and rises with
the level. The liquid is divergence-free SPH
(bodies/fluid/) with boundary samples on the glass's walls and on the box (two-way: the water lifts the
box, the box pushes the water), emitted in whole layers of its rest lattice, and surfaced every frame
by the course's blobs at the half level (as dam_break). run.json records each frame's pressure solves."""

import numpy as np

from .. import Builder
from ..geometry import revolve_mesh
from ..shapes import Box
from .blobs import BlobScene
from .dam_break import liquid_scene

VIEW = (0.6, 0.5, 1.0)  # the camera's direction from the scene's centre


def back_half(mesh, view):
    """The triangles of `mesh` on the far side of the y axis from a camera looking from `view`: a
    cut-away that shows what the mesh holds (the renderer draws props opaque)."""
    v, f = mesh
    toward = np.array([view[0], 0.0, view[2]])
    return v, f[v[f].mean(axis=1) @ toward < 0.0]


def glass_mesh(radius: float, height: float, wall: float, segments: int = 48):
    """A glass of outer `radius` and `height` [m] with walls and a bottom `wall` [m] thick, standing on
    y = 0 around the y axis, as a closed mesh (vertices, triangles)."""
    inner = radius - wall
    profile = [(0.0, 0.0), (radius, 0.0), (radius, height), (inner, height), (inner, wall), (0.0, wall)]
    return revolve_mesh(profile, segments)


def build(
    *,
    seed: int = 0,
    integrator: str = "symplectic_euler",
    spacing: float = 0.008,
    pour_time: float = 0.8,
    speed: float = 0.5,
    box_density: float = 500.0,
    resolution: int = 64,
    method: str = "dfsph",
) -> BlobScene:
    """A glass 6 cm in radius and 15 cm tall (walls 1.2 cm) holding 4 cm of water, under a nozzle 2
    spacings in radius 2 cm above its rim that pours at `speed` [m/s] from 0.2 s for `pour_time` [s]
    (to about two thirds of the glass at the defaults); a 4 cm box of `box_density` [kg/m^3] dropped
    from 1 cm above the water; liquid `spacing` [m] and solver `method` ("dfsph" or "pbf"); the surface's
    grid has `resolution` nodes across the glass's height."""
    radius, height, wall = 0.06, 0.15, 0.012
    b = Builder()
    b.add_force_gravity()
    glass = glass_mesh(radius, height, wall)
    b.add_collider_mesh(glass, restitution=0.0)
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0)  # the table the glass stands on
    lo, hi = np.array([-radius, 0.0, -radius]), np.array([radius, height + 0.03, radius])
    b.add_fluid(spacing=spacing, domain=(lo, hi), method=method)
    inner, level = radius - wall, wall + 0.04
    b.add_fluid_mesh(revolve_mesh([(0.0, wall), (inner, wall), (inner, level), (0.0, level)], 48))
    b.add_fluid_emitter(center=(0.02, height + 0.02, 0.0), radius=2 * spacing, speed=speed,
                        direction=(0.0, -1.0, 0.0), start_time=0.2, stop_time=0.2 + pour_time)  # fmt: skip
    b.add_rigid_body(Box((0.02, 0.02, 0.02)), density=box_density, position=(-0.02, level + 0.03, 0.0))
    model = b.finalize(seed=seed)
    return liquid_scene(
        "pour",
        model,
        integrator=integrator,
        spacing=spacing,
        bounds=(lo, hi),
        resolution=resolution,
        description=f"water poured into a glass ({model.fluid_count} particles at most), a box floating up",
        options={
            "spacing": spacing,
            "pour_time": pour_time,
            "speed": speed,
            "box_density": box_density,
            "method": method,
        },
        frames=120,
        view=VIEW,
        props=[back_half(glass, VIEW)],  # drawn only: the half away from the camera, so the water shows
        color_ranges={"speed": (0.0, 2.5)},
    )
