"""Cloth: a 1 m square sheet pinned at two corners swings down like a pendulum.

Mass-spring cloth (Provot 1995's stretch, shear and bend springs); each frame exports the sheet as a PLY
mesh with area-weighted vertex normals. The default integrator="auto" steps it with the cheapest method
stable at the frame's step (integrators/choice.py; here symplectic Euler at its stability limit, 21-30
ms per frame against 41 ms for linearised backward Euler with PCG, Baraff & Witkin 1998, eq. 6, at 4
steps per frame: benchmarks/results/auto_choice.md). With `--integrator` set to a fixed-step explicit
method the step shrinks to that method's stability limit for the stiffest spring, so every integrator runs
the same scene."""

import math

import numpy as np

from .. import Builder, ClothMaterial, FabricMaterial, make_integrator
from ..cloth import explicit_step_limit, validate
from ..errors import ParameterError
from ..integrators.choice import choose_integrator, make_chosen
from .base import Scene, frame_step

FRAME_DT = 1 / 60  # [s]
IMPLICIT_SUBSTEPS = 4  # dt = 1/240 s: implicit Euler is stable at any step, this keeps its damping low
# Integrators that choose their own internal steps, or need none for stability: run at the implicit dt.
SELF_STABLE = {"implicit_euler", "rk45", "adaptive"}
# Fixed-step explicit methods on a mass-spring grid: stable for dt < ~0.58 sqrt(m/k) (measured for
# symplectic Euler, benchmarks/RESULTS.md); keep a margin for the shear and bend springs' stiffness.
EXPLICIT_CFL = 0.4
FAMILIES = ("stretch", "shear", "bend")


# The continuum fabric of the demos' `material="membrane"` switch: the areal Young's modulus of a grid of
# stretch springs k [N/m] is about k (each spring carries k * strain * cell over a cell's width), so
# 1e3 N/m matches ClothMaterial's stretch springs; bending 5e-5 N m is a light cotton's (springs across two
# cells have no linear bending stiffness to match).
FABRIC = FabricMaterial(density=0.2, youngs_modulus=1.0e3, poisson_ratio=0.3, bending_stiffness=5.0e-5)


def material_for(name: str, bend_stiffness: float):
    """The cloth demos' material: "springs" (ClothMaterial) or "membrane" (FABRIC)."""
    validate.choice("material", name, ["springs", "membrane"])
    return FABRIC if name == "membrane" else ClothMaterial(bend_stiffness=bend_stiffness)


def substeps_for(integrator: str, material, vertex_mass: float, cell: float = 0.0) -> int:
    """Steps per 1/60 s frame for `integrator` on cloth of interior vertex mass [kg], grid cell [m] and
    `material`."""
    if integrator in SELF_STABLE:
        return IMPLICIT_SUBSTEPS
    if isinstance(material, FabricMaterial):
        # The fastest membrane mode with its Rayleigh damping; a margin for bending and the mesh's
        # deviation from the estimate.
        dt = 0.5 * explicit_step_limit(material, cell)
        return max(IMPLICIT_SUBSTEPS, math.ceil(FRAME_DT / dt))
    families = [(getattr(material, f"{f}_stiffness"), getattr(material, f"{f}_damping")) for f in FAMILIES]
    k = max(kf for kf, _ in families)
    dt = EXPLICIT_CFL * math.sqrt(vertex_mass / k)
    if integrator == "explicit_euler":
        # Forward Euler grows every undamped oscillation; on m x'' + c x' + k x = 0 it is stable only
        # for dt < c / k, and spring modes mix the families' ratios.
        dt = min(dt, 0.5 * min(cf / kf for kf, cf in families if kf > 0.0))
    return max(IMPLICIT_SUBSTEPS, math.ceil(FRAME_DT / dt))


IMPLICIT_OPTIONS = {"linear_solver": "pcg", "tol": 1e-4, "max_iterations": 200}  # the cloth demos' PCG


def cloth_integrator(name: str, implicit_options: dict = IMPLICIT_OPTIONS):
    """The integrator `name`; implicit Euler gets PCG at tol 1e-4 (the cloth demos' setting)."""
    if name == "implicit_euler":
        return make_integrator(name, **implicit_options)
    return make_integrator(name, check_every=20)


def cloth_method(name: str, model, substeps, rule, implicit_options: dict = IMPLICIT_OPTIONS):
    """(integrator, substeps per 1/60 s frame, choice record or None) for a cloth demo. name "auto": the
    cheapest method stable at the frame's step (integrators/choice.py: symplectic Euler or RK4 at their
    stable substeps, or implicit Euler at IMPLICIT_SUBSTEPS), substeps then chosen with it; otherwise
    `name` with `substeps` (None: rule(), the demo's own count)."""
    if name != "auto":
        return cloth_integrator(name, implicit_options), rule() if substeps is None else substeps, None
    if substeps not in (None, "auto"):
        raise ParameterError(
            f"integrator='auto' chooses the substeps too: leave substeps unset, got {substeps!r}"
        )
    choice = choose_integrator(
        model,
        FRAME_DT,
        implicit_substeps=IMPLICIT_SUBSTEPS,
        implicit_options=implicit_options,
        explicit_options={"check_every": 20},
    )
    return make_chosen(model, choice), choice.substeps, choice.record()


def build(
    *,
    seed: int = 0,
    integrator: str = "auto",
    bend_stiffness: float = 50.0,
    resolution: int = 48,
    size: float = 1.0,
    air_damping: float = 0.3,
    material: str = "springs",
    substeps: int | str | None = None,
) -> Scene:
    """A horizontal `size` [m] square sheet of `resolution` x `resolution` vertices at 1.2 m, pinned at
    the two corners of its back edge (z = -size/2); air_damping [1/s]: linear drag per unit mass;
    bend_stiffness [N/m]: 5x the ClothMaterial default, so compression buckles into folds rather than
    grid-scale ripples. Other material values are ClothMaterial's defaults. material: "springs" or
    "membrane" (a continuum fabric of the same stretch stiffness, FABRIC). substeps per 1/60 s frame: None
    (this demo's rule, substeps_for), a count, or "auto" (the smallest stable count, Scene)."""
    n = int(resolution)
    material_name = material
    material = material_for(material, bend_stiffness)
    half, height = 0.5 * size, 1.2
    b = Builder()
    b.add_force_gravity()
    cloth = b.add_cloth_grid(
        origin=(-half, height, -half),
        size=(size, size),
        resolution=(n, n),
        plane="xz",
        material=material,
        thickness=0.005,
        pinned=[0, n - 1],  # vertices (0, 0) and (n-1, 0): both corners of the edge z = -size/2
    )
    vertex_mass = material.density * (size / (n - 1)) ** 2
    if air_damping > 0.0:
        b.add_force_drag(air_damping * vertex_mass)
    model = b.finalize(seed=seed)
    integ, substeps, choice = cloth_method(
        integrator, model, substeps, lambda: substeps_for(integrator, material, vertex_mass, size / (n - 1))
    )
    pins = np.array([[-half, height, -half], [half, height, -half]])
    # The sheet swings through the vertical plane z = -size/2 and most of the way back up behind it.
    lo, hi = (-half - 0.1, height - size - 0.1, -half - 0.8 * size), (half + 0.1, height + 0.1, half - 0.2)
    return Scene(
        name="cloth",
        description="a sheet pinned at two corners swinging down",
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
            "air_damping": air_damping,
            "bend_stiffness": bend_stiffness,
            "material": material_name,
            "pinned": cloth.pinned.tolist(),
        },
        frames=120,
        guides=(pins[:1], pins[1:]),  # the bar the sheet hangs from
        view=(0.7, 0.45, 1.0),
        zoom=1.5,
    )
