"""Force terms, one file each, behind one protocol (base.py): pointwise terms (gravity, drag, anchor
springs) and element terms (springs, and the continuum cloth terms: membrane, bending, aerodynamics).
A Model holds a tuple of them; solvers iterate it at compile time, so a scene compiles only its terms."""

from .aero import AeroTriangles
from .anchor_spring import AnchorSpring
from .base import ElementCache, ElementTerm, PointTerm
from .bending import BendingDihedral, mesh_hinges
from .drag import Drag
from .gravity import Gravity
from .membrane import MembraneStVK
from .springs import Springs

__all__ = [
    "AeroTriangles",
    "AnchorSpring",
    "BendingDihedral",
    "Drag",
    "ElementCache",
    "ElementTerm",
    "Gravity",
    "MembraneStVK",
    "PointTerm",
    "Springs",
    "mesh_hinges",
]
