"""Integrator base: one `step(model, state, dt)` for every method — emission, the method's own update,
collisions and the divergence watch fused into its last kernel, trails, time.

Every method implements `advance(model, state, xi, vi, xo, vo, ta, t, h, step, finish)`: one step of
size h of x' = v, v' = M^-1 f(x, v, t) from fields (xi, vi) to (xo, vo) (they may alias). With
finish=True the last kernel also applies collisions against the step's start point and counts
non-finite results; adaptive wrappers call it with finish=False on scratch fields.
"""

import taichi as ti

from .. import validate
from ..collision import CollisionMode, collide
from ..runtime import data_oriented


def _mode(value) -> CollisionMode:
    if isinstance(value, CollisionMode):
        return value
    validate.choice("collision_mode", value, [m.value for m in CollisionMode])
    return CollisionMode(value)


@data_oriented
class Integrator:
    """Base class. Options: collision_mode ("projection" | "backward"); check_every: read the
    divergence counter every this many steps (each read synchronises with the device)."""

    name = "base"
    order = 0
    stages = 1  # force evaluations per advance

    def __init__(
        self, *, collision_mode: CollisionMode | str = CollisionMode.PROJECTION, check_every: int = 1
    ):
        self.collision_mode = _mode(collision_mode)
        self.check_every = validate.count("check_every", check_every, 1)
        self.evaluations = 0  # force evaluations per particle so far (the cost figure in benchmarks)

    def settings(self) -> dict:
        return {"integrator": self.name, "order": self.order, "collision_mode": self.collision_mode.value}

    def step(self, model, state, dt: float) -> None:
        """Advance `state` by dt [s] in place."""
        dt = validate.positive("dt", dt)
        if model.emitter_count:
            model.emit(state, dt)
        contacts = model.contacts
        if contacts is None:
            self._step(model, state, dt)
        else:
            # Sphere contacts after every (sub)step; continuous contacts choose substeps from v_max.
            n = contacts.substeps(state, dt)
            h = dt / n
            t0 = state.time
            for k in range(n):
                state.time = t0 + k * h
                self._step(model, state, h)
                contacts.solve(state, h, state.step_count + 1)
            state.time = t0
        if state.trail_length:
            state.record_trails(state.trail_head)
            state.trail_head = (state.trail_head + 1) % state.trail_length
        state.time += dt
        state.step_count += 1
        if state.step_count % self.check_every == 0:
            state.check_finite()

    def _step(self, model, state, dt: float) -> None:
        x, v = state.particle_x, state.particle_v
        self.advance(model, state, x, v, x, v, state.time, state.time, dt, state.step_count + 1, True)

    def advance(self, model, state, xi, vi, xo, vo, ta, t, h, step, finish) -> None:
        raise NotImplementedError

    @ti.func
    def _write(
        self,
        model: ti.template(),
        state: ti.template(),
        xo: ti.template(),
        vo: ti.template(),
        i,
        x0,
        v0,
        x1,
        v1,
        h,
        step,
        finish: ti.template(),
    ):
        if ti.static(finish):
            self._finish(model, state, i, x0, v0, x1, v1, h, step)
        else:
            xo[i] = x1
            vo[i] = v1

    @ti.func
    def _finish(self, model: ti.template(), state: ti.template(), i, x0, v0, x1, v1, h, step):
        x, v = x1, v1
        if ti.static(model.collider_count > 0):
            x, v = collide(
                model.colliders, self.collision_mode, x0, v0, x1, v1, h, model.radius(i), model.rest_speed
            )
        total = x.sum() + v.sum()  # NaN or inf in any component makes the sum NaN or inf
        if ti.math.isnan(total) or ti.math.isinf(total):
            ti.atomic_add(state.nonfinite_count[None], 1)
            ti.atomic_min(state.nonfinite_step[None], step)
        state.particle_x[i] = x
        state.particle_v[i] = v

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
        for i in range(model.particle_count):
            if model.alive(state, i, ta):
                self._finish(
                    model, state, i, state.particle_x[i], state.particle_v[i], x1f[i], v1f[i], h, step
                )
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
        for i in range(model.particle_count):
            if model.alive(state, i, ta):
                xd[i] = xs[i]
                vd[i] = vs[i]


class Scratch:
    """Pairs of (x, v) fields sized to a model, allocated on first use."""

    def __init__(self, pairs: int):
        self.pairs = pairs
        self.count = -1
        self.x: list = []
        self.v: list = []

    def ensure(self, n: int) -> None:
        if n != self.count:
            self.x = [ti.Vector.field(3, float, n) for _ in range(self.pairs)]
            self.v = [ti.Vector.field(3, float, n) for _ in range(self.pairs)]
            self.count = n
