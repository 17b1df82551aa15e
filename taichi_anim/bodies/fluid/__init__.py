"""The fluid kind: an incompressible liquid of SPH particles (builder.py), made incompressible by
divergence-free SPH (dfsph.py) or position-based fluids (pbf.py) against boundary samples of the
colliders (boundary.py). Its particles are particles of the particle kind, so everything that acts on
or shows particles acts on or shows the liquid; this kind adds which particles are liquid, its
constants, and the solver's carry."""

from ..base import BodyKind
from .builder import FluidBuilder
from .dfsph import FluidDynamics
from .model import FluidModel
from .pbf import PositionBasedFluid
from .state import FluidState


def _finalize(builder) -> tuple[dict, dict]:
    return builder.fluid_arrays(), builder.fluid_settings()


FLUID = BodyKind(
    name="fluid",
    builder=FluidBuilder,
    model=FluidModel,
    state=FluidState,
    init_builder=FluidBuilder._init_fluid,
    finalize=_finalize,
    init_model=FluidModel._init_fluid,
    init_state=FluidState._init_fluid,
    start_state=FluidState._start_fluid,
    save_state=FluidState._save_fluid,
    output_items=lambda model, state: [],
)


def fluid_solver(model, *, method: str, **options):
    """The liquid's solver for add_fluid's `method`: "dfsph" (dfsph.py) or "pbf" (pbf.py)."""
    cls = PositionBasedFluid if method == "pbf" else FluidDynamics
    return cls(model, method=method, **options)


__all__ = ["FLUID", "FluidDynamics", "PositionBasedFluid", "fluid_solver"]
