"""Force terms, one file each, behind one protocol (base.py): pointwise terms (gravity, drag, anchor
springs) and element terms (springs, and the continuum cloth terms: membrane, bending, aerodynamics).
A Model holds a tuple of them; solvers iterate it at compile time, so a scene compiles only its terms.
A term of one's own subclasses PointTerm or ElementTerm (Builder.add_force); `check_term` checks it."""

from .aero import AeroTriangles
from .anchor_spring import AnchorSpring
from .base import ENERGY_KINDS, ElementCache, ElementTerm, PointTerm, TermBounds, check_protocol
from .bending import BendingDihedral, mesh_hinges
from .check import check_term, check_term_derivatives
from .drag import Drag
from .gravity import Gravity
from .membrane import MembraneStVK
from .springs import Springs

__all__ = [
    "AeroTriangles",
    "AnchorSpring",
    "BendingDihedral",
    "Drag",
    "ENERGY_KINDS",
    "ElementCache",
    "ElementTerm",
    "Gravity",
    "MembraneStVK",
    "PointTerm",
    "Springs",
    "TermBounds",
    "check_protocol",
    "check_term",
    "check_term_derivatives",
    "mesh_hinges",
]
