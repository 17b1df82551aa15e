"""The particle kind's state part: positions and velocities, birth and death times and free-slot bits
(with emitters), emission carry and cursors, trails; their NumPy access and the read-only snapshot."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import bulk, validate
from ...errors import ParameterError
from ...runtime import data_oriented, np_float

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
class ParticleState:
    """State methods of the particle kind (the State inherits them): particle_x, particle_v (N,3);
    particle_birth/death (N,) [s] when the model has emitters; trail (N,K,3) ring buffer when trails
    are on. Index i is the model's particle i (a cloth grid's vertex (i, j) is j * nx + i, in builder
    order)."""

    def _init_particles(self, model) -> None:
        """Allocate the particle arrays of a State of `model` (once; particle_capacity rows, which is the
        particle count unless capacity buckets are on)."""
        cap = model.particle_capacity
        self.particle_x = model.particle_array(self, "particle_x", dims=(3,))
        self.particle_v = model.particle_array(self, "particle_v", dims=(3,))
        self.has_lifetimes = model.emitter_count > 0
        self.particle_birth = model.particle_array(self, "particle_birth") if self.has_lifetimes else None
        self.particle_death = model.particle_array(self, "particle_death") if self.has_lifetimes else None
        # One bit per slot, set while the slot is dead and not yet reused: emitters find free slots by
        # scanning 32 slots per word instead of one death time per slot.
        words = (cap + 31) // 32
        self.particle_free = None
        if self.has_lifetimes:
            self.particle_free = model.new_field(self, "particle_free", ti.u32, words)
        # Emission: per emitter the fraction of a particle carried to the next step, the word its free-slot
        # scan starts at, and the slots found this step (at the emitter's own slot range).
        k = model.emitter_count
        self.emit_carry = [0.0] * k
        self.emit_cursor = model.new_field(self, "emit_cursor", ti.i32, k) if k else None
        self.emit_found = model.new_field(self, "emit_found", ti.i32, k) if k else None
        self.emit_slot = model.particle_array(self, "emit_slot", ti.i32) if k else None
        self.trail_length = model.trail_length
        self.trail = None
        if self.trail_length:
            self.trail = model.particle_array(self, "trail", dims=(3,), extra=(self.trail_length,))
        self.trail_head = 0

    def _start_particles(self, model) -> None:
        """Fill the arrays for t = 0: the builder's particles in place, every emitter slot dead."""
        fills = [(self.particle_x, model.padded(model._x0)), (self.particle_v, model.padded(model._v0))]
        if self.has_lifetimes:
            death = np.full(model.particle_capacity, -1.0)  # rows past the live count: dead, never freed
            death[: model._static_count] = ALIVE_FOREVER
            fills += [
                (self.particle_death, model.padded(death)),
                (self.particle_birth, model.padded(np.zeros(model.particle_count))),
                (self.emit_cursor, np.zeros(model.emitter_count, np.int32)),  # a pooled field is not zero
            ]
            dead = np.zeros(self.particle_free.shape[0] * 32, dtype=np.uint8)
            dead[model._static_count : model.particle_count] = 1
            self.particle_free.from_numpy(np.packbits(dead, bitorder="little").view(np.uint32))  # u32 bits
        bulk.fill(fills)  # one launch: from_numpy is a kernel per field (bulk.py)
        if self.trail_length:
            self.trail.from_numpy(model.padded(np.repeat(model._x0[:, None, :], self.trail_length, axis=1)))

    def _save_particles(self, into, whole_trail: bool) -> None:
        """Copy the particle arrays into `into` (one kernel launch), and the emission carry and trail
        head."""
        _copy_particles(self, into, self.trail_head, whole_trail)
        into.trail_head = self.trail_head
        into.emit_carry = list(self.emit_carry)

    def positions(self) -> np.ndarray:
        """(N,3) float64 positions [m] of every particle slot, alive or not (snapshot() gives the alive)."""
        return bulk.read([self.particle_x], self.model.particle_count)[0].astype(np.float64)

    def velocities(self) -> np.ndarray:
        """(N,3) float64 velocities [m/s] of every particle slot."""
        return bulk.read([self.particle_v], self.model.particle_count)[0].astype(np.float64)

    def motion(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (N,3) [m], velocities (N,3) [m/s], alive (N,) bool) of every particle slot, float64,
        in one launch of the kernel snapshot() reads with (_slots: one kernel to compile)."""
        x, v, _, death = self._slots()
        return x.astype(np.float64), v.astype(np.float64), self._alive(death, len(x))

    def _alive(self, death, n: int) -> np.ndarray:
        """(n,) bool from the slots' death times [s] (None without lifetimes: every slot lives)."""
        return np.ones(n, dtype=bool) if death is None else death > self.time

    def _slots(self) -> tuple:
        """(x, v, birth, death) of every slot in one launch (bulk.read); birth and death None without
        lifetimes."""
        n = self.model.particle_count
        if self.has_lifetimes:
            return tuple(
                bulk.read([self.particle_x, self.particle_v, self.particle_birth, self.particle_death], n)
            )
        return (*bulk.read([self.particle_x, self.particle_v], n), None, None)

    def set_positions(self, x, indices=None) -> None:
        """Overwrite positions [m]: `x` is (N,3) for every particle, or (len(indices),3) with `indices`
        the particles to move. Pinned particles move too (they are kinematic). The watchdog re-takes the
        scene's energy at the next step, since an edit can add energy legitimately."""
        self._write(self.particle_x, "x", x, indices)

    def set_velocities(self, v, indices=None) -> None:
        """Overwrite velocities [m/s], like set_positions. A pinned particle keeps the velocity it is
        given (it moves with it, as pins keep their initial velocity)."""
        self._write(self.particle_v, "v", v, indices)

    def _write(self, field_, name: str, values, indices) -> None:
        n = self.model.particle_count
        values = validate.finite_array(name, values, (3,))
        idx = np.arange(n) if indices is None else validate.index_list("indices", indices, n)
        if len(values) != len(idx):
            what = f"{n} particles" if indices is None else f"{len(idx)} indices"
            raise ParameterError(f"{name} must have shape ({len(idx)}, 3) for {what}, got {values.shape}")
        dtype = np_float()
        validate.fits_float({name: values}, dtype)
        full = field_.to_numpy()
        full[idx] = values
        field_.from_numpy(full.astype(dtype))
        self.energy_start = None  # the watchdog's energy baseline is re-taken from the edited state

    def alive_mask(self) -> np.ndarray:
        """(N,) bool: particles alive now."""
        n = self.model.particle_count
        death = bulk.read([self.particle_death], n)[0] if self.has_lifetimes else None
        return self._alive(death, n)

    def snapshot(self) -> ParticleSnapshot:
        """Copy the alive particles to NumPy (read-only output; never fed back)."""
        x, v, birth, death = self._slots()
        if self.has_lifetimes:
            idx = np.nonzero(self._alive(death, len(x)))[0]
            x, v, birth, death = x[idx], v[idx], birth[idx], death[idx]
        else:
            idx = np.arange(len(x))
        if self.has_lifetimes:
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
        for i in range(self.model.live_particles()):
            self.trail[i, head] = self.particle_x[i]


@ti.kernel
def _copy_particles(src: ti.template(), dst: ti.template(), head: ti.i32, whole_trail: ti.template()):
    ti.loop_config(serialize=src.model.serial)
    for i in range(src.model.live_particles()):
        dst.particle_x[i] = src.particle_x[i]
        dst.particle_v[i] = src.particle_v[i]
        if ti.static(src.has_lifetimes):
            dst.particle_birth[i] = src.particle_birth[i]
            dst.particle_death[i] = src.particle_death[i]
        if ti.static(src.trail_length > 0):
            if ti.static(whole_trail):
                for k in range(src.trail_length):
                    dst.trail[i, k] = src.trail[i, k]
            else:
                dst.trail[i, head] = src.trail[i, head]  # the only column a step writes
    if ti.static(src.has_lifetimes):
        for w in range(src.particle_free.shape[0]):
            dst.particle_free[w] = src.particle_free[w]
    if ti.static(src.model.emitter_count > 0):
        for k in range(src.model.emitter_count):
            dst.emit_cursor[k] = src.emit_cursor[k]


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
