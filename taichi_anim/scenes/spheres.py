"""Spheres: 10^5 hard spheres poured into a box (counting-sort grid neighbour search, Jacobi projection
with restitution and Coulomb friction; collision/spheres.py), exported per frame as point clouds with a
radius attribute."""

from dataclasses import dataclass

import numpy as np

from .. import Builder, make_integrator
from ..content import Points
from .base import Scene

FRAME_DT = 1 / 30  # [s]
# The pour's own colours (blue at rest to orange at 2 m/s) when the picture does not colour by speed.
SLOW, FAST = np.array([0.2, 0.35, 0.75]), np.array([1.0, 0.6, 0.15])


@dataclass
class SpheresScene(Scene):
    """A Scene of hard spheres: point clouds carry each sphere's radius; colour shows speed."""

    def frame_content(self) -> list:
        """The spheres (radius, velocity; coloured by speed) and the box's edges."""
        snap = self.state.snapshot()
        s = np.clip(np.linalg.norm(snap.v, axis=1) / 2.0, 0.0, 1.0)[:, None]
        color = (1 - s) * SLOW + s * FAST
        radius = self.model.particle_radii(snap.index)
        attributes = {"radius": radius, "velocity": snap.v}
        spheres = Points("", snap.x, color, snap.index, radius, attributes, role="spheres")
        return [spheres, *self.guide_items()]


def build(
    *,
    seed: int = 0,
    integrator: str = "symplectic_euler",
    particles: int = 100_000,
    radius: float = 0.006,
    steps_per_frame: int = 240,
    sweeps: int = 1,
) -> Scene:
    """`particles` spheres of `radius` [m] on a jittered lattice in a narrow, tall column centred over the
    floor of a 1.2 x 1.2 m box, 0.3 m above the floor, falling with random velocities: the column pours
    onto one spot and a heap forms and spreads (10^5 spheres of 6 mm: a column 0.47 m wide and 1.03 m
    tall; it lands over 0.25-0.52 s and sloshes against the walls). 1/30 s
    frames of `steps_per_frame` steps (dt 1/7200 s by default) with `sweeps` projection sweeps each.
    The setting was chosen by measurement (overlap_stats after each frame, 10^5 spheres, f32; the
    closest pair is worst as the column's top lands, at up to ~5 m/s, and the overlap left then scales
    about as dt): the earlier column, 0.4 m wide and 1.5 m tall (top landing at ~5.9 m/s), dipped to
    0.88 d at frames 17-18 with 200 x 1, to 0.900 d with 240 x 1 and 0.918 d with 260 x 1; this wider,
    shorter column with 240 x 1 keeps 0.919 d (frame 16, as its top lands; 0.94 d or more over frames
    10-21 otherwise, and above 0.9 d over all 60 frames), at 1.2x the steps per frame of 200 x 1 (1.13x
    the wall time, 12.0 against 10.6 s per frame run side by side on a shared 2-core CPU). On an earlier
    wide, low column (0.8 m wide, 0.37 m tall) 200 x 1 kept 0.94 d, 160 x 1 0.904 d and 80 x 1
    0.75-0.84 d; more sweeps cost more per unit of separation gained (80 x 4 kept 0.93 d at 20,000
    spheres, as 160 x 1 did; benchmarks/results/sphere_demo.md). benchmarks/results/sphere_piles.md
    shows the largest overlap left in a settled pile against dt and sweeps."""
    rng = np.random.default_rng(seed)
    spacing = 2.2 * radius
    # A narrow column (at most 36 spheres = 0.47 m wide for 6 mm spheres) so that it pours onto a heap;
    # a narrower one is taller and lands faster, leaving deeper overlaps.
    side = max(2, min(36, round(0.78 * particles ** (1 / 3))))
    layers = -(-particles // (side * side))
    g = np.stack(np.meshgrid(np.arange(side), np.arange(layers), np.arange(side), indexing="ij"), -1)
    g = g.reshape(-1, 3)[:particles]
    lo, hi = (-0.6, 0.0, -0.6), (0.6, 0.3 + layers * spacing + 0.1, 0.6)
    corner = np.array([-0.5 * (side - 1) * spacing, 0.3, -0.5 * (side - 1) * spacing])
    x = corner + g * spacing + rng.uniform(-0.1, 0.1, g.shape) * radius
    v = rng.normal(0.0, 0.2, g.shape)
    b = Builder()
    b.add_force_gravity()
    b.add_particles(x, v, mass=1e-3, radius=radius)
    b.add_collider_box(lo, hi, restitution=0.3, friction=0.4)
    b.add_sphere_contacts(restitution=0.5, friction=0.4, iterations=sweeps)
    model = b.finalize(seed=seed)
    return SpheresScene(
        name="spheres",
        description=f"{particles} hard spheres poured into a box",
        model=model,
        state=model.state(),
        integrator=make_integrator(integrator, check_every=80),
        dt=FRAME_DT / steps_per_frame,
        substeps=steps_per_frame,
        bounds=(lo, hi),
        point_radius=radius,
        options={
            "particles": particles,
            "radius": radius,
            "steps_per_frame": steps_per_frame,
            "sweeps": sweeps,
        },
        frames=60,
        # Close and low, looking at the heap's foot with the column pouring in from above.
        camera={"eye": (0.78, 0.42, 1.02), "target": (0.0, 0.14, 0.0), "fov_deg": 48.0},
        color_by="speed",
        color_ranges={"speed": (0.0, 4.0)},
    )
