"""Rigid cloth: a heavy cloth falls onto a leaning stack of boxes, which tips over under it.

Cloth (mass springs, stepped by implicit Euler) and rigid boxes (bodies/rigid/) acting on each other:
each cloth vertex that hits a box takes a frictional impulse and gives the box the opposite one
(bodies/rigid/particle_coupling.py), so the cloth's weight and its impact push the stack; the boxes meet
each other and the floor through the rigid contacts. Each frame exports the cloth and the boxes as PLY
meshes."""

from .. import Builder, ClothMaterial, make_integrator, shapes
from .base import Scene, floor_outline, frame_step

FRAME_DT = 1 / 60  # [s]


def build(
    *,
    seed: int = 0,
    integrator: str = "implicit_euler",
    boxes: int = 4,
    lean: float = 0.06,
    cloth_density: float = 2.0,
    resolution: int = 24,
    substeps: int = 8,
) -> Scene:
    """A stack of `boxes` 0.3 m cubes (density 100 kg/m^3), each shifted `lean` [m] along +x from the
    one below; a 1 m square cloth of `cloth_density` [kg/m^2] and `resolution`^2 vertices released
    0.3 m above the stack's top, off to the lean's side. 1/60 s frames of `substeps` substeps."""
    b = Builder()
    b.add_force_gravity()
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0, friction=0.6)
    half = 0.15
    for k in range(boxes):
        b.add_rigid_body(
            shapes.Box((half, half, half)),
            density=100.0,
            position=(k * lean, half + 2 * half * k, 0.0),
            friction=0.6,
        )
    top = 2 * half * boxes
    n = int(resolution)
    b.add_cloth_grid(
        origin=(-0.3 + boxes * lean, top + 0.3, -0.5),
        size=(1.0, 1.0),
        resolution=(n, n),
        plane="xz",
        material=ClothMaterial(density=cloth_density),
        thickness=0.01,
    )
    model = b.finalize(seed=seed)
    lo, hi = (-1.2, 0.0, -1.0), (1.6, top + 0.5, 1.0)
    return Scene(
        name="rigid_cloth",
        description="a cloth falling on a leaning stack of boxes, which tips over",
        model=model,
        state=model.state(),
        integrator=make_integrator(integrator),
        dt=frame_step(FRAME_DT, substeps),
        substeps=substeps,
        bounds=(lo, hi),
        point_radius=0.01,
        options={"boxes": boxes, "lean": lean, "cloth_density": cloth_density, "resolution": n},
        frames=150,
        guides=floor_outline(lo, hi),
        view=(0.5, 0.45, 1.0),
        zoom=1.6,
    )
