"""Particle jet meshed every frame as a blobby isosurface, exported as PLY meshes with normals.

The jet is an emitter with gravity in a box (restitution 0.2, friction 0.3); each frame the alive
particles' Blinn (1982) field is evaluated on a grid and its isosurface extracted (marching cubes,
Lorensen & Cline 1987; see taichi_anim/blobs)."""

import math
from dataclasses import dataclass

import numpy as np

from .. import Builder, make_integrator
from ..blobs import BlobField, BlobMesh
from ..content import Mesh
from ..errors import ParameterError
from .base import Scene

WATER = (0.35, 0.6, 0.95)


@dataclass
class BlobScene(Scene):
    """A Scene whose frames also export the isosurface psi = iso of its particles' blob field."""

    blobs: BlobField | None = None
    iso: float = 0.5
    method: str | None = None  # None: the engine's default extractor

    def mesh(self) -> BlobMesh:
        """The isosurface of the particles alive now (computed once per step count)."""
        cached = getattr(self, "_mesh_cache", None)
        if cached is not None and cached[0] == self.state.step_count:
            return cached[1]
        s = self.state
        self.blobs.evaluate(s.particle_x, self.model.particle_count, s.particle_death, s.time)
        mesh = self.blobs.isosurface(self.iso, method=self.method)
        self._mesh_cache = (s.step_count, mesh)
        return mesh

    def frame_content(self) -> list:
        """The particles (Scene.frame_content) and the isosurface as the mesh item "mesh" with its normals."""
        mesh = self.mesh()
        surface = Mesh("mesh", mesh.vertices, mesh.triangles, mesh.normals, WATER, role="surface")
        return [*super().frame_content(), surface]

    def settings(self) -> dict:
        return {**super().settings(), "blobs": self.blobs.settings(), "iso": self.iso, "method": self.method}


def build(
    *,
    seed: int = 0,
    integrator: str = "symplectic_euler",
    particles: int = 1500,
    sigma: float = 0.04,
    iso: float = 0.5,
    resolution: int = 128,
    method: str | None = None,
) -> BlobScene:
    """A slanted jet from the left wall of a 2 x 1.5 x 1 m box, falling onto the floor; `particles` is
    the pool size (rate keeps it about 90 % full); sigma [m] the blob width, iso the level (a lone drop
    has radius sigma sqrt(ln(1/iso))); resolution: grid nodes along the box's longest side."""
    if not 0.0 < iso < 1.0:  # a lone drop has radius sigma sqrt(ln(1/iso)): real only for 0 < iso < 1
        raise ParameterError(f"iso must lie strictly between 0 and 1, got {iso!r}")
    lifetime = 2.0
    b = Builder()
    b.add_force_gravity((0.0, -9.81, 0.0))
    angle = math.radians(50)
    b.add_particle_emitter(
        capacity=particles,
        rate=0.9 * particles / lifetime,
        shape="disc",
        center=(-0.9, 0.25, 0.0),
        radius=0.04,
        direction=(math.cos(angle), math.sin(angle), 0.0),
        speed=3.6,
        speed_jitter=0.04,
        spread=math.radians(3),
        lifetime=lifetime,
        lifetime_jitter=0.2,
        mass=0.001,
    )
    lo, hi = (-1.0, 0.0, -0.5), (1.0, 1.5, 0.5)
    b.add_collider_box(lo, hi, restitution=0.2, friction=0.3)
    model = b.finalize(seed=seed)
    # The grid reaches one blob radius plus a node beyond the box, so drops on the floor or at a wall are
    # not cut by the grid's zero outer layer.
    margin = sigma * math.sqrt(math.log(1.0 / iso)) + 2.0 * max(np.subtract(hi, lo)) / resolution
    field = BlobField(
        capacity=model.particle_capacity,  # the count, or its bucket: another pool size compiles nothing new
        make=model.new_field,
        sigma=sigma,
        bounds=(np.subtract(lo, margin), np.add(hi, margin)),
        resolution=resolution,
    )
    return BlobScene(
        name="blobs",
        description="particle jet meshed every frame as a blobby isosurface",
        model=model,
        state=model.state(),
        integrator=make_integrator(integrator, collision_mode="backward"),
        dt=1 / 240,
        substeps=4,
        bounds=(lo, hi),
        point_radius=0.01,
        options={"particles": particles, "sigma": sigma, "iso": iso, "resolution": resolution},
        view=(0.35, 0.5, 1.0),
        zoom=1.25,
        color_ranges={"speed": (0.0, 4.0), "age": (0.0, lifetime)},
        blobs=field,
        iso=iso,
        method=method,
    )
