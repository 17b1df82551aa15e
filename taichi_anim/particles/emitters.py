"""Emitters (Reeves 1983, sec. 2.1 "Particle generation" and 2.2 "Particle attributes"): each owns a
fixed slot range of the particle pool; a dead slot (death time <= now) is recycled for a new particle.

Per step: `n = floor(rate * dt + carry)` new particles (the fraction carries over, so the mean rate is
exact and deterministic). Dead slots carry a bit in `State.particle_free` (set by the integrator's
last kernel with an integer atomic, so the result does not depend on thread order). A single-threaded
kernel scans those bits, 32 slots per word, from a rotating cursor and takes the first `n` free slots
(deterministic; a full pool with scattered deaths costs N/32 word reads, not N death times; on GPU
backends the same slots come from parallel passes, slot_scan.py), then a parallel kernel draws each
new particle's position, velocity and lifetime from counter-based hashes (same seed, same particles,
whatever the thread count).

A liquid's nozzle (`lattice` > 0, Builder.add_fluid_emitter) places no random points: it emits whole
layers of a square lattice of that spacing on its disc, one each time the last has moved a spacing
along `direction`, so that the jet leaves at the liquid's rest density (random points a spacing apart
on average overlap, and the pressure solve would blow them apart). SPlisHSPlasH's emitters and
Blender's inflow objects emit the same way.
"""

import math
from dataclasses import asdict, dataclass
from enum import Enum

import numpy as np
import taichi as ti

from .. import capacity, validate
from ..rng import uniform
from ..runtime import backend_name, data_oriented, np_float, serial_loops
from .slot_scan import ParallelSlotScan, bit_index

# Which free-slot scan emitters use: None picks by backend and pool (parallel passes, slot_scan.py, on
# GPUs from PARALLEL_SCAN_FROM slots; else the serial scan), True or False forces one (the tests run the
# parallel scan on the CPU). On an H200 the fountain's frame of 10 steps took 1.53 ms at 10^4 slots with
# the serial scan and 2.97 ms with the parallel passes, 4.61 and 3.19 ms at 10^5: the threshold lies
# between the two measured sizes, at their geometric mean's power of two.
PARALLEL_SCAN = None
PARALLEL_SCAN_FROM = 1 << 15


class EmitterShape(Enum):
    """Where new particles appear: at a point, on a disc facing `direction`, in a ball, or in a box."""

    POINT = "point"
    DISC = "disc"
    SPHERE = "sphere"
    BOX = "box"


@dataclass(frozen=True)
class EmitterSettings:
    """An emitter's options (SI units). `spread` is the half-angle [rad] of the velocity cone around
    `direction`; `lifetime_jitter` the relative spread of lifetimes (lifetime * (1 +- jitter))."""

    shape: EmitterShape
    center: tuple[float, float, float]
    size: tuple[float, float, float]  # radius in [0] for disc/sphere; half extents for box
    direction: tuple[float, float, float]
    rate: float  # [particles/s]
    speed: float  # [m/s]
    speed_jitter: float  # relative
    spread: float  # [rad]
    lifetime: float  # [s]
    lifetime_jitter: float  # relative
    mass: float  # [kg]
    capacity: int
    color_start: tuple[float, float, float]
    color_end: tuple[float, float, float]
    particle_radius: float = 0.0  # [m]; > 0 makes hard spheres
    lattice: float = 0.0  # [m]; > 0: whole layers of a square lattice of this spacing (a liquid's nozzle)
    start_time: float = 0.0  # [s] the first step that emits (lattice emitters)
    stop_time: float | None = None  # [s] no step starting at or after it emits (None: never stops)


def _basis(direction):
    """Two unit vectors orthogonal to `direction` (and to each other)."""
    d = direction
    helper = (1.0, 0.0, 0.0) if abs(d[0]) < 0.9 else (0.0, 1.0, 0.0)
    u = (
        d[1] * helper[2] - d[2] * helper[1],
        d[2] * helper[0] - d[0] * helper[2],
        d[0] * helper[1] - d[1] * helper[0],
    )
    n = math.sqrt(sum(c * c for c in u))
    u = tuple(c / n for c in u)
    w = (d[1] * u[2] - d[2] * u[1], d[2] * u[0] - d[0] * u[2], d[0] * u[1] - d[1] * u[0])
    return u, w


def disc_lattice(radius: float, spacing: float) -> np.ndarray:
    """(P,2) [m] the points of a square lattice of `spacing` through the centre within `radius` of it
    (the centre alone for a radius under a spacing)."""
    m = int(math.floor(radius / spacing + 1e-9))
    a = np.arange(-m, m + 1) * spacing
    uv = np.stack(np.meshgrid(a, a, indexing="ij"), -1).reshape(-1, 2)
    return uv[(uv * uv).sum(axis=1) <= radius * radius * (1.0 + 1e-9) + 1e-30]


@data_oriented
class Emitter:
    """Emits into slots [start, start + capacity) of the particle pool."""

    def __init__(self, settings: EmitterSettings, start: int, index: int):
        self.s = settings
        self.start = start
        self.capacity = settings.capacity
        self.index = index
        self.u, self.w = _basis(settings.direction)
        end = start + self.capacity
        # Slots are int32 indices in the kernels (the Builder refuses larger scenes before this).
        validate.capacity("capacity", end, bytes_each=0, unit="particle slots up to this emitter's last")
        self.word_lo, self.word_hi = start >> 5, (end - 1) >> 5
        # Bits of the first and last word that belong to this emitter's slot range.
        self.mask_lo = (0xFFFFFFFF << (start & 31)) & 0xFFFFFFFF
        self.mask_hi = 0xFFFFFFFF >> (31 - ((end - 1) & 31))
        # Under capacity buckets the choice goes by the bucket, so that every size compiles one kernel.
        self.serial = serial_loops(capacity.bucket(self.capacity) if capacity.enabled() else self.capacity)
        # One GPU thread walking the bits was nearly the whole step's time at 10^7 slots: large GPU pools
        # scan in parallel passes, whose scratch is made here with the model (nothing is allocated mid-run).
        slots = capacity.bucket(self.capacity) if capacity.enabled() else self.capacity
        on_gpu = backend_name() != "cpu" and slots >= PARALLEL_SCAN_FROM
        self.parallel_scan = on_gpu if PARALLEL_SCAN is None else bool(PARALLEL_SCAN)
        self._slot_scan = ParallelSlotScan(self.capacity) if self.parallel_scan else None
        self.layer_points = 0
        if settings.lattice > 0.0:
            uv = disc_lattice(settings.size[0], settings.lattice)
            self.layer_points = len(uv)
            self.layer_uv = ti.Vector.field(2, float, shape=len(uv))
            self.layer_uv.from_numpy(uv.astype(np_float()))
            self.layer_offset = ti.field(float, shape=())

    def settings(self) -> dict:
        d = asdict(self.s)
        d["shape"] = self.s.shape.value
        d["slots"] = [self.start, self.start + self.capacity]
        if self.layer_points:
            d["layer_points"] = self.layer_points
        return d

    def plan(self, state, dt: float) -> int:
        """The number of particles this emitter spawns in a step of dt [s] of `state`; carries the
        fraction left over to the next step (`State.emit_carry`), so call it once per step, in order."""
        want = self.s.rate * dt + state.emit_carry[self.index]
        state.emit_carry[self.index] = want - int(want)
        return min(int(want), self.capacity)

    def plan_layers(self, state, t: float, dt: float) -> int:
        """A nozzle's particles in a step of dt [s] from t: the whole layers its jet advances by at `speed`
        (the distance left over carries to the next step, `State.emit_carry`, below a spacing), none
        outside [start_time, stop_time), at most as many as its slots hold. Sets the kernel's offset
        of the newest layer from the disc."""
        s, k = self.s, self.index
        eps = 1e-6 * dt  # a time summed from steps (15 of 1/60 s) falls short of 0.25 s by its last bits
        if t + dt <= s.start_time + eps or (s.stop_time is not None and t >= s.stop_time - eps):
            return 0
        reach = s.speed * dt + state.emit_carry[k]
        # A layer per spacing travelled; the 1e-9 keeps sums of step lengths that should make whole
        # spacings (12 steps of 1/240 s at 1 m/s and 1 cm) from falling short by the last bit.
        layers = min(int(reach / s.lattice + 1e-9), self.capacity // self.layer_points)
        state.emit_carry[k] = min(max(reach - layers * s.lattice, 0.0), s.lattice * (1.0 - 1e-9))
        self.layer_offset[None] = state.emit_carry[k]
        return layers * self.layer_points

    def slot_range(self) -> tuple[int, int, int, int, int]:
        """(start, word_lo, word_hi, mask_lo, mask_hi): the slot range as kernel arguments (not
        constants, so that an emitter of another capacity compiles nothing new)."""
        return self.start, self.word_lo, self.word_hi, self.mask_lo, self.mask_hi

    def emit(self, state, t: float, dt: float, seed: int, step: int) -> None:
        """Spawn this step's particles at time t (they then live through the step). The fraction of a
        particle left over and the scan cursor are the state's (`State.emit_carry`, `emit_cursor`)."""
        n = self.plan_layers(state, t, dt) if self.layer_points else self.plan(state, dt)
        if n == 0:
            return
        self._emit(state, n, t, seed, step, *self.slot_range())

    @ti.kernel
    def _emit(
        self,
        state: ti.template(),
        n: ti.i32,
        t: float,
        seed: ti.u32,
        step: ti.u32,
        start: ti.i32,
        word_lo: ti.i32,
        word_hi: ti.i32,
        mask_lo: ti.u32,
        mask_hi: ti.u32,
    ):
        # One launch: the scan for free slots (serial, or the parallel passes of slot_scan.py), then a
        # parallel spawn into them.
        if ti.static(self.parallel_scan):
            self._slot_scan.take(state, self.index, n, start, word_lo, word_hi, mask_lo, mask_hi)
        else:
            ti.loop_config(serialize=True)
            for _ in range(1):
                state.emit_found[self.index] = self.scan(
                    state, n, start, word_lo, word_hi, mask_lo, mask_hi, self, 0
                )
        ti.loop_config(serialize=self.serial)
        for j in range(state.emit_found[self.index]):
            self._spawn_one(state, start, j, t, seed, step)

    @ti.func
    def scan(
        self,
        state: ti.template(),
        n,
        start,
        word_lo,
        word_hi,
        mask_lo,
        mask_hi,
        slots: ti.template(),
        ctx: ti.template(),
    ):
        """Take the first n free slots of this emitter's range, 32 per word from the rotating cursor, in
        order: `slots.free_bits(state, w, ctx)` gives word w's free bits and `slots.take(state, slot,
        found, start, ctx)` records a taken one (this emitter: the state's free bits; a blocked frame
        (integrators/blocked.py): its plan of births). Returns how many were found."""
        words = word_hi - word_lo + 1
        cursor = state.emit_cursor[self.index]
        found = 0
        scanned = 0
        while found < n and scanned < words:
            w = word_lo + cursor
            mask = ti.u32(0xFFFFFFFF)
            if w == word_lo:
                mask &= mask_lo
            if w == word_hi:
                mask &= mask_hi
            bits = slots.free_bits(state, w, ctx) & mask
            while bits != 0 and found < n:
                low = bits & (~bits + ti.u32(1))  # lowest set bit
                slots.take(state, w * 32 + bit_index(low), found, start, ctx)
                found += 1
                bits ^= low
            if found < n:  # this word is used up: move on (else more may be free here)
                cursor = (cursor + 1) % words
                scanned += 1
        state.emit_cursor[self.index] = cursor
        return found

    @ti.func
    def free_bits(self, state: ti.template(), w, ctx: ti.template()):
        return state.particle_free[w]

    @ti.func
    def take(self, state: ti.template(), slot, found, start, ctx: ti.template()):
        state.emit_slot[start + found] = slot
        state.particle_free[slot >> 5] ^= ti.u32(1) << ti.cast(slot & 31, ti.u32)

    @ti.func
    def _sample(self, seed, step, j):
        r = ti.Vector([uniform(seed, step, j, k) for k in ti.static(range(7))])
        center = ti.Vector(self.s.center, dt=float)
        axis = ti.Vector(self.s.direction, dt=float)
        u = ti.Vector(self.u, dt=float)
        w = ti.Vector(self.w, dt=float)
        pos = center
        if ti.static(self.s.shape == EmitterShape.DISC):
            rad = self.s.size[0] * ti.sqrt(r[0])
            ang = 2.0 * math.pi * r[1]
            pos = center + rad * (ti.cos(ang) * u + ti.sin(ang) * w)
        elif ti.static(self.s.shape == EmitterShape.SPHERE):
            z = 2.0 * r[0] - 1.0
            ang = 2.0 * math.pi * r[1]
            ring = ti.sqrt(ti.max(1.0 - z * z, 0.0))
            rad = self.s.size[0] * ti.pow(r[2], 1.0 / 3.0)
            pos = center + rad * ti.Vector([ring * ti.cos(ang), ring * ti.sin(ang), z])
        elif ti.static(self.s.shape == EmitterShape.BOX):
            pos = center + (2.0 * r.xyz - 1.0) * ti.Vector(self.s.size, dt=float)
        # Direction uniform on the spherical cap of half-angle `spread` around `direction`.
        cos_t = 1.0 - r[3] * (1.0 - ti.cos(self.s.spread))
        sin_t = ti.sqrt(ti.max(1.0 - cos_t * cos_t, 0.0))
        phi = 2.0 * math.pi * r[4]
        dirn = cos_t * axis + sin_t * (ti.cos(phi) * u + ti.sin(phi) * w)
        speed = self.s.speed * (1.0 + self.s.speed_jitter * (2.0 * r[5] - 1.0))
        return pos, speed * dirn, self.life(r[6])

    @ti.func
    def _layer_point(self, state: ti.template(), j):
        """The j-th particle of this step's layers (plan_layers): layer j // P of the P lattice points,
        the step's first layer furthest along the jet, the newest layer_offset from the disc."""
        p = self.layer_points
        layers = state.emit_found[self.index] // p
        uv = self.layer_uv[j % p]
        axis = ti.Vector(self.s.direction, dt=float)
        along = self.layer_offset[None] + (layers - 1 - j // p) * self.s.lattice
        pos = ti.Vector(self.s.center, dt=float) + along * axis
        pos += uv[0] * ti.Vector(self.u, dt=float) + uv[1] * ti.Vector(self.w, dt=float)
        return pos, self.s.speed * axis, ti.cast(self.s.lifetime, float)

    @ti.func
    def life(self, u):
        """A new particle's lifetime [s] from its uniform draw u (the 7th, k = 6, of `_sample`)."""
        return self.s.lifetime * (1.0 + self.s.lifetime_jitter * (2.0 * u - 1.0))

    @ti.func
    def lifetime_of(self, seed, step, j):
        """The lifetime [s] `_sample(seed, step, j)` gives, without drawing the rest (a blocked frame's
        plan of births, integrators/blocked.py)."""
        return self.life(uniform(seed, step, j, ti.u32(6)))

    @ti.func
    def _spawn_one(self, state: ti.template(), start, j, t, seed, step):
        i = state.emit_slot[start + j]
        x, v, life = ti.Vector.zero(float, 3), ti.Vector.zero(float, 3), ti.cast(0.0, float)
        if ti.static(self.layer_points):
            x, v, life = self._layer_point(state, j)
        else:
            x, v, life = self._sample(seed, step, ti.cast(start + j, ti.u32))
        state.particle_x[i] = x
        state.particle_v[i] = v
        state.particle_birth[i] = t
        state.particle_death[i] = t + life
        if ti.static(state.trail_length > 0):
            for k in range(state.trail_length):
                state.trail[i, k] = x
