"""Cloth options: the material of a mass-spring sheet (Provot 1995's structural, shear and bend springs,
lumped areal mass as in Baraff & Witkin 1998) and the record of a cloth added to a Builder."""

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
