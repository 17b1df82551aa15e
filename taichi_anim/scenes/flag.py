"""Flag: a flag on a pole flaps in gusty wind (StVK membrane + dihedral bending + aerodynamic drag and lift).

Continuum cloth: a Saint Venant–Kirchhoff triangle membrane (Volino et al. 2009) and discrete-shells
bending (Grinspun et al. 2003) on a grid mesh, pinned along the pole, blown by per-triangle flat-plate
drag and lift against a gusting wind, stepped by linearised backward Euler with PCG (Baraff & Witkin
1998): what integrator="auto" (integrators/choice.py) chooses for it too, since the aerodynamic damping
would hold symplectic Euler to thousands of substeps (benchmarks/results/auto_choice.md); the
default skips the choice's frequency estimate, which needs the membrane's probe kernels compiled. Each
frame exports the flag as a PLY mesh with vertex normals."""

import numpy as np

from .. import Builder, FabricMaterial
from ..cloth import explicit_step_limit
from .base import Scene, frame_step
from .cloth import cloth_method

# The flag's PCG: a looser tolerance than the sheet demos' (its membrane solves are costlier).
IMPLICIT_OPTIONS = {"linear_solver": "pcg", "tol": 1e-3, "max_iterations": 200}

FRAME_DT = 1 / 60  # [s]
SUBSTEPS = 4


def fabric(*, youngs_modulus: float = 2.0e3, bending_stiffness: float = 2.0e-4) -> FabricMaterial:
    """A light flag fabric (~120 g/m^2 polyester): areal Young's modulus [N/m], bending stiffness [N m]."""
    return FabricMaterial(
        density=0.12,
        youngs_modulus=youngs_modulus,
        poisson_ratio=0.3,
        bending_stiffness=bending_stiffness,
        damping=2e-3,
        bending_damping=2e-2,
    )


def build(
    *,
    seed: int = 0,
    integrator: str = "implicit_euler",
    resolution: int = 40,
    width: float = 1.5,
    height: float = 1.0,
    wind: tuple = (6.0, 0.0, 1.0),
    gust: float = 0.35,
    youngs_modulus: float = 2.0e3,
    bending_stiffness: float = 2.0e-4,
    substeps: int | str | None = None,
) -> Scene:
    """A `width` x `height` [m] flag of `resolution` vertices along its width (square cells), hanging from
    a vertical pole at x = 0 (every vertex of its left edge pinned), in a wind [m/s] whose speed swings by
    `gust` (a fraction) at 0.7 Hz. substeps per 1/60 s frame: None (this demo's rule), a count, or "auto"
    (the smallest stable count, Scene)."""
    nx = int(resolution)
    ny = max(2, round((nx - 1) * height / width) + 1)
    top = 2.5
    material = fabric(youngs_modulus=youngs_modulus, bending_stiffness=bending_stiffness)
    b = Builder()
    b.add_force_gravity()
    cloth = b.add_cloth_grid(
        origin=(0.0, top - height, 0.0),
        size=(width, height),
        resolution=(nx, ny),
        plane="xy",
        material=material,
        thickness=0.004,
        pinned=[j * nx for j in range(ny)],  # the left edge, on the pole
    )
    b.add_force_aerodynamics(
        cloth, wind=wind, drag_coefficient=1.2, lift_coefficient=0.6, gust_amplitude=gust, gust_frequency=0.7
    )
    model = b.finalize(seed=seed)

    def rule() -> int:  # explicit methods: half the membrane's damped stability limit
        if integrator == "implicit_euler":
            return SUBSTEPS
        limit = explicit_step_limit(material, width / (nx - 1))
        return max(SUBSTEPS, int(np.ceil(FRAME_DT / (0.5 * limit))))

    integ, substeps, choice = cloth_method(integrator, model, substeps, rule, IMPLICIT_OPTIONS)
    pole = (np.array([[0.0, top - 1.6 * height, 0.0]]), np.array([[0.0, top + 0.1, 0.0]]))
    lo, hi = (-0.1, top - 1.3 * height, -0.4 * width), (1.05 * width, top + 0.1, 0.4 * width)
    return Scene(
        name="flag",
        description="a flag on a pole in gusty wind (membrane + bending + aerodynamics)",
        model=model,
        state=model.state(),
        integrator=integ,
        integrator_choice=choice,
        dt=frame_step(FRAME_DT, substeps),
        substeps=substeps,
        bounds=(lo, hi),
        point_radius=0.004,
        options={
            "resolution": [nx, ny],
            "width": width,
            "height": height,
            "wind": list(wind),
            "gust": gust,
            "youngs_modulus": youngs_modulus,
            "bending_stiffness": bending_stiffness,
            "pinned": cloth.pinned.tolist(),
        },
        frames=180,
        guides=pole,
        view=(0.3, 0.2, 1.0),
        zoom=1.0,
    )
