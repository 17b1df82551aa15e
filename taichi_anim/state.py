"""State: what changes each step — every body kind's dynamic arrays (bodies/: the particles' positions,
velocities, birth and death times, trails), time and step count, the divergence watch and the solvers'
run carry. Fields exist only for the parts the model has."""

import math

import taichi as ti

from .bodies import KINDS, STATE_PARTS
from .bodies.particles import ALIVE_FOREVER, ParticleSnapshot, particle_colors
from .errors import DivergenceError
from .runtime import data_oriented
from .watchdog import NO_INDEX, bounds_compiled

__all__ = ["ALIVE_FOREVER", "ParticleSnapshot", "State", "particle_colors"]


# One launch instead of a Python-scope write per field: each such write runs its field's own writer
# kernel (one per component of a vector field), which every new Taichi program compiles or loads again
# (15-40 ms each here): fourteen per State, and a test builds several states.
@ti.kernel
def _clear_watch(state: ti.template(), limits: ti.template()):
    """Clear the divergence record; with `limits`, also open the watchdog's limits to +-inf."""
    state.nonfinite_count[None] = 0
    state.nonfinite_step[None] = NO_INDEX
    state.watch_particle[None] = NO_INDEX
    state.watch_claim[None] = 0
    state.watch_record[None] = ti.Vector([0, 0, 0])
    if ti.static(limits):
        inf = ti.math.inf
        state.watch_limit[None] = ti.Vector([-inf, -inf, -inf, inf, inf, inf, inf], dt=float)


@data_oriented
class State(*STATE_PARTS):
    """Dynamic data of a Model: each body kind's arrays (the particles': particle_x, particle_v (N,3);
    particle_birth/death (N,) [s] when the model has emitters; trail (N,K,3) ring buffer when trails are
    on), with the kind's NumPy access and snapshot.

    A State holds everything a run changes, so several states of one model (a rollback copy, a
    parameter sweep) evolve independently: time [s] and step_count, positions and velocities, births and
    deaths, emission (each emitter's fractional particle carried to the next step and its free-slot
    cursor), trails, the divergence watch, and `solver_carry` (the solvers' adaptive step sizes and
    warm starts for this run, parked here by the Stepper when it steps another State).

    Read and edit it from NumPy with positions(), velocities(), set_positions(), set_velocities();
    index i is the model's particle i (a cloth grid's vertex (i, j) is j * nx + i, in builder order)."""

    def __init__(self, model):
        self.model = model
        self.time = 0.0
        self.step_count = 0
        for kind in KINDS:
            kind.init_state(self, model)
        self.solver_carry = {}  # per Stepper: its solvers' carry for this run (Stepper._switch_run)
        # Divergence watch (watchdog.py): particle-steps that ended non-finite or out of the watchdog's
        # bounds, the first such step, its lowest particle index, one consistent (step, particle, quantity
        # code) record with its value, and the limits the kernel tests against (written by the Stepper's
        # Watchdog when they change). The names keep "nonfinite" for the solvers that count into them.
        self.watch_bounds = bounds_compiled()  # compile-time: TAICHI_ANIM_WATCHDOG_BOUNDS=0 leaves them out
        watch = model.new_field  # pooled under capacity buckets, like every array of the state
        self.nonfinite_count = watch(self, "nonfinite_count", ti.i32, ())
        self.nonfinite_step = watch(self, "nonfinite_step", ti.i32, ())
        self.watch_particle = watch(self, "watch_particle", ti.i32, ())
        self.watch_claim = watch(self, "watch_claim", ti.i32, ())
        self.watch_record = watch(self, "watch_record", ti.i32, (), (3,))
        self.watch_value = watch(self, "watch_value", float, ())
        self.watch_limit = watch(self, "watch_limit", float, (), (7,))
        self.watch_bounds_now = None  # (lo, hi, speed) the field holds, for messages
        self.watch_version = -1
        self.watch_until = -math.inf  # [s] end of the window the field's limits were written for
        self.energy_start = None  # [J] at the first step the watchdog saw (scenes with an energy)
        self.energy_step = 0  # step of the last energy evaluation
        _clear_watch(self, True)

    def watch_reset(self) -> None:
        """Clear the divergence record (after a rollback)."""
        _clear_watch(self, False)

    def save(self, into: "State", *, whole_trail: bool = False) -> None:
        """Copy everything a step changes into `into`, a State of the same model: every kind's arrays
        (the particles': positions, velocities, birth and death times, free-slot bits, emitter cursors
        and carries, the trail column the next step writes, every column with whole_trail: for a
        rollback over several steps, the trail head; one kernel launch per kind), time and step count."""
        for kind in KINDS:
            kind.save_state(self, into, whole_trail)
        into.time, into.step_count = self.time, self.step_count
        into.energy_start, into.energy_step = self.energy_start, self.energy_step

    def restore(self, source: "State") -> None:
        """Return to the state saved in `source` (filled by `self.save(source)`) and clear the
        divergence record (every trail column is copied: a rollback may span several steps)."""
        source.save(self, whole_trail=True)
        self.watch_reset()

    def check_finite(self) -> None:
        """Raise DivergenceError if any step so far produced a non-finite or out-of-bounds position or
        velocity (the Stepper's `check` names the particle, quantity and value)."""
        bad = int(self.nonfinite_count[None])
        if bad:
            step = int(self.nonfinite_step[None])
            raise DivergenceError(
                f"simulation diverged at step {step}: {bad} particle-step(s) got a non-finite or "
                f"out-of-bounds position or velocity (check dt, stiffness and the integrator's stability "
                f"limit); stopping before anything is exported",
                step=step,
            )
