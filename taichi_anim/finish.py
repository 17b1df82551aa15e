"""The finish tail of a particle's step, fused into each method's last kernel (integrators/base.py):
colliders against the step's start point, attachments onto their targets, the divergence watchdog, and
the write. One place, so every method ends a step the same way whatever its update."""

import taichi as ti

from .collision import collide
from .collision.motion import follow_attachments
from .watchdog import watch_against, watch_limits


@ti.func
def finish_particle(
    model: ti.template(), state: ti.template(), mode: ti.template(), i, x0, v0, x1, v1, t, h, step
):
    """`finished`, written to particle i of the state."""
    x, v = finished(model, state, mode, i, x0, v0, x1, v1, t, h, step, watch_limits(state))
    state.particle_x[i] = x
    state.particle_v[i] = v


@ti.func
def finished(
    model: ti.template(), state: ti.template(), mode: ti.template(), i, x0, v0, x1, v1, t, h, step, lim
):
    """The end of a step [t, t + h] for particle i, fused into a method's last kernel: colliders against
    the step's start point (x0, v0), attached particles onto their targets, the divergence watchdog
    (non-finite or out-of-bounds results against the bounds `lim`, watchdog.watch_limits); returns the
    end-of-step (x, v).

    Pinned particles (mass 0) are kinematic, as in Blender, Houdini Vellum and Newton: colliders never
    move them, even one placed inside a collider (State.set_positions); they go only where their
    velocity or their attachment's target takes them."""
    x, v = x1, v1
    # Not for the liquid: its walls are boundary samples in its pressure solve, and its last guard
    # (bodies/fluid/dfsph.py, _finish) sets each liquid particle's end position from the solve, half a
    # spacing off every collider, removing the velocity into it. A swept test here only changed the
    # velocity the solve starts from, and in a scene of liquid alone it compiled every collider's test
    # into the step (the pour demo's glass: a mesh's tree walk).
    if ti.static(model.collider_count > 0 and not model.all_liquid):
        if model.inv_mass(i) > 0.0 and not model.liquid(i):
            x, v = collide(model.colliders, mode, x0, v0, x1, v1, t, h, model.radius(i), model.rest_speed)
    if ti.static(model.attachment_count > 0):
        x, v = follow_attachments(model.attachments, model.particle_attachment, i, x0, x, v, t + h, h)
    watch_against(state, lim, i, x, v, step)
    return x, v
