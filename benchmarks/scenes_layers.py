"""The stacked-sheets scene of the self-contact benchmark, built with taichi_anim's public Builder.

Two horizontal 1 m x 1 m sheets of 32 x 32 cells (33 x 33 vertices), areal density 0.2 kg/m^2, the lower
at 0.6 m and the upper 3 cm above it, centred over a ball of radius 0.25 m at (0, 0.25, 0) resting on the
floor y = 0; gravity 9.81 m/s^2 along -y; 1/60 s frames. The same geometry, triangles and vertex order as
benchmarks/peers/newton_vbd.py (both use the engine's grid), so crossing counts compare pair for pair.
This builder adds no self-contact: a caller adds the engine's cloth contact to the returned Builder
before finalising (`layers_builder`), or takes the finished scene without it (`build`).
"""

from __future__ import annotations

import numpy as np

import taichi_anim as ta
from taichi_anim.scenes.base import Scene
from taichi_anim.scenes.cloth import FRAME_DT, cloth_integrator, material_for, substeps_for
from taichi_anim.scenes.drape import uv_sphere

CELLS = 32
SIZE = 1.0  # [m]
LOWER_HEIGHT = 0.6  # [m]
SPACING = 0.03  # [m]
BALL_RADIUS = 0.25  # [m]


def layers_builder(
    *,
    material: str = "membrane",
    thickness: float = 0.005,
    friction: float = 0.5,
    bend_stiffness: float = 50.0,
    cells: int = CELLS,
) -> tuple[ta.Builder, list]:
    """The Builder with gravity, both sheets, the ball and the floor, not finalised, and the two Cloth
    handles (lower first). material: "springs" or "membrane" (the cloth demos' materials); thickness [m]:
    each vertex's collision radius against the ball and the floor; friction: Coulomb coefficient of both
    colliders; bend_stiffness [N/m]: bend springs of the "springs" material."""
    b = ta.Builder()
    b.add_force_gravity()
    fabric = material_for(material, bend_stiffness)
    half = 0.5 * SIZE
    cloths = [
        b.add_cloth_grid(
            origin=(-half, h, -half),
            size=(SIZE, SIZE),
            resolution=(cells + 1, cells + 1),
            plane="xz",
            material=fabric,
            thickness=thickness,
        )
        for h in (LOWER_HEIGHT, LOWER_HEIGHT + SPACING)
    ]
    b.add_collider_sphere((0.0, BALL_RADIUS, 0.0), BALL_RADIUS, restitution=0.0, friction=friction)
    b.add_collider_plane(normal=(0.0, 1.0, 0.0), offset=0.0, restitution=0.0, friction=friction)
    return b, cloths


def scene_from(
    b: ta.Builder, *, material: str = "membrane", integrator: str = "implicit_euler", bend_stiffness=50.0
) -> Scene:
    """Finalise a `layers_builder` Builder (after any additions) into a Scene stepped like the cloth demos
    (implicit Euler with PCG, or a fixed-step method at its stability limit)."""
    model = b.finalize(seed=0)
    fabric = material_for(material, bend_stiffness)
    cell = SIZE / CELLS
    substeps = substeps_for(integrator, fabric, fabric.density * cell * cell, cell)
    reach = 0.5 * SIZE + 0.15
    floor = np.array([[-reach, 0.0, -reach], [reach, 0.0, -reach], [reach, 0.0, reach], [-reach, 0.0, reach]])
    return Scene(
        name="layers",
        description="two stacked sheets falling onto a ball on the floor",
        model=model,
        state=model.state(),
        integrator=cloth_integrator(integrator),
        dt=FRAME_DT / substeps,
        substeps=substeps,
        bounds=((-reach, 0.0, -reach), (reach, LOWER_HEIGHT + SPACING + 0.05, reach)),
        point_radius=0.005,
        options={
            "cells": CELLS,
            "size": SIZE,
            "lower_height": LOWER_HEIGHT,
            "spacing": SPACING,
            "ball_radius": BALL_RADIUS,
            "material": material,
            "integrator": integrator,
        },
        frames=90,
        props=[uv_sphere((0.0, BALL_RADIUS, 0.0), 0.985 * BALL_RADIUS)],
        guides=(floor, np.roll(floor, -1, axis=0)),
        view=(0.55, 0.6, 1.0),
        zoom=1.15,
    )


def build(*, material: str = "membrane", integrator: str = "implicit_euler", thickness: float = 0.005):
    """The Scene without self-contact (the sheets pass through each other); thickness [m] as above."""
    b, _ = layers_builder(material=material, thickness=thickness)
    return scene_from(b, material=material, integrator=integrator)


def run(scene: Scene, frames: int, *, every: int = 1) -> dict:
    """Step `frames` frames; positions (frames // every + 1, V, 3) [m] and the triangles (F, 3), for
    taichi_anim.spatial.crossings."""
    stepper = ta.Stepper(scene.model, scene.integrator)
    xs = [scene.state.particle_x.to_numpy().astype(np.float64)]
    for f in range(1, frames + 1):
        for _ in range(scene.substeps):
            stepper.step(scene.state, scene.dt)
        if f % every == 0:
            xs.append(scene.state.particle_x.to_numpy().astype(np.float64))
    return {"x": np.array(xs), "triangles": np.asarray(scene.model.triangles, np.int64)}
