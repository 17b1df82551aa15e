"""Pile: boxes, capsules, spheres, convex hulls and a closed mesh poured into a walled bin.

Rigid bodies of every shape the engine has (bodies/rigid/, shapes.py), their mass properties exact
from their shapes; contacts between them and with the floor and walls (analytic colliders) by the
cascade and sequential impulses with Coulomb friction. Each frame exports the bodies as one mesh."""

import numpy as np

from .. import Builder, make_integrator, shapes
from .base import Scene, frame_step

FRAME_DT = 1 / 60  # [s]


def _octahedron(size: float):
    """A closed triangle mesh (an octahedron of half-diagonal `size` [m]), outward-wound."""
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * size
    f = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    return shapes.Mesh(v, f)


def build(
    *,
    seed: int = 0,
    integrator: str = "symplectic_euler",
    layers: int = 4,
    per_side: int = 3,
    bin_half: float = 0.6,
    friction: float = 0.5,
    substeps: int = 4,
) -> Scene:
    """`layers` x `per_side`^2 bodies (a mix of the five shapes, about 0.1 m across, random orientations
    and sizes) dropped from a lattice above a bin of half-width `bin_half` [m] with a floor and four
    walls; Coulomb `friction` everywhere. 1/60 s frames of `substeps` substeps."""
    rng = np.random.default_rng(seed)
    b = Builder()
    b.add_force_gravity()
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0, friction=friction)
    for axis in (0, 2):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = -sign
            b.add_collider_plane(tuple(n), -bin_half, restitution=0.0, friction=friction)
    makers = [
        lambda s: shapes.Box(s * rng.uniform(0.6, 1.0, 3)),
        lambda s: shapes.Capsule(0.6 * s, s),
        lambda s: shapes.Sphere(s),
        lambda s: shapes.ConvexHull(rng.normal(size=(12, 3)) * s),
        lambda s: _octahedron(1.4 * s),
    ]
    spacing = 2.0 * bin_half / per_side
    k = 0
    for layer in range(layers):
        for i in range(per_side):
            for j in range(per_side):
                shape = makers[k % len(makers)](0.07)
                q = rng.normal(size=4)
                b.add_rigid_body(
                    shape,
                    density=800.0,
                    position=(
                        -bin_half + (i + 0.5) * spacing,
                        0.3 + 0.3 * layer,
                        -bin_half + (j + 0.5) * spacing,
                    ),
                    orientation=q / np.linalg.norm(q),
                    friction=friction,
                )
                k += 1
    model = b.finalize(seed=seed)
    lo, hi = (-bin_half, 0.0, -bin_half), (bin_half, 0.3 * layers + 0.3, bin_half)
    return Scene(
        name="pile",
        description=f"{k} rigid bodies of five shapes poured into a bin",
        model=model,
        state=model.state(),
        integrator=make_integrator(integrator),
        dt=frame_step(FRAME_DT, substeps),
        substeps=substeps,
        bounds=(lo, hi),
        point_radius=0.01,
        options={"layers": layers, "per_side": per_side, "bin_half": bin_half, "friction": friction},
        frames=180,
        view=(0.6, 0.7, 1.0),
    )
