"""taichi_anim: a Taichi-based particle and cloth animation engine.

build (Builder) -> model + state -> a Stepper advances the state with an integrator -> read-only output
(snapshots, export).
Taichi is never initialised on import: call `taichi_anim.init(arch=...)`, or let `Builder.finalize()`
start it on the CPU.
"""

from . import ode, shapes, stability
from .blobs import BlobField, BlobMesh, IsosurfaceMethod
from .bodies.rigid import RigidSnapshot
from .builder import Builder
from .cloth import Cloth, ClothMaterial, FabricMaterial
from .collision import CollisionMode, RigidMotion
from .collision.neighbors import NeighborMethod, make_neighbor_search
from .errors import (
    ConvergenceError,
    DivergenceError,
    FolderBusyError,
    OutputError,
    ParameterError,
    RunInterrupted,
    SolverWarning,
    StabilityError,
    StabilityWarning,
)
from .health import Health, Policy
from .integrators import (
    INTEGRATORS,
    Integrator,
    IntegratorAdaptive,
    IntegratorExplicitEuler,
    IntegratorImplicitEuler,
    IntegratorMidpoint,
    IntegratorRK4,
    IntegratorRK45,
    IntegratorSymplecticEuler,
    make_integrator,
)
from .linalg import (
    LinearSolverCG,
    LinearSolveResult,
    LinearSolverJacobi,
    LinearSolverKind,
    make_linear_solver,
)
from .model import Model
from .particles import EmitterShape
from .runtime import backend_name, init, is_initialized
from .state import ParticleSnapshot, State
from .statics import solve_static
from .stepper import Stepper
from .terms import (
    AeroTriangles,
    AnchorSpring,
    BendingDihedral,
    Drag,
    ElementTerm,
    Gravity,
    MembraneStVK,
    PointTerm,
    Springs,
)
from .watchdog import Watchdog

__version__ = "0.1.0"

__all__ = [
    "RigidSnapshot",
    "shapes",
    "ConvergenceError",
    "Health",
    "OutputError",
    "FolderBusyError",
    "RunInterrupted",
    "Policy",
    "SolverWarning",
    "StabilityError",
    "StabilityWarning",
    "ode",
    "stability",
    "Watchdog",
    "AeroTriangles",
    "AnchorSpring",
    "BendingDihedral",
    "Drag",
    "ElementTerm",
    "Gravity",
    "MembraneStVK",
    "PointTerm",
    "Springs",
    "Stepper",
    "INTEGRATORS",
    "BlobField",
    "BlobMesh",
    "Builder",
    "Cloth",
    "ClothMaterial",
    "FabricMaterial",
    "CollisionMode",
    "DivergenceError",
    "EmitterShape",
    "Integrator",
    "IntegratorAdaptive",
    "IntegratorExplicitEuler",
    "IntegratorImplicitEuler",
    "IntegratorMidpoint",
    "IntegratorRK4",
    "IntegratorRK45",
    "IntegratorSymplecticEuler",
    "IsosurfaceMethod",
    "LinearSolveResult",
    "LinearSolverCG",
    "LinearSolverJacobi",
    "LinearSolverKind",
    "Model",
    "NeighborMethod",
    "ParameterError",
    "ParticleSnapshot",
    "RigidMotion",
    "State",
    "backend_name",
    "init",
    "is_initialized",
    "make_integrator",
    "make_linear_solver",
    "make_neighbor_search",
    "solve_static",
]
