"""The default demo: a particle fountain with lifetimes bouncing in a box (Reeves 1983 emitters,
symplectic Euler, backward-search collisions with restitution and friction, short trails)."""

import math

from .. import Builder, make_integrator
from .base import Scene


def build(*, seed: int = 0, integrator: str = "symplectic_euler", particles: int = 20000) -> Scene:
    """A disc emitter at the floor of a 2 x 3 x 2 m box; `particles` is the pool size, the rate keeps it
    about 95 % full (rate = 0.95 pool / mean lifetime)."""
    lifetime = 2.5
    b = Builder()
    b.add_force_gravity((0.0, -9.81, 0.0))
    b.add_force_wind((0.6, 0.0, 0.0), 0.02)
    b.add_particle_emitter(
        capacity=particles,
        rate=0.95 * particles / lifetime,
        shape="disc",
        center=(0.0, 0.05, 0.0),
        radius=0.08,
        direction=(0.0, 1.0, 0.0),
        speed=6.5,
        speed_jitter=0.15,
        spread=math.radians(20),
        lifetime=lifetime,
        lifetime_jitter=0.3,
        mass=0.01,
        color_start=(1.0, 0.85, 0.3),
        color_end=(0.2, 0.35, 1.0),
    )
    lo, hi = (-1.0, 0.0, -1.0), (1.0, 3.0, 1.0)
    b.add_collider_box(lo, hi, restitution=0.6, friction=0.1)
    b.add_particle_trails(6)
    model = b.finalize(seed=seed)
    return Scene(
        name="fountain",
        description="particle fountain with lifetimes bouncing in a box (default demo)",
        model=model,
        state=model.state(),
        integrator=make_integrator(integrator, collision_mode="backward"),
        dt=1 / 240,
        substeps=4,
        bounds=(lo, hi),
        point_radius=0.01,
        options={"particles": particles, "lifetime": lifetime},
        color_ranges={"speed": (0.0, 7.0), "age": (0.0, lifetime)},
        view=(0.6, 0.3, 1.0),
        zoom=1.1,
    )
