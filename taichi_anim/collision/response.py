"""Collision response for particles against colliders (Witkin & Baraff course notes, "Particle
dynamics", collisions: v_n -> -e v_n, tangential velocity reduced by Coulomb friction), applied to the
velocity relative to the surface, v - v_s, for a moving collider (restitution and friction act on the
relative velocity; v_s = 0 for a static one, whose code has no such term).

`collide` runs after the integrator has produced the end-of-step state; PROJECTION moves the end point to
the surface, BACKWARD re-walks the step's segment (backward search to the time of impact).

BACKWARD filters velocities and lets positions follow them (Bridson, Fedkiw & Anderson, "Robust Treatment
of Collisions, Contact and Friction for Cloth Animation", SIGGRAPH 2002, sec. 7.1 and 8: impulses change
the velocity, and the rest of the step moves with the filtered velocity). A particle touching two
surfaces at once (a wedge, such as a ball resting on the floor) must leave with a velocity in the cone
{v : v.n_a >= 0, v.n_b >= 0} of both contacts, i.e. along their crease: removing one normal at a time
re-enters the other surface at every impact, the step's impacts run out, the particle is held where it is
while its velocity keeps the springs' pull, and a velocity the position never follows grows every step
(a cloth vertex caught between a ball and the floor reached 170 m/s and fed the energy back through its
springs).
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
def crease(v, n, nb):
    """v (with v.n >= 0, n the normal just responded to) kept out of the previous impact's surface of
    normal nb too (nb = 0: none): the projection onto that surface's plane if it leaves the first, else
    onto the crease n x nb (Bridson et al. 2002, sec. 7.1: velocities stay in the cone of every contact)."""
    out = v
    vb = v.dot(nb)
    if vb < 0.0:
        out = v - vb * nb
        if out.dot(n) < 0.0:
            c = n.cross(nb)
            cc = c.norm_sqr()
            out = ti.Vector.zero(float, 3)  # normals opposite (a particle squeezed between two faces)
            if cc > 1e-12:
                out = v.dot(c) / cc * c
    return out


def any_moving(colliders) -> bool:
    """Whether any collider moves (a compile-time flag: static scenes compile no surface velocities)."""
    return any(c.moving for c in colliders)


def any_shell(colliders) -> bool:
    """Whether any collider is a shell (an open mesh: a surface with no inside)."""
    return any(c.shell for c in colliders)


def any_heavy(colliders) -> bool:
    """Whether any collider has large tests (a mesh)."""
    return any(c.heavy for c in colliders)


def distances_bound(colliders) -> bool:
    """Whether every collider's sdf is a bound on the distance to it (`distance_bound`), so that
    `path_is_clear` can vouch for a step's path."""
    return all(getattr(c, "distance_bound", False) for c in colliders)


# The margin of `path_is_clear` beyond the path's length, as a fraction of the coordinates' size: float
# round-off in the sdf and the swept tests is a few units in the last place of |x| (f32: 1.2e-7 each).
CLEAR_SLACK = 1e-5


@ti.func
def path_is_clear(colliders: ti.template(), x0, x1, t, r):
    """Whether the path x0 -> x1 of a particle of radius r [m] stays clear of every collider (all of them
    `distances_bound`) with margin: then `collide` finds no impact on it and no contact at its end, and
    returns (x1, v1) untouched. An sdf bounded by the distance is 1-Lipschitz, so every point of the path
    is at least sdf(x0) - |x1 - x0| from the solid. The swept tests may report a hit up to sqrt(3) r from
    a solid (a box's test grows it by r with square corners), so that is the reach asked for; the margin
    takes the path's length twice and CLEAR_SLACK of the coordinates' and distances' size for round-off
    in either test. Branch-free, so that a pack of particles tests it as one vector."""
    nearest = ti.cast(1e30, float)
    for c in ti.static(colliders):
        nearest = ti.min(nearest, c.sdf(x0, t))
    size = 1.0 + ti.max(ti.abs(x0).max(), ti.abs(x1).max()) + ti.abs(nearest)
    return nearest - 1.7320508 * r > 2.0 * (x1 - x0).norm() + CLEAR_SLACK * size


def _fused(c) -> bool:
    """Whether to ask collider c for (sdf, normal, velocity) at once: one pose or distance query for
    all three (moving colliders, meshes)."""
    return c.moving or c.heavy


@ti.func
def _project(colliders: ti.template(), x, v, r, rest_speed, x_prev, t, h):
    if ti.static(any_heavy(colliders)):
        # A mesh's distance query is large code: one copy of each collider's test, in a run-time loop
        # over the response pass and the position-only pass.
        for p in range(2):
            x, v = _project_pass(colliders, x, v, r, rest_speed, x_prev, t, h, p == 0)
    else:
        x, v = _project_light(colliders, x, v, r, rest_speed, x_prev, t, h)
    return x, v


@ti.func
def _project_pass(colliders: ti.template(), x, v, r, rest_speed, x_prev, t, h, respond_too):
    """One pass of `_project_each` over every collider: with the response (friction, velocity) if
    respond_too, else positions only."""
    for c in ti.static(colliders):
        d, n, vs = c.contact(x, t)
        d -= r
        if d < 0.0:
            x -= d * n
            if respond_too:
                x, v = _slide_and_respond(c, x, v - vs, d, n, x - x_prev - h * vs, rest_speed)
                v += vs
    return x, v


@ti.func
def _project_light(colliders: ti.template(), x, v, r, rest_speed, x_prev, t, h):
    # One branch for the common case (touching nothing), not one per collider: a branch-free minimum
    # (a short-circuit `and` would compile to one branch per collider again).
    nearest = ti.cast(1e30, float)
    for c in ti.static(colliders):
        nearest = ti.min(nearest, c.sdf(x, t))
    if nearest < r:
        x, v = _project_each(colliders, x, v, r, rest_speed, x_prev, t, h)
    return x, v


@ti.func
def _slide_and_respond(c: ti.template(), x, v, d, n, dx, rest_speed):
    """Friction on the step's displacement dx and the velocity response, both relative to the surface."""
    # Coulomb friction on the step's tangential displacement too (Macklin et al., "Unified Particle
    # Physics for Real-Time Applications", 2014, eq. 24): it shrinks by mu times the depth pushed out, so
    # a vertex held by static friction does not creep h^2 g sin(theta) per step down a slope.
    dxt = dx - dx.dot(n) * n
    slip = dxt.norm()
    x -= (1.0 - ti.max(1.0 - c.friction * (-d) / ti.max(slip, 1e-12), 0.0)) * dxt
    e = c.restitution
    if -v.dot(n) <= rest_speed:
        e = 0.0  # resting contact: no bounce
    return x, respond(v, n, e, c.friction)


@ti.func
def _project_each(colliders: ti.template(), x, v, r, rest_speed, x_prev, t, h):
    # x_prev is where the step started (x itself: no displacement); on a moving surface the displacement
    # and the velocity are taken relative to the surface.
    for c in ti.static(colliders):
        if ti.static(_fused(c)):
            d, n, vs = c.contact(x, t)  # one pose evaluation (or distance query) for all three
            d -= r
            if d < 0.0:
                x -= d * n
                x, v = _slide_and_respond(c, x, v - vs, d, n, x - x_prev - h * vs, rest_speed)
                v += vs
        else:
            d = c.sdf(x, t) - r
            if d < 0.0:
                n = c.normal(x, t)
                x -= d * n
                x, v = _slide_and_respond(c, x, v, d, n, x - x_prev, rest_speed)
    # The friction shift moves a point back along one surface, possibly a hair into another (a corner):
    # one more position-only pass keeps every collider's sdf >= r.
    for c in ti.static(colliders):
        if ti.static(_fused(c)):
            d, n, _ = c.contact(x, t)
            if d < r:
                x -= (d - r) * n
        else:
            d = c.sdf(x, t) - r
            if d < 0.0:
                x -= d * c.normal(x, t)
    return x, v


@ti.func
def project_spheres(colliders: ti.template(), x, v, r, rest_speed, t):
    """A sphere of radius r [m] at x, at time t [s], moved out of every collider it overlaps; approach
    speeds (relative to the surface) at or below rest_speed [m/s] do not bounce."""
    return _project(colliders, x, v, r, rest_speed, x, t, 0.0)


@ti.func
def _first_hit(colliders: ti.template(), xs, xe, t, h, r):
    """The earliest impact on the segment xs -> xe over [t, t + h]: (tau, n, e, mu, v_surface)."""
    tau = ti.cast(NO_HIT, float)
    n = ti.Vector.zero(float, 3)
    vsurf = ti.Vector.zero(float, 3)
    e = ti.cast(0.0, float)
    mu = ti.cast(0.0, float)
    for c in ti.static(colliders):
        tc, nc, vc = c.sweep(xs, xe, t, h, r)
        if tc < tau:
            tau, n, e, mu = tc, nc, c.restitution, c.friction
            if ti.static(c.moving):
                vsurf = vc
            elif ti.static(any_moving(colliders)):
                vsurf = ti.Vector.zero(float, 3)
    return tau, n, e, mu, vsurf


@ti.func
def _impact(colliders: ti.template(), xs, vs, xe, ve, frac, t, dt, r, rest_speed, nb, stop):
    """The first impact on what is left of the step (the path xs -> xe, the last frac of [t, t + dt]),
    resolved: the state at impact and the rest of the step with the new velocity (unchanged if none), and
    the normal hit (nb unchanged if none); nb: the previous impact's normal in this step (0: none), whose
    surface the new velocity may not enter either (`crease`); with `stop`, the particle stays at the
    contact instead (see `_stop`). Last, whether it found an impact."""
    tau, n, e, mu, vsurf = _first_hit(colliders, xs, xe, t + (1.0 - frac) * dt, frac * dt, r)
    hit = tau <= 1.0
    if stop and tau <= 1.0:
        xe, ve = _stop(xs, xe, tau, vsurf)
        tau = NO_HIT  # resolved: no bounce below
    if tau <= 1.0:
        xh = xs + tau * (xe - xs)
        # Velocity at impact interpolated along the step; the rest of the step keeps the step's velocity
        # change (gravity keeps acting after the bounce).
        vi = vs + tau * (ve - vs)
        if ti.static(any_moving(colliders)):
            vi -= vsurf
        if -vi.dot(n) <= rest_speed:
            e = 0.0
        vh = crease(respond(vi, n, e, mu), n, nb)
        if ti.static(any_moving(colliders)):
            vh += vsurf
        rest = 1.0 - tau
        ve = vh + rest * (ve - vs)
        # A resting or sliding contact: the velocity change of the rest of the step (gravity) still
        # drives the particle into the surface. Remove that normal part, with Coulomb friction on it, so
        # that the rest of the path slides along the surface instead of hitting it again at once
        # (which ended in the stop below and left the particle where it was for the step).
        if ti.static(any_moving(colliders)):
            if (ve - vsurf).dot(n) < 0.0:
                ve = crease(respond(ve - vsurf, n, 0.0, mu), n, nb) + vsurf
        elif ve.dot(n) < 0.0:
            ve = crease(respond(ve, n, 0.0, mu), n, nb)
        frac *= rest
        xs, vs = xh, vh
        xe = xh + frac * dt * ve
        nb = n
    return xs, vs, xe, ve, frac, nb, hit


@ti.func
def _stop(xs, xe, tau, vsurf):
    """The particle stays at the contact at tau on xs -> xe for the rest of the step (impacts left after
    MAX_HITS), and leaves with a velocity of that contact's surface's (a relative velocity of zero): it
    does not move for the rest of the step, so a velocity kept beside a position held still is one the
    position never follows, and the springs' pull would grow it step after step."""
    return xs + tau * (xe - xs), vsurf


@ti.func
def collide(colliders: ti.template(), mode: ti.template(), x0, v0, x1, v1, t, dt, r, rest_speed):
    """End-of-step position and velocity after collisions; x0, v0 start the step at time t [s], x1, v1
    end it at t + dt; r [m] the particle's radius (0 for points); impacts at or below rest_speed [m/s]
    (< 0: none; relative to the surface) do not bounce."""
    x = x1
    v = v1
    if ti.static(mode == CollisionMode.BACKWARD):
        xs, vs, xe, ve = x0, v0, x1, v1
        frac = ti.cast(1.0, float)  # fraction of dt still to run from xs
        nb = ti.Vector.zero(float, 3)  # the normal of the step's last impact
        # One copy of the swept tests, in a run-time loop that ends at the first pass finding no impact:
        # the rest of the path is then free, and a later pass would sweep the same path and find nothing
        # either. Unrolled, MAX_HITS + 1 copies of every collider's sweep made the particle step's
        # compile the largest part of a cold start (the blobs demo's frame kernel: fe 0.29 s, 3.2 s
        # cold) and swept every path MAX_HITS + 1 times. The last pass stops at the contact instead of
        # bouncing: impacts left after MAX_HITS (the step's velocity change keeps driving the path into a
        # surface) leave the particle at its first contact on what is left of the path, instead of
        # letting the safety projection push it out of whichever side is nearest, possibly the far
        # side of a thin solid.
        for k in range(MAX_HITS + 1):
            xs, vs, xe, ve, frac, nb, hit = _impact(
                colliders, xs, vs, xe, ve, frac, t, dt, r, rest_speed, nb, k == MAX_HITS
            )
            if not hit:
                break
        x, v = xe, ve
    if ti.static(mode == CollisionMode.PROJECTION and any_shell(colliders)):
        x, v = _cross_shells(colliders, x0, x, v, t, dt, r, rest_speed)
    # Safety net in both modes: nothing ends a step inside a collider (round-off, multiple contacts).
    return _project(colliders, x, v, r, rest_speed, x0, t + dt, dt)


@ti.func
def _cross_shells(colliders: ti.template(), x0, x, v, t, dt, r, rest_speed):
    """Projection mode against shells (open meshes): a particle can cross one within a step without
    ending inside it (at thickness 0 it never is inside), where no end-point projection finds it. The
    step's path x0 -> x is swept instead; at its first contact the particle stays on the side it came
    from, the rest of the step's displacement (relative to the surface) loses its part into the surface
    and slides with Coulomb friction, and the velocity responds as in a projection."""
    for c in ti.static(colliders):
        if ti.static(c.shell):
            tau, n, vs = c.sweep(x0, x, t, dt, r)
            if tau <= 1.0:
                dx = (1.0 - tau) * (x - x0 - dt * vs)
                dn = ti.min(dx.dot(n), 0.0)
                x = x0 + tau * (x - x0) + (1.0 - tau) * dt * vs + dx - dn * n
                x, v = _slide_and_respond(c, x, v - vs, dn, n, dx, rest_speed)
                v += vs
    return x, v
