"""The world step: one driver owns what every time-integration method shares — emission, sphere
contacts and their substeps, the finish tail of a step (alive check, colliders, the divergence watch,
release of dead slots), trails, time — while a method (integrators/) supplies only its update.
Newton separates `solver.step(...)` from its collision pipeline the same way."""

import taichi as ti

from . import stability, validate
from .collision import collide
from .collision.motion import follow_attachments
from .collision.self_contact import SelfContact
from .collision.spheres import ContactSpheres
from .errors import ParameterError
from .health import Health


@ti.func
def finish_particle(
    model: ti.template(), state: ti.template(), mode: ti.template(), i, x0, v0, x1, v1, t, h, step
):
    """The end of a step [t, t + h] for particle i, fused into a method's last kernel: colliders against
    the step's start point (x0, v0), attached particles onto their targets, a count of non-finite results
    for the divergence watch, and the write."""
    x, v = x1, v1
    if ti.static(model.collider_count > 0):
        x, v = collide(model.colliders, mode, x0, v0, x1, v1, t, h, model.radius(i), model.rest_speed)
    if ti.static(model.attachment_count > 0):
        x, v = follow_attachments(model.attachments, model.particle_attachment, i, x0, x, v, t + h, h)
    total = x.sum() + v.sum()  # NaN or inf in any component makes the sum NaN or inf
    if ti.math.isnan(total) or ti.math.isinf(total):
        ti.atomic_add(state.nonfinite_count[None], 1)
        ti.atomic_min(state.nonfinite_step[None], step)
    state.particle_x[i] = x
    state.particle_v[i] = v


class Stepper:
    """Steps `model`'s states with `integrator`, which is bound to the model here (its scratch fields
    are allocated now, never during a run). `step(state, dt)` advances a state by dt [s] in place."""

    def __init__(self, model, integrator):
        self.model = model
        self.integrator = integrator
        integrator.bind(model)
        # What the run does when a solver misbehaves, and what it has reported so far (health.py).
        self.policy = integrator.policy
        self.health = Health(self.policy)
        integrator.health = self.health  # solvers inside the method report here
        self._guarded_dt = None  # the step the stability guard last checked
        # The sphere-contact solver (its neighbour grid, predictions and sweep buffers), when the scene
        # has sphere contacts.
        opts = model.sphere_contacts
        self.contacts = None if opts is None else ContactSpheres(model, **opts)
        # Cloth self- and cloth-cloth contact (its hierarchies, pair lists and bounds), when asked for.
        opts = model.self_contact
        self.self_contact = None if opts is None else SelfContact(model, **opts)

    def step(self, state, dt: float) -> None:
        dt = validate.positive("dt", dt)
        model, method = self.model, self.integrator
        if state.model is not model:
            raise ParameterError("state belongs to another model: make it with this model's state()")
        if dt != self._guarded_dt:
            stability.guard(self, state, dt)
            self._guarded_dt = dt
        if model.emitter_count:
            model.emit(state, dt)
        contacts = self.contacts
        if contacts is None:
            model.prepare_colliders(state.time, dt)
            self._advance(state, dt)
        else:
            # Sphere contacts after every (sub)step; continuous contacts choose substeps from v_max.
            n = contacts.substeps(model, state, dt)
            h = dt / n
            t0 = state.time
            for k in range(n):
                state.time = t0 + k * h
                model.prepare_colliders(state.time, h)
                self._advance(state, h, contacts)
            state.time = t0
        if state.trail_length:
            state.record_trails(state.trail_head)
            state.trail_head = (state.trail_head + 1) % state.trail_length
        state.time += dt
        state.step_count += 1
        if state.step_count % method.check_every == 0:
            self.check(state)

    def check(self, state) -> None:
        """Read the divergence watch now (a device sync): raises DivergenceError if a step so far
        diverged. The runner calls it before exporting a frame, so nothing after a bad step is written."""
        state.check_finite()
        if self.self_contact is not None:
            self.self_contact.read_stats()

    def _advance(self, state, h: float, contacts=None) -> None:
        """The method's step by h, sphere contacts, then cloth self-contact on the result (last: nothing
        may move a cloth vertex after its guard)."""
        sc = self.self_contact
        if sc is not None:
            sc.begin(self.model, state)
        self.integrator.advance_step(self.model, state, h)
        if contacts is not None:
            contacts.solve(self.model, state, h, state.step_count + 1)
        if sc is not None:
            sc.solve(self.model, state, h)
