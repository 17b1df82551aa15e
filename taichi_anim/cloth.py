"""Cloth options: the material of a mass-spring sheet (Provot 1995's structural, shear and bend springs,
lumped areal mass as in Baraff & Witkin 1998) and the record of a cloth added to a Builder."""

import math
from dataclasses import dataclass

import numpy as np

from . import validate


@dataclass(frozen=True)
class ClothMaterial:
    """density [kg/m^2] (lumped onto vertices by triangle area); per spring family: stiffness [N/m] and
    damping [kg/s] along the spring. Stretch springs are the mesh edges (grid: horizontal and vertical),
    shear springs the quads' diagonals, bend springs join vertices two apart (across interior edges)."""

    density: float = 0.2
    stretch_stiffness: float = 1.0e3
    stretch_damping: float = 0.05
    shear_stiffness: float = 1.0e2
    shear_damping: float = 0.01
    bend_stiffness: float = 10.0
    bend_damping: float = 0.005

    def __post_init__(self):
        validate.positive("density", self.density)
        for name in ("stretch", "shear", "bend"):
            validate.non_negative(f"{name}_stiffness", getattr(self, f"{name}_stiffness"))
            validate.non_negative(f"{name}_damping", getattr(self, f"{name}_damping"))

    def family_arrays(self, family: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(stiffness, damping) per spring for family codes 0 stretch, 1 shear, 2 bend."""
        k = np.array([self.stretch_stiffness, self.shear_stiffness, self.bend_stiffness])
        c = np.array([self.stretch_damping, self.shear_damping, self.bend_damping])
        return k[family], c[family]


@dataclass(frozen=True)
class Cloth:
    """A cloth in a model: its particles (a range of indices), triangles (F,3) over model particle
    indices, and pinned particles (model indices)."""

    particles: range
    triangles: np.ndarray
    pinned: np.ndarray


@dataclass(frozen=True)
class FabricMaterial:
    """A continuum fabric: a StVK triangle membrane plus dihedral bending instead of springs, so the
    result converges as the mesh is refined. density [kg/m^2]; youngs_modulus [N/m] (areal: Young's
    modulus times thickness); poisson_ratio in [0, 0.5); bending_stiffness [N m] (E t^3 / (12 (1 - nu^2))
    for a plate); damping, bending_damping [s]: Rayleigh (stiffness-proportional) damping (a membrane
    damping beta also bounds explicit steps: see `explicit_step_limit`). Optional
    warp/weft anisotropy: youngs_warp, youngs_weft, shear_modulus [N/m] along warp_direction (projected
    on each triangle)."""

    density: float = 0.2
    youngs_modulus: float = 1.0e3
    poisson_ratio: float = 0.3
    bending_stiffness: float = 1.0e-4
    damping: float = 1.0e-4
    bending_damping: float = 1.0e-2
    youngs_warp: float | None = None
    youngs_weft: float | None = None
    shear_modulus: float | None = None
    warp_direction: tuple = (1.0, 0.0, 0.0)

    def __post_init__(self):
        validate.positive("density", self.density)
        validate.positive("youngs_modulus", self.youngs_modulus)
        validate.in_range("poisson_ratio", self.poisson_ratio, 0.0, 0.4999)
        validate.non_negative("bending_stiffness", self.bending_stiffness)
        validate.non_negative("damping", self.damping)
        validate.non_negative("bending_damping", self.bending_damping)

    def membrane_options(self) -> dict:
        """Keyword options of Builder.add_force_membrane."""
        opts = dict(
            youngs_modulus=self.youngs_modulus, poisson_ratio=self.poisson_ratio, damping=self.damping
        )
        if self.youngs_warp is not None:
            opts.update(
                youngs_warp=self.youngs_warp,
                youngs_weft=self.youngs_weft,
                shear_modulus=self.shear_modulus,
                warp_direction=self.warp_direction,
            )
        return opts


def explicit_step_limit(material: FabricMaterial, cell: float) -> float:
    """Largest stable symplectic Euler step [s] for the membrane's fastest mode on a mesh of edge `cell`
    [m]: omega = 2 c / cell with wave speed c = sqrt(E / density), damping ratio zeta = beta omega / 2
    (Rayleigh), and the damped oscillator's limit dt < 2 (sqrt(1 + zeta^2) - zeta) / omega."""
    omega = 2.0 * math.sqrt(material.youngs_modulus / material.density) / cell
    zeta = 0.5 * material.damping * omega
    return 2.0 * (math.sqrt(1.0 + zeta * zeta) - zeta) / omega
