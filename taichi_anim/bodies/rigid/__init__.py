"""The rigid kind: bodies with a shape, a mass and an inertia, a pose (x, q) and velocities (v, w),
stepped by the Stepper's integrator (dynamics.py)."""

from ..base import BodyKind
from .builder import RigidBuilder
from .dynamics import RigidDynamics
from .model import RigidModel
from .output import rigid_items
from .state import RigidSnapshot, RigidState


def _finalize(builder) -> tuple[dict, dict]:
    return builder.rigid_arrays(), builder.rigid_settings()


RIGID = BodyKind(
    name="rigid",
    builder=RigidBuilder,
    model=RigidModel,
    state=RigidState,
    init_builder=RigidBuilder._init_rigid,
    finalize=_finalize,
    init_model=RigidModel._init_rigid,
    init_state=RigidState._init_rigid,
    start_state=RigidState._start_rigid,
    save_state=RigidState._save_rigid,
    output_items=rigid_items,
)

__all__ = ["RIGID", "RigidDynamics", "RigidSnapshot"]
