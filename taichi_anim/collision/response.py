"""Collision response for particles against static colliders (Witkin & Baraff course notes,
"Particle dynamics", collisions: v_n -> -e v_n, tangential velocity reduced by Coulomb friction).

`collide` runs after the integrator has produced the end-of-step state; PROJECTION moves the end point to
the surface, BACKWARD re-walks the step's segment (backward search to the time of impact).
"""

import taichi as ti

from .colliders import NO_HIT, CollisionMode

MAX_HITS = 4  # impacts resolved per particle and step in BACKWARD mode (corners need two or three)


@ti.func
def respond(v, n, restitution, friction):
    """Velocity after an impact with a surface of outward normal n (unchanged if separating)."""
    vn = v.dot(n)
    out = v
    if vn < 0.0:
        v_normal = vn * n
        v_tangent = v - v_normal
        # Coulomb: the tangential impulse is at most mu times the normal impulse (1 + e)|v_n|.
        vt = v_tangent.norm()
        keep = ti.max(1.0 - friction * (1.0 + restitution) * (-vn) / ti.max(vt, 1e-12), 0.0)
        out = keep * v_tangent - restitution * v_normal
    return out


@ti.func
def _project(colliders: ti.template(), x, v, r, rest_speed, x_prev):
    # One branch for the common case (touching nothing), not one per collider: a branch-free minimum
    # (a short-circuit `and` would compile to one branch per collider again).
    nearest = ti.cast(1e30, float)
    for c in ti.static(colliders):
        nearest = ti.min(nearest, c.sdf(x))
    if nearest < r:
        x, v = _project_each(colliders, x, v, r, rest_speed, x_prev)
    return x, v


@ti.func
def _project_each(colliders: ti.template(), x, v, r, rest_speed, x_prev):
    for c in ti.static(colliders):
        d = c.sdf(x) - r
        if d < 0.0:
            n = c.normal(x)
            x -= d * n
            # Coulomb friction on the step's tangential displacement too (Macklin et al., "Unified
            # Particle Physics for Real-Time Applications", 2014, eq. 24): it shrinks by mu times the
            # depth pushed out, so a vertex held by static friction does not creep h^2 g sin(theta)
            # per step down a slope. x_prev is where the step started (x itself: no displacement).
            dx = x - x_prev
            dxt = dx - dx.dot(n) * n
            slip = dxt.norm()
            x -= (1.0 - ti.max(1.0 - c.friction * (-d) / ti.max(slip, 1e-12), 0.0)) * dxt
            e = c.restitution
            if -v.dot(n) <= rest_speed:
                e = 0.0  # resting contact: no bounce
            v = respond(v, n, e, c.friction)
    # The friction shift moves a point back along one surface, possibly a hair into another (a corner):
    # one more position-only pass keeps every collider's sdf >= r.
    for c in ti.static(colliders):
        d = c.sdf(x) - r
        if d < 0.0:
            x -= d * c.normal(x)
    return x, v


@ti.func
def project_spheres(colliders: ti.template(), x, v, r, rest_speed):
    """A sphere of radius r [m] at x moved out of every collider it overlaps; approach speeds at or
    below rest_speed [m/s] do not bounce."""
    return _project(colliders, x, v, r, rest_speed, x)


@ti.func
def collide(colliders: ti.template(), mode: ti.template(), x0, v0, x1, v1, dt, r, rest_speed):
    """End-of-step position and velocity after collisions; x0, v0 start the step, x1, v1 end it; r [m]
    the particle's radius (0 for points); impacts at or below rest_speed [m/s] (< 0: none) do not
    bounce."""
    x = x1
    v = v1
    if ti.static(mode == CollisionMode.BACKWARD):
        xs, vs, xe, ve = x0, v0, x1, v1
        frac = 1.0  # fraction of dt still to run from xs
        for _ in ti.static(range(MAX_HITS)):
            tau = NO_HIT
            n = ti.Vector.zero(float, 3)
            e = 0.0
            mu = 0.0
            for c in ti.static(colliders):
                tc, nc = c.sweep(xs, xe, r)
                if tc < tau:
                    tau, n, e, mu = tc, nc, c.restitution, c.friction
            if tau <= 1.0:
                xh = xs + tau * (xe - xs)
                # Velocity at impact interpolated along the step; the rest of the step keeps the
                # step's velocity change (gravity keeps acting after the bounce).
                vi = vs + tau * (ve - vs)
                if -vi.dot(n) <= rest_speed:
                    e = 0.0
                vh = respond(vi, n, e, mu)
                rest = 1.0 - tau
                ve = vh + rest * (ve - vs)
                frac *= rest
                xs, vs = xh, vh
                xe = xh + frac * dt * ve
        # Impacts left after MAX_HITS (the step's velocity change keeps driving the path into a surface):
        # stop at the first contact on what is left of the path instead of letting the safety projection
        # push the particle out of whichever side is nearest, possibly the far side of a thin solid.
        tau = NO_HIT
        n = ti.Vector.zero(float, 3)
        mu = 0.0
        for c in ti.static(colliders):
            tc, nc = c.sweep(xs, xe, r)
            if tc < tau:
                tau, n, mu = tc, nc, c.friction
        if tau <= 1.0:
            xe = xs + tau * (xe - xs)
            ve = respond(ve, n, 0.0, mu)
        x, v = xe, ve
    # Safety net in both modes: nothing ends a step inside a collider (round-off, multiple contacts).
    return _project(colliders, x, v, r, rest_speed, x0)
