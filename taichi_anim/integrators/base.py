"""Integrator base: a time-integration method supplies only its update; the world step around it
(emission, contacts, trails, time, divergence) is the Stepper's (stepper.py).

A method is bound to a model once (`bind`, which allocates its scratch: element-term caches, stage
fields, linear-solver vectors) and then advances fields (xi, vi) to (xo, vo) by h with
`advance(model, state, xi, vi, xo, vo, ta, t, h, step, finish)`, as:
  prepare(...)        Python-side launches the update needs first (Runge-Kutta stages, a linear solve)
  final_pass(...)     @ti.func: top-level loops that must run before the particle loop (element passes)
  update(...)         @ti.func: (x1, v1) of particle i
One kernel, `_final`, runs the last two for every method, and with finish=True ends each particle with
the Stepper's finish tail (colliders, divergence watch, slot release); adaptive wrappers call it with
finish=False on scratch fields and finish once at the end of the step (`_finish_all`).
"""

from typing import TYPE_CHECKING

import taichi as ti

from .. import validate
from ..collision import CollisionMode
from ..finish import finish_particle
from ..health import Health, make_policy
from ..runtime import compile_with, data_oriented
from ..stability import StabilityRegion, check_integrator

if TYPE_CHECKING:
    from ..stepper import Stepper


def _mode(value) -> CollisionMode:
    if isinstance(value, CollisionMode):
        return value
    validate.choice("collision_mode", value, [m.value for m in CollisionMode])
    return CollisionMode(value)


@data_oriented
class Integrator:
    """Base class. Options: collision_mode ("projection" | "backward"); check_every: read the
    divergence counter every this many steps (each read synchronises with the device); policy: what the
    run does on non-convergence, instability and divergence (health.Policy, or a dict of its fields)."""

    name = "base"
    order = 0
    stages = 1  # force evaluations per advance
    implicit = False  # whether element caches hold linearisations (implicit solves)
    own_caches = True  # False for wrappers whose inner method evaluates the terms
    # Whether a frame of substeps can run as one kernel: single-stage methods whose advance is the final
    # kernel alone (no Python-side preparation between substeps).
    fusable = False
    # What the stability guard bounds its step by (stability.py); a method without one is refused at bind.
    stability_region: StabilityRegion | None = None
    # How rigid bodies are stepped with this method (bodies/rigid/dynamics.py): an explicit Runge-Kutta
    # Tableau or "semi_implicit"; None: the method cannot step them (refused when a scene has bodies).
    rigid_scheme = None

    def __init__(
        self,
        *,
        collision_mode: CollisionMode | str = CollisionMode.PROJECTION,
        check_every: int = 1,
        policy=None,
    ):
        self.collision_mode = _mode(collision_mode)
        self.policy = make_policy(policy)
        self.health = Health(self.policy)  # replaced by the Stepper's when one binds this integrator
        self.check_every = validate.count("check_every", check_every, 1)
        self.evaluations = 0  # force evaluations per particle so far (the cost figure in benchmarks)
        self.model = None
        self.caches = ()
        self._stepper = None

    def settings(self) -> dict:
        """The method's name, order and collision mode (and subclasses' options), for run.json."""
        return {"integrator": self.name, "order": self.order, "collision_mode": self.collision_mode.value}

    def bind(self, model) -> None:
        """Allocate this method's scratch for `model` (called by the Stepper, once per model)."""
        if model is self.model:
            return
        check_integrator(self)
        self.model = model
        self.caches = model.make_caches(implicit=self.implicit) if self.own_caches else ()
        self._allocate(model)

    def _allocate(self, model) -> None:
        """Subclasses allocate their own fields here."""

    def run_carry(self) -> dict:
        """Values this method carries from one step of a run to the next (an adaptive method's next step
        size, a linear solver's warm start). The Stepper parks them in the State they belong to when it
        switches to another State, so states of one model stepped in turn evolve independently."""
        return {}

    def set_run_carry(self, carry: dict | None) -> None:
        """Load values saved by run_carry, or start afresh (None: a State this method never stepped)."""

    def step(self, model, state, dt: float, substeps: int = 1) -> None:
        """A shortcut for `stepper_for(model).step(state, dt, substeps)`: the Stepper is the one way to
        step (stepper.py); this delegates to the one this integrator keeps for `model`."""
        self.stepper_for(model).step(state, dt, substeps)

    def stepper_for(self, model) -> "Stepper":
        """The Stepper this integrator steps `model` with (made, and the integrator bound, on first use;
        `stepper_for(model).solvers` is its ordered list of contact solvers)."""
        # Imported here, not at the top: the Stepper makes integrators (its implicit fallback) and an
        # integrator makes its Stepper, so one of the two modules must import the other late.
        # cycle: stepper.py imports integrators/implicit_euler.py, which imports this module
        from ..stepper import Stepper

        if self._stepper is None or self._stepper.model is not model:
            self._stepper = Stepper(model, self)
        return self._stepper

    def advance_step(self, model, state, dt: float) -> None:
        """One step of the state by dt, finished (adaptive methods take several internal steps)."""
        x, v = state.particle_x, state.particle_v
        self.advance(model, state, x, v, x, v, state.time, state.time, dt, state.step_count + 1, True)

    def advance(self, model, state, xi, vi, xo, vo, ta, t, h, step, finish) -> None:
        """One step of h [s] from fields (xi, vi) at time t into (xo, vo): the preparing launches, then the
        final kernel (finished with colliders and the divergence watch when `finish`); `step` numbers it
        for reports and `ta` is the state's time at the start of the outer step."""
        self.prepare(model, state, xi, vi, ta, t, h)
        self._final(model, state, xi, vi, xo, vo, ta, t, h, step, finish)
        self.evaluations += self.stages

    def prepare(self, model, state, xi, vi, ta, t, h) -> None:
        """Launches that must precede the final kernel (none for one-stage explicit methods)."""

    @ti.func
    def final_pass(self, model: ti.template(), xi: ti.template(), vi: ti.template(), t, h):
        """Element passes the update reads (default: forces at the step's start)."""
        model.element_pass(self.caches, xi, vi, t)

    # The fused step inlines every collider's swept test: Taichi's CFG passes took most of its compile
    # (fountain 10.6 -> 4.7 s, moving_mesh 27.5 -> 10.1 s cold); per frame the fountain did not change
    # and moving_mesh ran ~1 % slower (benchmarks/results/compile_cold_warm_subset.md: +3 % in all).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _final(
        self,
        model: ti.template(),
        state: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        xo: ti.template(),
        vo: ti.template(),
        ta: float,
        t: float,
        h: float,
        step: ti.i32,
        finish: ti.template(),
    ):
        self.final_pass(model, xi, vi, t, h)  # reads the whole start state before anything is overwritten
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            self.final_particle(model, state, xi, vi, xo, vo, ta, t, h, step, finish, i)

    @ti.func
    def final_particle(self, model: ti.template(), state: ti.template(), xi: ti.template(),
                       vi: ti.template(), xo: ti.template(), vo: ti.template(), ta, t, h, step,
                       finish: ti.template(), i):  # fmt: skip
        """Particle i's part of `_final`: its update from (xi, vi), finished or written to (xo, vo)."""
        if model.alive(state, i, ta):
            x0 = xi[i]
            v0 = vi[i]
            x1, v1 = self.update(model, i, x0, v0, t, h)
            if ti.static(finish):
                finish_particle(model, state, self.collision_mode, i, x0, v0, x1, v1, t, h, step)
                if ti.static(state.has_lifetimes):
                    model.release_if_dead(state, i, ta + h)  # dies within this step
            else:
                xo[i] = x1
                vo[i] = v1
        elif ti.static(finish and state.has_lifetimes):
            model.release(state, i)

    @ti.kernel
    def _frame(
        self, model: ti.template(), state: ti.template(), t0: float, h: float, count: ti.i32, step0: ti.i32
    ):
        """`count` steps of h from t0 in one launch, all loops serial (fusable methods on small models on
        the CPU, where a launch costs more than the work; Stepper.frame_mode). The same per-particle
        arithmetic as `_final` with finish=True, so results are bitwise those of `count` launches for
        forces that do not depend on time (t is t0 + k h here, accumulated in Python there)."""
        x, v = ti.static(state.particle_x, state.particle_v)
        ti.loop_config(serialize=True)
        for k in range(count):
            t = t0 + k * h
            self.final_pass(model, x, v, t, h)
            for i in range(model.live_particles()):
                x0 = x[i]
                v0 = v[i]
                x1, v1 = self.update(model, i, x0, v0, t, h)
                finish_particle(model, state, self.collision_mode, i, x0, v0, x1, v1, t, h, step0 + k)

    @ti.kernel
    def _finish_all(
        self,
        model: ti.template(),
        state: ti.template(),
        x1f: ti.template(),
        v1f: ti.template(),
        ta: float,
        h: float,
        step: ti.i32,
    ):
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            if model.alive(state, i, ta):
                x0, v0 = state.particle_x[i], state.particle_v[i]
                finish_particle(model, state, self.collision_mode, i, x0, v0, x1f[i], v1f[i], ta, h, step)
                if ti.static(state.has_lifetimes):
                    model.release_if_dead(state, i, ta + h)
            elif ti.static(state.has_lifetimes):
                model.release(state, i)

    @ti.kernel
    def _copy(
        self,
        model: ti.template(),
        state: ti.template(),
        xs: ti.template(),
        vs: ti.template(),
        xd: ti.template(),
        vd: ti.template(),
        ta: float,
    ):
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            if model.alive(state, i, ta):
                xd[i] = xs[i]
                vd[i] = vs[i]


def scratch_pairs(model, owner, pairs: int) -> tuple[list, list]:
    """`pairs` (x, v) particle field pairs for `owner` (adaptive methods' work and candidate states)."""
    return (
        [model.particle_array(owner, f"scratch_x{k}", dims=(3,)) for k in range(pairs)],
        [model.particle_array(owner, f"scratch_v{k}", dims=(3,)) for k in range(pairs)],
    )
