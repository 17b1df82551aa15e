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
from ..collision.response import distances_bound, path_is_clear
from ..finish import finished
from ..runtime import compile_with, data_oriented, np_float
from ..watchdog import breaks_bounds, watch_limits

# Substeps per launch: a longer frame runs as several launches (the plan of times and birth counts travels
# as a small array of this many rows at most).
MAX_STEPS = 64
NEVER = 2**30  # free_from of a slot whose particle outlives the launch
# A launch's loops run serially on the CPU below this many particle-steps (capacity x substeps): the
# fountain's frame of 10 substeps on the 2-core Xeon took 7.0 ns per particle-step serially and 9.2 in
# parallel at 1e4 particles, 6.4 and 5.6 at 3e4, 6.0 and 5.0 at 1e5, 6.1 and 4.1 at 1e6 (the serial
# pass that plans births, and the thread pool's wake-up, do not shrink with a second core).
SERIAL_BELOW = 300_000
# Particles per pack on the CPU (see BlockedFrame.advance_pack): 8 lanes of f32 fill an AVX register, 16
# made the pack's code twice as long (its compile with it) for no gain in a trial on the 2-core Xeon.
PACK = 8
# Packs from this many particles (the pool's capacity): their kernel compiles about 1.7 s longer with an
# empty cache and 0.15 s longer with a warm one (the 2-core Xeon), and saves about 2 ns a particle-step,
# so below this size a frame is too short (under ~0.6 ms of 10 substeps) for them to repay a start.
PACKS_FROM = 8192
# None: packs where they apply (`packs_apply`) from PACKS_FROM particles; True: wherever they apply;
# False: one particle per iteration (tests compare both).
PACKED = None


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
        # (start, word_lo, word_hi, mask_lo, mask_hi, end) per emitter: a field's values, not constants, so
        # that another pool size compiles nothing new.
        rows = np.zeros((1, 6), np.int32)
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
            rows = np.array(rows, np.int64).astype(np.uint32).view(np.int32)
        # A field written once: each array argument costs a launch about 20 us on the Xeon (a frame of
        # 1e4 particles in packs takes 0.45 ms), so the frame's plan travels as one array.
        self.ranges = model.new_field(self, "blocked_ranges", ti.i32, rows.shape)
        self.ranges.from_numpy(rows)
        wanted = model.particle_capacity >= PACKS_FROM if PACKED is None else PACKED
        self.packed = wanted and packs_apply(model)
        self.watch_count = None  # the watchdog's count after the last frame (CPU), see run

    def run(self, state, h: float, count: int) -> None:
        """`count` substeps of h [s] from the state's time (the caller advances time and step count)."""
        model = self.model
        # The plan: a header row (h, the seed, the first step number, the first trail column; the launch
        # writes the watchdog's count after it, which Stepper.check then reads without a launch), then one
        # row per substep: its start time, accumulated as `count` calls of Stepper.step do, and each
        # emitter's births. Integers travel as the bits of an integer of the float's width (exact at any
        # count): every scalar argument of a launch costs ~3 us of Taichi's Python, an array ~20 us.
        plan = np.zeros((count + 1, max(1 + model.emitter_count, 5)), np_float())
        ints = plan.view(np.int32 if plan.dtype == np.float32 else np.int64)
        plan[0, 0] = h
        seed = np.array([model.seed], np.uint32)  # a u32 argument before: its bits
        ints[0, 1] = seed.view(np.int32)[0] if ints.dtype == np.int32 else seed[0]
        births = ints[1:, 1 : 1 + model.emitter_count]
        t = state.time
        for k in range(count):
            plan[k + 1, 0] = t
            t += h
        for k in range(count):
            for e in model.emitters:
                births[k, e.index] = e.plan(state, h)
        per_step = births.sum(axis=1)
        on_cpu = runtime.backend_name() == "cpu"
        first = 0
        while first < count:
            end, total = first + 1, int(per_step[first])
            while end < count and end - first < MAX_STEPS and total + per_step[end] <= self.capacity:
                total += int(per_step[end])
                end += 1
            serial = on_cpu and self.capacity * (end - first) < SERIAL_BELOW
            chunk = plan
            if (first, end) != (0, count):  # a frame split into launches: the header, then this one's rows
                chunk = np.concatenate([plan[:1], plan[1 + first : 1 + end]])
            chunk.view(ints.dtype)[0, 2:4] = state.step_count + first, state.trail_head + first
            self._launch(serial, model, state, self.method, chunk)
            first = end
        # On the CPU the launch wrote into `chunk` itself (a GPU's copy is not read back here).
        self.watch_count = int(chunk.view(ints.dtype)[0, 4]) if on_cpu else None

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
        plan: ti.types.ndarray(ndim=2),
    ):
        steps = plan.shape[0] - 1
        h = ti.cast(plan[0, 0], float)
        seed = ti.cast(self.int_at(plan, 0, 1), ti.u32)
        step0 = self.int_at(plan, 0, 2)
        head = self.int_at(plan, 0, 3)
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
                            free = self.free_step(state.particle_death[i], plan, 0, steps, h)
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
                        n = self.births_of(plan, k, e.index)
                        if n > 0:
                            r = e.index
                            e.scan(
                                state,
                                n,
                                self.ranges[r, 0],
                                self.ranges[r, 1],
                                self.ranges[r, 2],
                                ti.cast(self.ranges[r, 3], ti.u32),
                                ti.cast(self.ranges[r, 4], ti.u32),
                                self,
                                (k, e, plan, steps, h, seed, step0),
                            )
        # 3. Each particle through the frame. One particle per iteration, not a word: Taichi cuts a CPU
        # loop into tasks of at least 512 iterations, and a loop over words left one thread idle up to
        # ~5e5 particles. Pass 1 cleared the live slots' bits; the few slots free at the end set theirs.
        if ti.static(self.packed):
            ti.loop_config(serialize=serial)
            for p in range((model.live_particles() + PACK - 1) // PACK):
                self.advance_pack(model, state, method, p * PACK, plan, steps, h, seed, step0, head)
        else:
            ti.loop_config(serialize=serial)
            for i in range(model.live_particles()):
                x, v, birth, death, m = self.start_of(state, i)
                lim = watch_limits(state)
                for k in range(steps):
                    x, v, birth, death, m = self.substep_of(
                        model,
                        state,
                        method,
                        i,
                        x,
                        v,
                        birth,
                        death,
                        m,
                        k,
                        plan,
                        h,
                        seed,
                        step0,
                        head,
                        lim,
                    )
                self.end_of(state, i, x, v, birth, death, steps)
        # 4. The watchdog's count, for Stepper.check (a Python-scope field read is a launch, ~20 us).
        plan[0, 4] = self.as_float(state.nonfinite_count[None])

    @ti.func
    def start_of(self, state: ti.template(), i):
        """Particle i at the launch's start: (x, v, birth, death, the head of its chain of births)."""
        birth = ti.cast(0.0, float)
        death = ti.cast(0.0, float)
        m = -1
        if ti.static(self.lifetimes):
            birth = state.particle_birth[i]
            death = state.particle_death[i]
            m = self.birth_head[i]
        return state.particle_x[i], state.particle_v[i], birth, death, m

    @ti.func
    def end_of(self, state: ti.template(), i, x, v, birth, death, steps):
        """Particle i's end of the launch written, and its slot's free bit set if it ends free."""
        state.particle_x[i] = x
        state.particle_v[i] = v
        if ti.static(self.lifetimes):
            state.particle_birth[i] = birth
            state.particle_death[i] = death
            if self.free_from[i] <= steps:
                ti.atomic_or(state.particle_free[i >> 5], ti.u32(1) << ti.cast(i & 31, ti.u32))

    @ti.func
    def substep_of(
        self,
        model: ti.template(),
        state: ti.template(),
        method: ti.template(),
        i,
        x,
        v,
        birth,
        death,
        m,
        k,
        plan: ti.template(),
        h,
        seed,
        step0,
        head,
        lim,
    ):
        """Particle i (at x, v, with its birth and death times and its next birth m in the chain) through
        substep k, born first where its chain says, its trail column head + k written after it as
        State.record_trails does: the new (x, v, birth, death, m)."""
        t = self.time_of(plan, k)
        if ti.static(self.lifetimes):
            if m >= 0 and self.birth_step[m] == k:  # Emitter._spawn_one, before the step's update
                for e in ti.static(model.emitters):
                    start = self.ranges[e.index, 0]
                    if start <= i and i < self.ranges[e.index, 5]:
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
        else:
            x, v = self.substep(model, state, method, i, x, v, t, h, step0 + k + 1, lim)
        self.record_trail(state, i, x, head + k)
        return x, v, birth, death, m

    @ti.func
    def advance_pack(
        self,
        model: ti.template(),
        state: ti.template(),
        method: ti.template(),
        base,
        plan: ti.template(),
        steps,
        h,
        seed,
        step0,
        head,
    ):
        """Particles base .. base + PACK - 1 through the frame as one pack: the same arithmetic per
        particle as the loop of `substep_of`, written so that LLVM's straight-line (SLP) vectoriser runs
        the pack's lanes in one vector register. Taichi runs each iteration of a parallel loop as a call
        of its body, so a loop over particles is never vectorised; PACK copies of the update, one per
        lane with constant indices into small local matrices, are straight-line code that is.

        A substep in which every lane is quiet (no birth; dead, or alive on a path that `path_is_clear`
        vouches for and inside the watchdog's bounds) ends at the update, which is then what `finished`
        would return; those substeps run in an inner loop that writes no memory, so LLVM keeps the
        particles' constant data (mass, radius) in registers. In a substep with a lane that is not quiet,
        that lane goes through `substep_of` as the particle loop would take it, and the quiet ones keep
        their update (which is what `substep_of` would give them)."""
        n = model.live_particles()
        lim = watch_limits(state)
        X = ti.Matrix.zero(float, 3, PACK)
        V = ti.Matrix.zero(float, 3, PACK)
        B = ti.Vector.zero(float, PACK)
        D = ti.Vector.zero(float, PACK)  # death time; without lifetimes a time no lane reaches (alive)
        M = ti.Vector.zero(ti.i32, PACK)
        NB = ti.Vector.zero(ti.i32, PACK)  # the substep of the lane's next birth (NEVER: none)
        for j in ti.static(range(PACK)):
            x, v, birth, death, m = self.start_of(state, ti.min(base + j, n - 1))
            for c in ti.static(range(3)):
                X[c, j] = x[c]
                V[c, j] = v[c]
            B[j] = birth
            D[j] = -1e30  # a lane past the end is dead throughout, and never written
            M[j] = -1
            NB[j] = NEVER
            if base + j < n:
                D[j] = 1e30
                if ti.static(self.lifetimes):
                    D[j] = death
                    M[j] = m
                    if m >= 0:
                        NB[j] = self.birth_step[m]
        k = 0
        X1 = X  # the update of substep k, and which lanes are quiet in it
        V1 = V
        Q = ti.Vector.zero(ti.i32, PACK)
        while k < steps:
            while k < steps:  # quiet substeps: no memory written
                t = self.time_of(plan, k)
                quiet = True
                for j in ti.static(range(PACK)):
                    i = ti.min(base + j, n - 1)
                    x = ti.Vector([X[0, j], X[1, j], X[2, j]])
                    v = ti.Vector([V[0, j], V[1, j], V[2, j]])
                    x1, v1 = method.update(model, i, x, v, t, h)
                    live = D[j] > t
                    fine = not breaks_bounds(state, lim, x1, v1)
                    if ti.static(model.collider_count > 0):
                        fine &= path_is_clear(model.colliders, x, x1, t, model.radius(i))
                    q = (NB[j] != k) & (fine | (D[j] <= t))  # `|`, not `or`: no branch
                    Q[j] = ti.cast(q, ti.i32)
                    quiet &= q
                    for c in ti.static(range(3)):
                        X1[c, j] = ti.select(live, x1[c], x[c])
                        V1[c, j] = ti.select(live, v1[c], v[c])
                if not quiet:
                    break
                X = X1
                V = V1
                k += 1
            if k < steps:
                # Substep k: the quiet lanes keep their update, the others go through the particle path
                # one at a time (copies: a run-time lane index).
                Xk, Vk, Qk = X, V, Q
                Xs, Vs, Bs, Ds, Ms, NBs = X1, V1, B, D, M, NB
                for j in range(PACK):
                    i = base + j
                    if i < n and Qk[j] == 0:
                        x, v, birth, death, m = self.substep_of(
                            model,
                            state,
                            method,
                            i,
                            ti.Vector([Xk[0, j], Xk[1, j], Xk[2, j]]),
                            ti.Vector([Vk[0, j], Vk[1, j], Vk[2, j]]),
                            Bs[j],
                            Ds[j],
                            Ms[j],
                            k,
                            plan,
                            h,
                            seed,
                            step0,
                            head,
                            lim,
                        )
                        for c in ti.static(range(3)):
                            Xs[c, j] = x[c]
                            Vs[c, j] = v[c]
                        Bs[j] = birth
                        Ds[j] = death
                        Ms[j] = m
                        if ti.static(self.lifetimes):
                            NBs[j] = NEVER
                            if m >= 0:
                                NBs[j] = self.birth_step[m]
                X, V, B, D, M, NB = Xs, Vs, Bs, Ds, Ms, NBs
                k += 1
        for j in ti.static(range(PACK)):
            if base + j < n:
                x = ti.Vector([X[0, j], X[1, j], X[2, j]])
                v = ti.Vector([V[0, j], V[1, j], V[2, j]])
                self.end_of(state, base + j, x, v, B[j], D[j], steps)

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
    def free_step(self, death, plan: ti.template(), k0, steps, h):
        """One after the first substep k >= k0 whose final kernel releases a particle dying at `death`
        [s] (death <= t_k + h: Integrator._final's release_if_dead, or release if dead at t_k), else
        NEVER: the first substep at whose start its slot is free."""
        free = NEVER
        if death <= self.time_of(plan, steps - 1) + h:  # most particles outlive the launch: one test
            for k in range(k0, steps):
                if free == NEVER and death <= self.time_of(plan, k) + h:
                    free = k + 1
        return free

    @ti.func
    def time_of(self, plan: ti.template(), k):
        """Substep k's start time [s] in the launch's plan."""
        return ti.cast(plan[1 + k, 0], float)

    @ti.func
    def births_of(self, plan: ti.template(), k, e):
        """Emitter e's births at substep k in the launch's plan."""
        return self.int_at(plan, 1 + k, 1 + e)

    @ti.func
    def as_float(self, n):
        """Integer n's bits in a float's place (int_at reads them back)."""
        bits = ti.i32 if ti.static(np_float() == np.float32) else ti.i64
        return ti.bit_cast(ti.cast(n, bits), float)

    @ti.func
    def int_at(self, plan: ti.template(), row, column):
        """The integer whose bits the plan holds at (row, column), in a float's place."""
        bits = ti.i32 if ti.static(np_float() == np.float32) else ti.i64
        return ti.cast(ti.bit_cast(plan[row, column], bits), ti.i32)

    # Emitter.scan reads and takes slots through these two, ctx = (substep, emitter, plan, substeps, h,
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
        # ctx = (k, emitter, plan, steps, h, seed, step0), read in place (an array cannot be assigned).
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
        death = self.time_of(ctx[2], k) + life
        free = self.free_step(death, ctx[2], k, ctx[3], ctx[4])
        self.free_from[slot] = free
        w = slot >> 5
        self.word_bits[w] ^= ti.u32(1) << ti.cast(slot & 31, ti.u32)  # taken (it was free)
        self.word_next[w] = ti.min(self.word_next[w], free)


def packs_apply(model) -> bool:
    """Whether a blocked frame of `model` runs its particles in packs (BlockedFrame.advance_pack): on the
    CPU (a GPU runs lanes as threads already), without trails (a store per substep would keep the
    quiet substeps' loads in the loop), and with colliders whose sdf bounds their distance
    (`path_is_clear` cannot vouch for a mesh's or a moving collider's)."""
    return runtime.backend_name() == "cpu" and model.trail_length == 0 and distances_bound(model.colliders)
