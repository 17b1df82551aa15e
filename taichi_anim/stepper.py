"""The world step: one driver owns what every time-integration method shares — emission, the ordered
list of solvers that correct what the method proposed (sphere contacts, cloth self-contact, a user's;
solvers.py holds their protocol) and the substeps they ask for, trails, time, and what happens when a
step diverges (raise, or roll back and retry) — while a method (integrators/) supplies only its update,
ended by the finish tail (finish.py). Newton separates `solver.step(...)` from its collision pipeline the
same way.

This is the one way to step: `Integrator.step(model, state, dt)` is a shortcut to the Stepper that
`Integrator.stepper_for(model)` keeps."""

import math
import weakref

from . import runtime, stability, validate
from .errors import DivergenceError, ParameterError
from .health import Health
from .integrators.blocked import BlockedFrame
from .integrators.implicit_euler import IntegratorImplicitEuler
from .integrators.parallel_frame import ParallelFrame, parallel_frame_applies
from .solvers import check_solver, make_solvers
from .state import State
from .watchdog import Watchdog

MAX_STABLE_SPLIT = 4096  # the most substeps the retry policy takes from the stability estimate
# A frame of substeps of a fusable method runs as one serial kernel on the CPU below this much work
# (particles + element entries): there a parallel loop costs more than its work (the second core takes
# ~80 us to join a loop here); above it, one parallel launch per substep (benchmarks/results/frame_fusion.md:
# serial frame faster up to 80^2 cloth, 82k work; launches from 96^2, 118k), or, where it applies, the
# parallel frame from FRAME_PARALLEL_FROM (below).
FRAME_SERIAL_BELOW = 100_000
# From this much work, a frame runs in one parallel launch with barriers between its passes where that
# applies (integrators/parallel_frame.py). Warp's cloth benchmark on the 2-core Xeon, ms a frame, serial
# frame against parallel frame, two runs each: 32^2 (work 12,600) 0.77, 0.72 against 0.96, 0.93; 40^2
# (20,000) 1.19, 1.22 against 1.37, 0.98; 48^2 (29,000) 1.80, 1.71 against 1.18, 1.97; 56^2 (39,700)
# 2.15, 2.17 against 1.47, 1.61; 64^2 3.04, 3.02 against 1.88, 1.82 (launches: 3.30).
FRAME_PARALLEL_FROM = 25_000
# None: the parallel frame where it applies from FRAME_PARALLEL_FROM; True: wherever it applies; False:
# never (tests compare the modes).
PARALLEL_FRAME = None


class Stepper:
    """Steps `model`'s states with `integrator`, which is bound to the model here (its scratch fields
    are allocated now, never during a run). `step(state, dt)` advances a state by dt [s] in place.

    `watchdog` holds the divergence bounds (watchdog.py; `stepper.watchdog.configure(...)` overrides
    them). On divergence the policy (`policy.divergence`) decides: "raise" (DivergenceError); "retry":
    roll the state back to the step's start and redo the step in 2, 4, ... substeps, up to
    `policy.max_retries` halvings; "implicit": roll back and redo it with implicit Euler (in 1, 2, ...
    substeps, `max_retries` attempts). Under the recovering policies, and under "raise" with
    `policy.keep_last_good`, a DivergenceError leaves the state at the last good step that was checked
    (with `check_every` = 1, the step before the bad one; with k > 1, the last multiple of k before it):
    positions, velocities, lifetimes, emission, trails, time and step count, bitwise, from a copy taken at
    the start of each checked step (one copy kernel per step, or per frame of fused substeps); without
    it the state holds the step that diverged, and the error says so. A recovery is a
    "divergence_recovered" event in `health`, and the substeps (and method) that worked are kept for the
    following steps until dt changes. With a recovering policy the watchdog is read after every step (the
    rollback point is the step's start), the energy
    (where the scene has one) is evaluated every step (`watchdog.energy_every` = 1; a larger value trades
    recoveries for speed), and the state is saved into a backup State before each step. A rollback
    restores the State (see `State.save`); it does not undo solver-side counters and warm starts
    (adaptive step sizes, a linear solver's previous solution, self-contact statistics), which only
    affect where the next solve starts.

    Values a run carries from step to step belong to its State: time, step count and emission (in the
    State itself), and the solvers' run carry (adaptive step sizes, warm starts, the recovery in force),
    which the Stepper parks in `State.solver_carry` when another State of the model is stepped. The
    health counters are the Stepper's: they report everything it stepped."""

    def __init__(self, model, integrator):
        self.model = model
        self.integrator = integrator
        integrator.bind(model)
        # What the run does when a solver misbehaves, and what it has reported so far (health.py).
        self.policy = integrator.policy
        self.health = Health(self.policy)
        integrator.health = self.health  # solvers inside the method report here
        self._guarded_dt = None  # the step the stability guard last checked
        self._frame_mode = None  # how a frame of substeps is launched (frame_mode), chosen on first use
        self._blocked = None  # the blocked frame's scratch (BlockedFrame), made on its first frame
        self._parallel = None  # the parallel frame's counters (ParallelFrame), made on its first frame
        self._watch_count = None  # the watch's count a frame just read back (_frame), for its own check
        self.watchdog = Watchdog(model)
        # The rollback point (a State saved at the last good checked step, `_keep_good`): recovering
        # policies redo the step from it, and with policy.keep_last_good a DivergenceError leaves the state
        # there. Off by default: the copy is a launch and a memcpy per step, which cost a third of a
        # 10^4-particle step (benchmarks/regression.py). For "implicit", the fallback method too; both
        # made now so that nothing is allocated mid-run.
        recovering = self.policy.divergence != "raise"
        self._recovering = recovering
        self._backup = State(model) if recovering or self.policy.keep_last_good else None
        self._backup_of = None  # weak reference to the State the backup was saved from
        self._fallback = None
        if self.policy.divergence == "implicit":
            self._fallback = IntegratorImplicitEuler(
                collision_mode=integrator.collision_mode, policy=self.policy
            )
            self._fallback.bind(model)
            self._fallback.health = self.health
        self._recovery = None  # (method, substeps) that recovered, kept until dt changes
        # The State whose run carry (adaptive step sizes, warm starts, the recovery in force) the solvers
        # hold now; stepping another State parks it there first (_switch_run).
        self._run_state = None
        self._carry_key = object()  # this Stepper's key in State.solver_carry
        if recovering:
            # A step can store energy (a spring stretched past any stable length) before anything moves
            # fast: only the energy shows it in time to roll back, so it is evaluated every step.
            self.watchdog.energy_every = 1
        # The solvers that correct each substep the method proposes, in order (solvers.py): sphere
        # contacts (a neighbour grid, predictions, sweep buffers), then cloth self- and cloth-cloth
        # contact (hierarchies, pair lists, bounds), each when the scene asked for it; each owns its fields.
        self.solvers = make_solvers(model, integrator)

    def add_solver(self, solver, *, index: int | None = None) -> None:
        """Put `solver` (an object with the hooks of solvers.py's protocol) in the list, at the end or
        before position `index`; it then acts on every substep from the next step on (and frames are
        stepped substep by substep). ParameterError if it lacks a hook."""
        check_solver(solver)
        if index is None:
            self.solvers.append(solver)
        else:
            self.solvers.insert(validate.count("index", index, 0, len(self.solvers)), solver)
        self._frame_mode = None  # fused frames would skip it

    def solver(self, name: str):
        """The first solver in the list called `name`, or None."""
        return next((s for s in self.solvers if s.name == name), None)

    @property
    def contacts(self):
        """The sphere-contact solver (collision/spheres.py), or None when the scene has no sphere
        contacts."""
        return self.solver("sphere contacts")

    @property
    def self_contact(self):
        """The cloth self-contact solver (collision/self_contact.py), or None."""
        return self.solver("self-contact")

    def step(self, state, dt: float, substeps: int = 1) -> None:
        """Advance `state` by dt [s] in `substeps` equal steps of dt / substeps: the same as that many
        calls of step(state, dt / substeps), launched as `frame_mode` says (one kernel for the whole
        frame, one per substep without the per-step Python work, or step by step)."""
        dt = validate.positive("dt", dt)
        n = 1 if type(substeps) is int and substeps == 1 else validate.count("substeps", substeps, 1)
        model = self.model
        if state.model is not model:
            raise ParameterError("state belongs to another model: make it with this model's state()")
        if self._run_state is None or self._run_state() is not state:
            self._switch_run(state)
        if n > 1:
            self.advance(state, dt / n, n)
            return
        if dt != self._guarded_dt:
            if model.particle_count:  # the guard bounds the particles' method
                stability.guard(self, state, dt)
            self._guarded_dt = dt
            self._recovery = None
        if self.watchdog.derived is None:
            speeds = [
                s.separation_speed(model, state, dt) for s in self.solvers if hasattr(s, "separation_speed")
            ]
            if speeds:
                self.watchdog.separation_speed = max(speeds)
        if model.particle_count:  # the watch bounds particles; rigid bodies check themselves (solver check)
            self.watchdog.arm(state, dt)
        if not self._recovering:
            self._keep_good(state)
            try:
                self._step(state, dt, self.integrator, 1)
            except BaseException:  # a solver giving up, Ctrl-C: back to the last good step
                self._roll_back(state)
                raise
            if state.step_count % self.integrator.check_every == 0:
                self.check(state)
            return
        self._keep_good(state, always=True)  # every step: the step's start is the retry point
        method, split = self._recovery or (self.integrator, 1)
        try:
            error = self._attempt(state, dt, method, split)
            if error is not None:
                self._recover(state, dt, error, method, split)
        except BaseException:  # any failure (a solver giving up under "raise", Ctrl-C): the last good state
            state.restore(self._backup)
            raise
        if self.solvers and state.step_count % self.integrator.check_every == 0:
            try:
                self._check_solvers(state)
            except DivergenceError as e:  # a solver's own verdict (a pair list overflowed): the step's start
                raise self._roll_back(state, e) from None

    def advance(self, state, h: float, count: int) -> None:
        """`count` steps of h [s]: the same as `count` calls of step(state, h), launched as frame_mode
        says (a scene's frame: its substeps at its own step, without re-dividing the frame)."""
        h = validate.positive("dt", h)
        count = validate.count("substeps", count, 1)
        mode = self.frame_mode()["mode"]
        if count == 1 or mode == "steps":
            for _ in range(count):
                self.step(state, h)
        else:
            if state.model is not self.model:
                raise ParameterError("state belongs to another model: make it with this model's state()")
            if self._run_state is None or self._run_state() is not state:
                self._switch_run(state)
            self._frame(state, h, count, mode)

    def _switch_run(self, state) -> None:
        """Make `state` the run the solvers carry values for: park the carry of the State stepped before
        (its adaptive step sizes, linear-solver warm starts, the recovery in force) in that State, and
        load `state`'s (a fresh start for a State never stepped here). Two states of one model stepped
        in turn then evolve exactly as each would alone."""
        before = None if self._run_state is None else self._run_state()
        if before is not None:
            before.solver_carry[self._carry_key] = (
                self.integrator.run_carry(),
                None if self._fallback is None else self._fallback.run_carry(),
                self._recovery,
            )
        carry = state.solver_carry.get(self._carry_key)
        method, fallback, self._recovery = (None, None, None) if carry is None else carry
        self.integrator.set_run_carry(method)
        if self._fallback is not None:
            self._fallback.set_run_carry(fallback)
        self._run_state = weakref.ref(state)

    def frame_mode(self) -> dict:
        """How step(state, dt, substeps) launches a frame, and why (recorded in run.json):
        "blocked": one kernel takes each particle through every substep (particles that do not act on
        each other: integrators/blocked.py);
        "serial_frame": one kernel runs every substep, serially (CPU, work below FRAME_SERIAL_BELOW);
        "parallel_frame": one kernel runs every substep on the CPU's workers (one per thread, at most one
        per core), which wait for each other between passes (integrators/parallel_frame.py; work from
        FRAME_PARALLEL_FROM);
        "launches": the method's kernel once per substep with nothing else in between; "steps": the
        full step per substep (what the scene needs between substeps: contacts, moving meshes,
        rollback, a multi-stage method; emission and trails where the particles are coupled or on a
        GPU); "solver_frame": a scene of one solver's bodies only (no particles), which runs the frame
        in one launch itself (its `runs_frames`: rigid bodies with serial contacts)."""
        if self._frame_mode is None:
            self._frame_mode = self._choose_frame_mode()
        return self._frame_mode

    def _choose_frame_mode(self) -> dict:
        model, method = self.model, self.integrator
        on_cpu = runtime.backend_name() == "cpu"
        # Particles that do not act on each other go through a frame one at a time (integrators/
        # blocked.py). Emitters' births are planned in a serial pass: on the CPU only (not measured on GPUs).
        independent = method.fusable and not model.element_terms and not model.attachment_count
        blockable_births = independent and on_cpu
        # A solver that runs frames itself does so only alone, in a scene without particles.
        framer = self.solvers[0] if len(self.solvers) == 1 and not model.particle_count else None
        if framer is not None and not getattr(framer, "runs_frames", lambda m: False)(model):
            framer = None
        needs = [
            why
            for why, present in (
                (f"{method.name} prepares stages between substeps", not method.fusable and framer is None),
                ("emitters", model.emitter_count > 0 and not blockable_births),
                *((s.name, s is not framer) for s in self.solvers),
                ("colliders prepared per step", bool(model._prepared_colliders)),
                ("trails", model.trail_length > 0 and not independent),
                (
                    f"policy divergence={self.policy.divergence!r} (rollback per step)",
                    self._recovering,
                ),
            )
            if present
        ]
        if needs:
            return {"mode": "steps", "reason": "per-step work: " + ", ".join(needs)}
        if framer is not None:
            return {"mode": "solver_frame", "reason": f"{framer.name} only: the frame in one launch"}
        if independent:
            return {
                "mode": "blocked",
                "reason": "particles independent: each one through the frame in registers",
            }
        work = model.work
        wanted = work >= FRAME_PARALLEL_FROM if PARALLEL_FRAME is None else PARALLEL_FRAME
        if wanted and parallel_frame_applies(model, method):
            return {"mode": "parallel_frame", "reason": f"work {work}: one parallel launch on the CPU"}
        if on_cpu and work < FRAME_SERIAL_BELOW:
            return {"mode": "serial_frame", "reason": f"work {work} < {FRAME_SERIAL_BELOW} on the CPU"}
        where = "on the GPU" if not on_cpu else f">= {FRAME_SERIAL_BELOW} on the CPU"
        return {"mode": "launches", "reason": f"work {work} {where}"}

    def _frame(self, state, h: float, n: int, mode: str) -> None:
        """n substeps of h without the per-step Python work (frame_mode): the stability guard, the
        watchdog's bounds for the whole frame, the method's kernel(s), then time, counters and the
        divergence check as n calls of step(state, h) would leave them."""
        model = self.model
        if h != self._guarded_dt:
            if model.particle_count:  # as in step: the guard bounds the particles' method
                stability.guard(self, state, h)
            self._guarded_dt = h
            self._recovery = None
        if model.particle_count:
            self.watchdog.arm(state, h * n)
        self._keep_good(state, frame=True)
        method = self.integrator
        first = state.step_count
        try:
            if mode == "launches":  # one launch per substep, each at its own time
                x, v = state.particle_x, state.particle_v
                for k in range(n):
                    t = state.time
                    method._final(model, state, x, v, x, v, t, t, h, first + k + 1, True)
                    state.time += h
            else:
                if mode == "solver_frame":
                    self.solvers[0].frame(model, state, h, n)
                elif mode == "parallel_frame":
                    if self._parallel is None:
                        self._parallel = ParallelFrame(model, method)
                    self._parallel.run(state, h, n, first + 1)
                elif mode == "blocked":
                    if self._blocked is None:
                        self._blocked = BlockedFrame(model, method)
                    self._blocked.run(state, h, n)
                    if state.trail_length:
                        state.trail_head = (state.trail_head + n) % state.trail_length
                else:
                    method._frame(model, state, state.time, h, n, first + 1)
                for _ in range(n):  # added step by step, as n calls of step(state, h) would
                    state.time += h
            if mode != "solver_frame":  # the bodies' solver steps without the particles' method
                method.evaluations += method.stages * n
        except BaseException:  # Ctrl-C between a frame's launches: back to the frame's start, as step does
            self._roll_back(state)
            raise
        state.step_count += n
        every = method.check_every
        # A solver's frame stops at a step that overflowed or diverged, leaving the rest undone: it is
        # read after every frame, whatever check_every says.
        if (state.step_count // every) > (first // every) or mode == "solver_frame":
            # The blocked launch wrote the watch's count into its plan: this check reads that instead
            # of the field (a launch); only this check, right after the frame that wrote it.
            self._watch_count = self._blocked.watch_count if mode == "blocked" else None
            try:
                self.check(state)
            finally:
                self._watch_count = None

    def check(self, state, *, energy: bool = False) -> None:
        """Read the divergence watch now (a device sync): raises DivergenceError if a step so far
        diverged (non-finite or out-of-bounds particles; energy growth, evaluated every
        `watchdog.energy_every` steps, or now with energy=True). The runner calls it with energy=True
        before exporting a frame, so nothing after a bad step is written. On an error the state is first
        rolled back to the last good checked step (`_roll_back`) where a copy is kept
        (`policy.keep_last_good`, or a recovering policy)."""
        error = self._divergence(state) or self.watchdog.energy_error(state, now=energy)
        if error is None:
            try:
                self._check_solvers(state)
            except DivergenceError as e:  # a solver's own verdict (a pair list overflowed)
                error = e
        if error is not None:
            raise self._roll_back(state, error)

    def _check_solvers(self, state) -> None:
        """Each solver's `check` (its statistics), in list order; a DivergenceError propagates."""
        for s in self.solvers:
            s.check(state)

    def _keep_good(self, state, *, always: bool = False, frame: bool = False) -> None:
        """Save `state` as the rollback point when it is at a checked step (a multiple of
        `check_every`, whose watch was read and found good), or when it is not the State saved last (its
        first step here; `always`: every step, for the recovering policies; `frame`: before a fused frame,
        whose substeps write several trail columns). One copy kernel: positions, velocities, lifetimes,
        emission and trails (State.save), a memcpy of the state's fields."""
        if self._backup is None:
            return
        every = 1 if always else self.integrator.check_every
        saved = None if self._backup_of is None else self._backup_of()
        if saved is not state or state.step_count % every == 0:
            # With check_every > 1 several steps may pass before a rollback: every trail column is kept; so
            # does the first save of a state (the backup's columns were never written: a rollback within
            # the trail's length would put them back).
            state.save(self._backup, whole_trail=every > 1 or frame or saved is not state)
            self._backup_of = weakref.ref(state)

    def _roll_back(self, state, error=None):
        """Return `state` to the rollback point (the last good checked step: its positions,
        velocities, lifetimes, emission, trails, time and step count; the watch cleared) and give
        `error` with that said in its message (None: just roll back). Solver-side carries (adaptive
        step sizes, warm starts) are not undone: they only choose where the next solve starts."""
        saved = None if self._backup_of is None else self._backup_of()
        if saved is state:
            state.restore(self._backup)
        if error is None:
            return None
        if saved is state:
            where = (
                f"the state is left at the last good step checked, step {state.step_count} "
                f"(t = {state.time:.6g} s)"
            )
        elif self._backup is None:
            where = (
                "the state holds the step that diverged (Policy(keep_last_good=True) keeps the last good "
                "step, at the cost of a state copy per step)"
            )
        else:
            where = "the state could not be rolled back (it was never stepped by this stepper)"
        return DivergenceError(
            f"{error}; {where}",
            step=error.step,
            particle=error.particle,
            quantity=error.quantity,
            value=error.value,
        )

    def _divergence(self, state):
        """The DivergenceError the state's watch recorded, or None (one counter read; none without
        particles, the only thing the watch counts: rigid bodies check themselves, 5 us a step saved)."""
        if not self.model.particle_count:
            return None
        count = self._watch_count
        if count is None:
            count = int(state.nonfinite_count[None])
        return None if count == 0 else self.watchdog.error(state, count)

    def _attempt(self, state, dt: float, method, split: int):
        """Step with `method` in `split` substeps and read the watch (and the energy, when due): the
        DivergenceError, or None."""
        try:
            self._step(state, dt, method, split)
        except DivergenceError as e:  # a method's own verdict (step-size underflow)
            return e
        return self._divergence(state) or self.watchdog.energy_error(state)

    def _recover(self, state, dt: float, error, method, split: int) -> None:
        """Roll back and redo the step as the policy says; raise if no attempt recovers (the state is
        then left at the step's start, the last good state)."""
        policy = self.policy
        if policy.divergence == "retry":
            attempts = [(self.integrator, 2**r) for r in range(1, policy.max_retries + 1)]
            stable = self._stable_split(dt)
            if stable is not None and stable > attempts[-1][1]:
                attempts.append((self.integrator, stable))  # what the stability guard says is enough
        else:
            attempts = [(self._fallback, 2**r) for r in range(policy.max_retries)]
        tried = [(m, n) for m, n in attempts if m is not method or n > split]
        if method is self._fallback:  # the fallback already failed at `split`: only more substeps
            tried = [(m, n) for m, n in tried if n > split]
        first = error
        for m, n in tried:
            state.restore(self._backup)
            self.health.count("divergence_attempts")
            if self._attempt(state, dt, m, n) is None:
                self._recovery = (m, n)
                self.health.event(
                    "divergence_recovered",
                    state.step_count,
                    f"step {state.step_count} redone with {m.name} in {n} substep(s) after: {first}",
                    policy=policy.divergence,
                    method=m.name,
                    substeps=n,
                    quantity=first.quantity,
                    particle=first.particle,
                    value=first.value,
                )
                return
        state.restore(self._backup)
        raise DivergenceError(
            f"{first} -- not recovered by policy divergence={policy.divergence!r} after {len(tried)} "
            f"attempt(s) (up to {tried[-1][1] if tried else split} substeps); the state is left at the "
            f"step's start",
            step=first.step,
            particle=first.particle,
            quantity=first.quantity,
            value=first.value,
        )

    def _stable_split(self, dt: float) -> int | None:
        """Substeps within the stability limit the guard estimated for this model (None if it made no
        estimate or the method has no limit)."""
        cached = getattr(self, "stability_limit", None)
        limit = None if cached is None else cached[1]
        if not limit or not math.isfinite(limit):
            return None
        return min(math.ceil(dt / (stability.AUTO_SAFETY * limit)), MAX_STABLE_SPLIT)

    def _step(self, state, dt: float, method, split: int) -> None:
        """Emission, the method's advance in substeps (the most any solver asks for, times `split`),
        each corrected by the solvers, trails, time."""
        model = self.model
        if model.emitter_count:
            model.emit(state, dt)
        solvers = self.solvers
        # Continuous sphere contacts choose their substeps from v_max; the others ask for none.
        n = split * max((s.substeps(model, state, dt) for s in solvers), default=1)
        h = dt / n
        t0 = state.time
        for k in range(n):
            state.time = t0 + k * h
            model.prepare_colliders(state.time, h)
            self._advance(state, h, method, solvers)
        state.time = t0
        if state.trail_length:
            state.record_trails(state.trail_head)
            state.trail_head = (state.trail_head + 1) % state.trail_length
        state.time += dt
        state.step_count += 1

    def _advance(self, state, h: float, method, solvers) -> None:
        """The method's step by h, then each solver on the result in list order (Gauss-Seidel: each
        reads what the ones before it wrote; self-contact is last, nothing may move a cloth vertex after
        its guard)."""
        model = self.model
        for s in solvers:
            s.before_substep(model, state, h)
        if model.particle_count:  # a scene of rigid bodies only compiles and runs no particle kernel
            method.advance_step(model, state, h)
        for s in solvers:
            s.after_substep(model, state, h, state.step_count + 1)
