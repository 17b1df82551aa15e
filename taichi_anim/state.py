"""State: what changes each step (positions, velocities, birth and death times, trails), and its
NumPy snapshot for output. Fields exist only for the parts the model has."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from .errors import DivergenceError
from .runtime import data_oriented

ALIVE_FOREVER = 1.0e30


@dataclass
class ParticleSnapshot:
    """Alive particles at one instant, as NumPy arrays: x (N,3) [m], v (N,3) [m/s], age (N,) [s],
    lifetime (N,) [s] (inf for particles that never die), color (N,3) in [0,1], index (N,) pool slots,
    trails (N,K,3) oldest first, or None."""

    time: float
    x: np.ndarray
    v: np.ndarray
    age: np.ndarray
    lifetime: np.ndarray
    color: np.ndarray
    index: np.ndarray
    trails: np.ndarray | None


@data_oriented
class State:
    """Dynamic data of a Model: particle_x, particle_v (N,3); particle_birth/death (N,) [s] when the
    model has emitters; trail (N,K,3) ring buffer when trails are on."""

    def __init__(self, model):
        n = model.particle_count
        self.model = model
        self.time = 0.0
        self.step_count = 0
        self.particle_x = ti.Vector.field(3, float, n)
        self.particle_v = ti.Vector.field(3, float, n)
        self.has_lifetimes = model.emitter_count > 0
        self.particle_birth = ti.field(float, n) if self.has_lifetimes else None
        self.particle_death = ti.field(float, n) if self.has_lifetimes else None
        # One bit per slot, set while the slot is dead and not yet reused: emitters find free slots by
        # scanning 32 slots per word instead of one death time per slot.
        self.particle_free = ti.field(ti.u32, (n + 31) // 32) if self.has_lifetimes else None
        # Emission: per emitter the fraction of a particle carried to the next step, the word its free-slot
        # scan starts at, and the slots found this step (at the emitter's own slot range).
        k = model.emitter_count
        self.emit_carry = [0.0] * k
        self.emit_cursor = ti.field(ti.i32, k) if k else None
        self.emit_found = ti.field(ti.i32, k) if k else None
        self.emit_slot = ti.field(ti.i32, n) if k else None
        self.trail_length = model.trail_length
        self.trail = ti.Vector.field(3, float, (n, self.trail_length)) if self.trail_length else None
        self.trail_head = 0
        # Divergence watch: count of particles that ended a step non-finite, and the first such step.
        self.nonfinite_count = ti.field(ti.i32, ())
        self.nonfinite_step = ti.field(ti.i32, ())
        self.nonfinite_step[None] = 2**31 - 1

    def check_finite(self) -> None:
        """Raise DivergenceError if any step so far produced a non-finite position or velocity."""
        bad = int(self.nonfinite_count[None])
        if bad:
            step = int(self.nonfinite_step[None])
            raise DivergenceError(
                f"simulation diverged at step {step}: {bad} particle(s) got a non-finite position or "
                f"velocity (check dt, stiffness and the integrator's stability limit); stopping before "
                f"anything is exported"
            )

    def alive_mask(self) -> np.ndarray:
        """(N,) bool: particles alive now."""
        if not self.has_lifetimes:
            return np.ones(self.model.particle_count, dtype=bool)
        return self.particle_death.to_numpy() > self.time

    def snapshot(self) -> ParticleSnapshot:
        """Copy the alive particles to NumPy (read-only output; never fed back)."""
        alive = self.alive_mask()
        idx = np.nonzero(alive)[0]
        x = self.particle_x.to_numpy()[idx]
        v = self.particle_v.to_numpy()[idx]
        if self.has_lifetimes:
            birth = self.particle_birth.to_numpy()[idx]
            death = self.particle_death.to_numpy()[idx]
            age = self.time - birth
            life = np.where(death >= ALIVE_FOREVER, np.inf, death - birth)
        else:
            age = np.full(len(idx), self.time)
            life = np.full(len(idx), np.inf)
        color = particle_colors(self.model.emitters, idx, age, life)
        trails = None
        if self.trail_length:
            tr = self.trail.to_numpy()[idx]
            order = (np.arange(self.trail_length) + self.trail_head) % self.trail_length
            trails = tr[:, order]
        return ParticleSnapshot(self.time, x, v, age, life, color, idx, trails)

    @ti.kernel
    def record_trails(self, head: ti.i32):
        ti.loop_config(serialize=self.model.serial)  # same launch-cost choice as the integrators
        for i in range(self.particle_x.shape[0]):
            self.trail[i, head] = self.particle_x[i]


def particle_colors(emitters, idx: np.ndarray, age: np.ndarray, life: np.ndarray) -> np.ndarray:
    """(N,3) colours in [0,1] of particles idx: each emitter's ramp over normalised age; grey for other
    particles (an output concern: the ramps are emitter options, read only here)."""
    color = np.full((len(idx), 3), 0.8)
    for e in emitters:
        sel = (idx >= e.start) & (idx < e.start + e.capacity)
        if sel.any():
            s = np.clip(age[sel] / life[sel], 0.0, 1.0)[:, None]
            color[sel] = (1 - s) * np.asarray(e.s.color_start) + s * np.asarray(e.s.color_end)
    return color
