"""The particle kind: point masses and hard spheres, emitters' particles and cloth vertices (cloth is
particles with element terms between them)."""

from ..base import BodyKind
from .builder import ParticleBuilder
from .model import ParticleModel
from .output import particle_items
from .state import ALIVE_FOREVER, ParticleSnapshot, ParticleState, particle_colors


def _finalize(builder) -> tuple[dict, dict]:
    x, v, m, r, emitters = builder.particle_arrays()
    arrays = dict(x=x, v=v, mass=m, radius=r, emitters=emitters, trail_length=builder._trail_length)
    return arrays, builder.particle_settings(emitters)


PARTICLES = BodyKind(
    name="particles",
    builder=ParticleBuilder,
    model=ParticleModel,
    state=ParticleState,
    init_builder=ParticleBuilder._init_particles,
    finalize=_finalize,
    init_model=ParticleModel._init_particles,
    init_state=ParticleState._init_particles,
    start_state=ParticleState._start_particles,
    save_state=ParticleState._save_particles,
    output_items=particle_items,
)

__all__ = ["ALIVE_FOREVER", "PARTICLES", "ParticleSnapshot", "particle_colors"]
