"""A frame of substeps in one launch for particles that do not act on each other (temporal blocking):
each particle is loaded once, taken through every substep in registers and stored once, instead of one
launch and one pass over memory per substep. It is the temporal blocking (time skewing) of stencil
codes (Wonnacott, "Using time skewing to eliminate idle time due to memory bandwidth and network
limitations", IPDPS 2000) in its simplest case: no halo is needed, because nothing couples two
particles: the method is single-stage (`fusable`), the forces pointwise (no element terms), the
colliders pure functions of (x, t), and no solver or attachment acts between substeps (Stepper.frame_mode
checks this). Trails are per particle: each writes the column of every substep, as the step would.

Emitters (particles/emitters.py) couple the slots through their free-slot scan: a step's births take the
first free slots from a rotating cursor, and a slot is free from the step after its particle died. A
particle's death time is fixed at its birth, so the scan of every substep can be planned before any
particle moves:
  1. every live slot gets `free_from`, the first substep at whose start the step-by-step path would find
     its bit set (0: set now; k + 1: released by step k's final kernel, i.e. death <= t_k + h; never);
  2. one serial pass runs the emitters' scans of substeps 0, 1, ... with a slot's bit read as
     free_from <= k; a taken slot records its birth (substep, index in the batch) in a per-slot chain
     and gets the free_from of its new particle (whose lifetime is the same hash draw the birth makes);
  3. one parallel pass steps each particle through the frame, born where its chain says, and sets the
     free bits the frame ends with.
The result is the step-by-step path's: the same births in the same slots, the same arithmetic per
particle (tests/test_blocked_frame.py compares them)."""

import numpy as np
import taichi as ti

from .. import runtime
from ..finish import finished
from ..runtime import compile_with, data_oriented, np_float
from ..watchdog import watch_limits

# Substeps per launch: a longer frame runs as several launches (the times and birth counts travel as
# small arrays of this many rows at most).
MAX_STEPS = 64
NEVER = 2**30  # free_from of a slot whose particle outlives the launch
# A launch's loops run serially on the CPU below this many particle-steps (capacity x substeps): the
# fountain's frame of 10 substeps on the 2-core Xeon took 7.0 ns per particle-step serially and 9.2 in
# parallel at 1e4 particles, 6.4 and 5.6 at 3e4, 6.0 and 5.0 at 1e5, 6.1 and 4.1 at 1e6 (the serial
# pass that plans births, and the thread pool's wake-up, do not shrink with a second core).
SERIAL_BELOW = 300_000


@data_oriented
class BlockedFrame:
    """Runs frames of a fusable `method` on `model` (Stepper.frame_mode "blocked"). Scratch, with
    emitters: per slot the substep it is free from and the head and tail of its chain of births in this
    launch; the births (substep, index in the step's batch, next in the chain), at most one per slot of
    the pool per launch (more births split the frame into more launches)."""

    def __init__(self, model, method):
        self.model = model
        self.method = method
        self.lifetimes = model.emitter_count > 0
        self.capacity = model.particle_capacity
        # (start, word_lo, word_hi, mask_lo, mask_hi, end) per emitter: arguments, not constants, so
        # that another pool size compiles nothing new.
        self.ranges = np.zeros((1, 6), np.int32)
        if self.lifetimes:
            arr = model.particle_array
            self.free_from = arr(self, "blocked_free_from", ti.i32)
            self.birth_head = arr(self, "blocked_birth_head", ti.i32)
            self.birth_tail = arr(self, "blocked_birth_tail", ti.i32)
            self.birth_step = arr(self, "blocked_birth_step", ti.i32)
            self.birth_index = arr(self, "blocked_birth_index", ti.i32)
            self.birth_next = arr(self, "blocked_birth_next", ti.i32)
            self.birth_count = model.new_field(self, "blocked_birth_count", ti.i32, ())
            words = (self.capacity + 31) // 32
            self.word_bits = model.new_field(self, "blocked_word_bits", ti.u32, words)
            self.word_next = model.new_field(self, "blocked_word_next", ti.i32, words)
            rows = [[*e.slot_range(), e.start + e.capacity] for e in model.emitters]
            # int32 (GPU backends without 64-bit integers); the u32 masks travel as their bit patterns.
            self.ranges = np.array(rows, np.int64).astype(np.uint32).view(np.int32)

    def run(self, state, h: float, count: int) -> None:
        """`count` substeps of h [s] from the state's time (the caller advances time and step count)."""
        model = self.model
        times = np.empty(count)  # each substep's start, accumulated as `count` calls of Stepper.step do
        t = state.time
        for k in range(count):
            times[k] = t
            t += h
        births = np.zeros((count, max(model.emitter_count, 1)), np.int32)
        for k in range(count):
            for e in model.emitters:
                births[k, e.index] = e.plan(state, h)
        per_step = births.sum(axis=1)
        first = 0
        while first < count:
            end, total = first + 1, int(per_step[first])
            while end < count and end - first < MAX_STEPS and total + per_step[end] <= self.capacity:
                total += int(per_step[end])
                end += 1
            serial = runtime.backend_name() == "cpu" and self.capacity * (end - first) < SERIAL_BELOW
            self._launch(
                serial,
                model,
                state,
                self.method,
                times[first:end].astype(np_float()),
                births[first:end],
                self.ranges,
                end - first,
                h,
                model.seed,
                state.step_count + first,
                state.trail_head + first,
            )
            first = end

    # The particle pass inlines every collider's swept test, as Integrator._final does: Taichi's CFG
    # passes were most of its compile (the fountain demo's first frame with an empty cache compiled
    # 22.8 s with them, 4.6 s without) and bought no run time measurable here (120 frames: 1.62 and
    # 1.62 ms per frame without them, 1.64 and 2.78 with).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _launch(
        self,
        serial: ti.template(),
        model: ti.template(),
        state: ti.template(),
        method: ti.template(),
        times: ti.types.ndarray(ndim=1),
        births: ti.types.ndarray(dtype=ti.i32, ndim=2),
        ranges: ti.types.ndarray(dtype=ti.i32, ndim=2),
        steps: ti.i32,
        h: float,
        seed: ti.u32,
        step0: ti.i32,
        head: ti.i32,
    ):
        if ti.static(self.lifetimes):
            # 1. The substep each slot is free from, and per word of 32 slots the bits free at the start
            # and the first substep at which another of its slots comes free; no births yet.
            ti.loop_config(serialize=serial)
            for w in range((model.live_particles() + 31) >> 5):
                bits = ti.u32(0)
                next_free = NEVER
                for b in range(32):
                    i = (w << 5) + b
                    if i < model.live_particles():
                        bit = ti.u32(1) << ti.cast(b, ti.u32)
                        free = 0
                        if (state.particle_free[w] & bit) == 0:
                            free = self.free_step(state.particle_death[i], times, 0, steps, h)
                        self.free_from[i] = free
                        self.birth_head[i] = -1
                        if free == 0:
                            bits |= bit
                        else:
                            next_free = ti.min(next_free, free)
                self.word_bits[w] = bits
                self.word_next[w] = next_free
                live = model.live_particles() - (w << 5)
                mask = ti.u32(0xFFFFFFFF)  # the live slots of this word: their bits are pass 3's to set
                if live < 32:
                    mask = (ti.u32(1) << ti.cast(live, ti.u32)) - ti.u32(1)
                state.particle_free[w] &= ~mask
            # 2. The emitters' scans, substep after substep, in the order Stepper.step runs them.
            ti.loop_config(serialize=True)
            for _ in range(1):
                self.birth_count[None] = 0
                for k in range(steps):
                    for e in ti.static(model.emitters):
                        n = births[k, e.index]
                        if n > 0:
                            r = e.index
                            e.scan(
                                state,
                                n,
                                ranges[r, 0],
                                ranges[r, 1],
                                ranges[r, 2],
                                ti.cast(ranges[r, 3], ti.u32),
                                ti.cast(ranges[r, 4], ti.u32),
                                self,
                                (k, e, times, steps, h, seed, step0),
                            )
        # 3. Each particle through the frame. One particle per iteration, not a word: Taichi cuts a CPU
        # loop into tasks of at least 512 iterations, and a loop over words left one thread idle up to
        # ~5e5 particles. Pass 1 cleared the live slots' bits; the few slots free at the end set theirs.
        ti.loop_config(serialize=serial)
        for i in range(model.live_particles()):
            free = self.advance(model, state, method, i, times, ranges, steps, h, seed, step0, head)
            if ti.static(self.lifetimes):
                if free:
                    ti.atomic_or(state.particle_free[i >> 5], ti.u32(1) << ti.cast(i & 31, ti.u32))

    @ti.func
    def advance(
        self,
        model: ti.template(),
        state: ti.template(),
        method: ti.template(),
        i,
        times: ti.template(),
        ranges: ti.template(),
        steps,
        h,
        seed,
        step0,
        head,
    ):
        """Particle i through `steps` substeps (born on the way where its chain says), its trail column
        head + k written after substep k as State.record_trails does; returns whether its slot ends the
        launch free."""
        x = state.particle_x[i]
        v = state.particle_v[i]
        lim = watch_limits(state)
        free = False
        if ti.static(self.lifetimes):
            birth = state.particle_birth[i]
            death = state.particle_death[i]
            m = self.birth_head[i]
            for k in range(steps):
                t = ti.cast(times[k], float)
                if m >= 0 and self.birth_step[m] == k:  # Emitter._spawn_one, before the step's update
                    for e in ti.static(model.emitters):
                        start = ranges[e.index, 0]
                        if start <= i and i < ranges[e.index, 5]:
                            j = ti.cast(start + self.birth_index[m], ti.u32)
                            x, v, life = e._sample(seed, ti.cast(step0 + k, ti.u32), j)
                            birth = t
                            death = t + life
                            if ti.static(state.trail_length > 0):  # a new particle's trail starts at birth
                                for c in range(state.trail_length):
                                    state.trail[i, c] = x
                    m = self.birth_next[m]
                if death > t:  # alive at the step's start (Integrator._final)
                    x, v = self.substep(model, state, method, i, x, v, t, h, step0 + k + 1, lim)
                self.record_trail(state, i, x, head + k)
            state.particle_birth[i] = birth
            state.particle_death[i] = death
            free = self.free_from[i] <= steps
        else:
            for k in range(steps):
                x, v = self.substep(
                    model, state, method, i, x, v, ti.cast(times[k], float), h, step0 + k + 1, lim
                )
                self.record_trail(state, i, x, head + k)
        state.particle_x[i] = x
        state.particle_v[i] = v
        return free

    @ti.func
    def record_trail(self, state: ti.template(), i, x, column):
        if ti.static(state.trail_length > 0):
            state.trail[i, column % state.trail_length] = x

    @ti.func
    def substep(
        self, model: ti.template(), state: ti.template(), method: ti.template(), i, x, v, t, h, step, lim
    ):
        x1, v1 = method.update(model, i, x, v, t, h)
        return finished(model, state, method.collision_mode, i, x, v, x1, v1, t, h, step, lim)

    @ti.func
    def free_step(self, death, times: ti.template(), k0, steps, h):
        """One after the first substep k >= k0 whose final kernel releases a particle dying at `death`
        [s] (death <= t_k + h: Integrator._final's release_if_dead, or release if dead at t_k), else
        NEVER: the first substep at whose start its slot is free."""
        free = NEVER
        if death <= ti.cast(times[steps - 1], float) + h:  # most particles outlive the launch: one test
            for k in range(k0, steps):
                if free == NEVER and death <= ti.cast(times[k], float) + h:
                    free = k + 1
        return free

    # Emitter.scan reads and takes slots through these two, ctx = (substep, emitter, times, substeps, h,
    # seed, first step number).
    @ti.func
    def free_bits(self, state: ti.template(), w, ctx: ti.template()):
        """Word w's free bits at substep k = ctx[0]: the word's kept bits, brought up to date from its
        slots' free_from only when one of them has come free since (a pool scanned end to end, when
        births outrun deaths, then reads one word per 32 slots, as the step-by-step scan does)."""
        k = ctx[0]
        if self.word_next[w] <= k:
            bits = ti.u32(0)
            next_free = NEVER
            for b in range(32):
                i = (w << 5) + b
                if i < self.model.live_particles():
                    free = self.free_from[i]
                    if free <= k:
                        bits |= ti.u32(1) << ti.cast(b, ti.u32)
                    else:
                        next_free = ti.min(next_free, free)
            self.word_bits[w] = bits
            self.word_next[w] = next_free
        return self.word_bits[w]

    @ti.func
    def take(self, state: ti.template(), slot, found, start, ctx: ti.template()):
        """Record the birth in `slot` at substep k as the found-th of the step's batch, and when the new
        particle's slot is free again (its lifetime: Emitter.lifetime_of, _sample's own draw)."""
        # ctx = (k, emitter, times, steps, h, seed, step0), read in place (an array cannot be assigned).
        k = ctx[0]
        m = self.birth_count[None]
        self.birth_count[None] = m + 1
        self.birth_step[m] = k
        self.birth_index[m] = found
        self.birth_next[m] = -1
        if self.birth_head[slot] < 0:
            self.birth_head[slot] = m
        else:
            self.birth_next[self.birth_tail[slot]] = m
        self.birth_tail[slot] = m
        life = ctx[1].lifetime_of(ctx[5], ti.cast(ctx[6] + k, ti.u32), ti.cast(start + found, ti.u32))
        death = ti.cast(ctx[2][k], float) + life
        free = self.free_step(death, ctx[2], k, ctx[3], ctx[4])
        self.free_from[slot] = free
        w = slot >> 5
        self.word_bits[w] ^= ti.u32(1) << ti.cast(slot & 31, ti.u32)  # taken (it was free)
        self.word_next[w] = ti.min(self.word_next[w], free)
