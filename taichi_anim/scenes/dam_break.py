"""Dam break: a column of water (width a, height 2 a: Martin & Moyce's n^2 = 2 case) released in a tank
4.5 a long, made incompressible by divergence-free SPH (bodies/fluid/) and surfaced every frame by the
course's blobs: the particles' Gaussian field (Blinn 1982) and its isosurface (taichi_anim/blobs), at
the level where the field falls to half its value inside the liquid, which on a flat surface lies half
a spacing beyond the outer particles (where the liquid's volume ends). run.json records each frame's
pressure iterations and density errors (`solver_frames`)."""

import math

import numpy as np

from .. import Builder, make_integrator
from ..blobs import BlobField
from .blobs import BlobScene

FRAME_DT = 1 / 60  # [s]


# The liquid's blobs reach 2.5 sigma (the field's default is 3): a blob's truncation is then
# exp(-6.25) = 0.2 % of its peak, and the field takes two thirds of the time with the same smooth surface
# (a 54,000-particle column: 184 against 276 ms, 71,992 triangles both; at 2 sigma the truncation
# dimples the surface, 41 % more triangles). The iso level uses the same cutoff.
LIQUID_CUTOFF = 2.5


def half_level(spacing: float, sigma: float, cutoff: float = 3.0) -> float:
    """Half of the blob field sum_j exp(-|x - x_j|^2 / sigma^2) over |x - x_j| < cutoff sigma inside a
    cubic lattice of `spacing`."""
    n = int(math.ceil(cutoff * sigma / spacing))
    k = np.arange(-n, n + 1) * spacing
    g = np.stack(np.meshgrid(k, k, k, indexing="ij"), -1).reshape(-1, 3)
    r2 = (g**2).sum(axis=1)
    return 0.5 * float(np.exp(-r2[r2 < (cutoff * sigma) ** 2] / sigma**2).sum())


def liquid_scene(name: str, model, *, integrator: str, spacing: float, bounds, resolution: int, **scene):
    """A BlobScene of a liquid of `spacing` [m] within `bounds` (lo, hi) [m], in frames of FRAME_DT that
    the liquid's solver splits by its CFL condition, surfaced every frame by blobs of sigma = spacing
    reaching LIQUID_CUTOFF at the half level (on a flat surface half a spacing beyond the outer
    particles), `resolution` nodes along the bounds' longest side; `scene`: the other BlobScene fields."""
    margin = LIQUID_CUTOFF * spacing
    field = BlobField(
        capacity=model.particle_capacity,
        make=model.new_field,
        sigma=spacing,
        bounds=(np.subtract(bounds[0], margin), np.add(bounds[1], margin)),
        resolution=resolution,
        cutoff=LIQUID_CUTOFF,
    )
    return BlobScene(
        name=name,
        model=model,
        state=model.state(),
        integrator=make_integrator(integrator),
        dt=FRAME_DT,
        substeps=1,  # the liquid's solver splits each frame by its CFL condition
        bounds=bounds,
        point_radius=0.4 * spacing,
        blobs=field,
        iso=half_level(spacing, spacing, LIQUID_CUTOFF),
        **scene,
    )


def build(
    *,
    seed: int = 0,
    integrator: str = "symplectic_euler",
    width: float = 0.2,
    per_width: int = 10,
    depth: float = 0.2,
    tolerance: float = 5e-4,
    resolution: int = 96,
    method: str = "dfsph",
) -> BlobScene:
    """A column `width` [m] wide (a), 2a high and `depth` [m] deep, `per_width` particles across a,
    against the left wall of a tank 4.5 a long and 1.5 a high; density error `tolerance` (a fraction
    of rest density) and solver `method` ("dfsph" or "pbf"); the surface's grid has `resolution` nodes
    along the tank's length."""
    d = width / per_width
    b = Builder()
    b.add_force_gravity()
    lo, hi = (0.0, 0.0, 0.0), (4.5 * width, 3.0 * width, depth)
    b.add_collider_box(lo, hi, restitution=0.0)
    b.add_fluid(spacing=d, tolerance=tolerance, method=method)
    b.add_fluid_block((0.0, 0.0, 0.0), (width, 2.0 * width, depth))
    model = b.finalize(seed=seed)
    return liquid_scene(
        "dam_break",
        model,
        integrator=integrator,
        spacing=d,
        bounds=(lo, hi),
        resolution=resolution,
        description=f"a {model.fluid_count}-particle water column collapsing in a tank, surfaced by blobs",
        options={"width": width, "per_width": per_width, "depth": depth, "tolerance": tolerance,
                 "method": method},
        frames=90,
        view=(0.3, 0.5, 1.0),
        color_ranges={"speed": (0.0, 3.0)},
    )  # fmt: skip
