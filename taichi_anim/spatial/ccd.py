"""Continuous collision tests as `@ti.func`s: point–triangle and edge–edge over one step with linear
vertex motion, returning the earliest time of impact tau in [0, 1] (as a fraction of the step) or
NO_HIT = 2.0.

Bridson, Fedkiw & Anderson, "Robust treatment of collisions, contact and friction for cloth animation"
(SIGGRAPH 2002), sec. 6.4: a point and a triangle (or two edges) can only collide when their four
points are coplanar, i.e. at a root in [0, 1] of the cubic

    f(t) = (x21(t) x x31(t)) . x41(t),

with x21 = b - a, x31 = c - a, x41 = p - a for point p and triangle abc (x21 = q - p, x31 = s - r,
x41 = r - p for edges pq and rs); at such a time a collision is reported if the distance (point–triangle,
or segment–segment) is at most the thickness h.

Root finding robust to round-off, as done here:
1. The cubic's coefficients give f'(t) = 3 a3 t^2 + 2 a2 t + a1; its real roots inside (0, 1), from the
   cancellation-free quadratic formula (a vanishing leading or linear coefficient handled, so
   quadratic, linear and constant f need no special case), split [0, 1] into pieces where f is monotone.
   The ends t = 0 and t = 1 are piece ends, so coplanarity at the start or end is seen.
2. A root is any time where |f| <= eps_f, not just a sign change: eps_f bounds the round-off of
   evaluating f (16 machine epsilons times the sizes of the terms of f, the coordinates' magnitude
   included). On a monotone piece the times with |f| <= eps_f form one interval [ta, tb] (a point-like one
   for a clean crossing, the whole piece for motion that stays coplanar); its ends are found by bisection
   on f - eps_f and f + eps_f, keeping the conservative side (ta early, tb late).
3. Within [ta, tb] the earliest time with distance <= h is found by conservative advancement
   (Mirtich 1996): the distance changes at most at rate L, the largest relative speed of the point and
   a triangle vertex (of two edge endpoints), so from t the next possible contact is no earlier than
   t + (d(t) - h) / L. This is the proximity test at the root for a clean crossing, and the earliest
   contact for coplanar motion (a point sliding into a triangle in its plane, parallel edges, zero-area
   triangles, zero motion), where the thickness is the tolerance that makes "coplanar" meaningful. After
   `ADVANCE_STEPS` steps without deciding (a grazing pass just outside h) the current time is returned as
   a hit: conservative.

Hence: no crossing whose coplanar configuration is within h is missed (up to round-off); reported hits
lie within h of a configuration where |f| <= eps_f (near-coplanar), so near misses within the thickness
count as hits. Use h well above the round-off of the coordinates (f64: ~1e-12 of their magnitude; f32:
~1e-5). Time resolution of the band ends: 2^-40 of the step in f64, 2^-20 in f32.
"""

import taichi as ti
from taichi.lang import impl

from .bounds import fp_epsilon
from .distance import point_triangle_closest, segment_segment_closest
from .intersect import NO_HIT

ADVANCE_STEPS = 128


@ti.func
def _bisect_steps():
    return ti.static(40 if impl.get_runtime().default_fp == ti.f64 else 20)


@ti.func
def _coplanarity(X0, dX, Y0, dY, Z0, dZ, t):
    return (X0 + t * dX).cross(Y0 + t * dY).dot(Z0 + t * dZ)


@ti.func
def _monotone_breaks(X0, dX, Y0, dY, Z0, dZ):
    """The roots of f' in (0, 1), sorted; absent ones are returned as 1.0 (an empty last piece)."""
    c0 = X0.cross(Y0)
    c1 = X0.cross(dY) + dX.cross(Y0)
    c2 = dX.cross(dY)
    qa = 3.0 * c2.dot(dZ)
    qb = 2.0 * (c1.dot(dZ) + c2.dot(Z0))
    qc = c0.dot(dZ) + c1.dot(Z0)
    r0 = 1.0
    r1 = 1.0
    if qa != 0.0:
        disc = qb * qb - 4.0 * qa * qc
        if disc >= 0.0:
            sq = ti.sqrt(disc)
            q = -0.5 * (qb + ti.select(qb >= 0.0, sq, -sq))
            if q != 0.0:
                r0 = q / qa
                r1 = qc / q
            else:
                r0 = 0.0  # qb = qc = 0: a double root at t = 0
    elif qb != 0.0:
        r0 = -qc / qb
    if r0 <= 0.0 or r0 >= 1.0:
        r0 = 1.0
    if r1 <= 0.0 or r1 >= 1.0:
        r1 = 1.0
    return ti.min(r0, r1), ti.max(r0, r1)


@ti.func
def _band_end(X0, dX, Y0, dY, Z0, dZ, lo, hi, level, first: ti.template()):
    """Bisection on a monotone piece for where |f| enters (first) or leaves (not first) the band
    |f| <= |level|; `level` is eps_f with the sign of f outside the band at that end."""
    for _ in range(_bisect_steps()):
        mid = 0.5 * (lo + hi)
        outside = level * (_coplanarity(X0, dX, Y0, dY, Z0, dZ, mid) - level) > 0.0
        if ti.static(first):
            if outside:
                lo = mid
            else:
                hi = mid
        else:
            if outside:
                hi = mid
            else:
                lo = mid
    end = hi
    if ti.static(first):
        end = lo
    return end


@ti.func
def _distance(edge: ti.template(), x0, x1, x2, x3, y0, y1, y2, y3, t):
    """Point-triangle (x0 vs x1 x2 x3) or edge-edge (x0 x1 vs x2 x3) distance at time t."""
    p = x0 + t * (y0 - x0)
    q = x1 + t * (y1 - x1)
    r = x2 + t * (y2 - x2)
    s = x3 + t * (y3 - x3)
    d = 0.0
    if ti.static(edge):
        u, v = segment_segment_closest(p, q, r, s)
        d = (p + u * (q - p) - r - v * (s - r)).norm()
    else:
        w = point_triangle_closest(p, q, r, s)
        d = (p - w[0] * q - w[1] * r - w[2] * s).norm()
    return d


@ti.func
def _cubic_vectors(edge: ti.template(), x0, x1, x2, x3):
    """(X, Y, Z) with f = (X x Y) . Z: (b - a, c - a, p - a) for p = x0 and triangle x1 x2 x3, or
    (q - p, s - r, r - p) for edges x0 x1 and x2 x3."""
    X = x2 - x1
    Y = x3 - x1
    Z = x0 - x1
    if ti.static(edge):
        X = x1 - x0
        Y = x3 - x2
        Z = x2 - x0
    return X, Y, Z


@ti.func
def _ccd(edge: ti.template(), x0, x1, x2, x3, y0, y1, y2, y3, h):
    # x: positions at the start, y: at the end of the step.
    X0, Y0, Z0 = _cubic_vectors(edge, x0, x1, x2, x3)
    X1, Y1, Z1 = _cubic_vectors(edge, y0, y1, y2, y3)
    dX = X1 - X0
    dY = Y1 - Y0
    dZ = Z1 - Z0
    # Bound on the rate of change of the distance: the largest relative speed of a point of one
    # primitive and a point of the other, attained at vertices.
    v0, v1, v2, v3 = y0 - x0, y1 - x1, y2 - x2, y3 - x3
    speed = ti.max((v0 - v1).norm(), (v0 - v2).norm(), (v0 - v3).norm())
    if ti.static(edge):
        speed = ti.max((v0 - v2).norm(), (v0 - v3).norm(), (v1 - v2).norm(), (v1 - v3).norm())
    # Round-off bound of f: errors of the coordinates (magnitude m) and of the products.
    m = ti.max(
        ti.abs(x0), ti.abs(x1), ti.abs(x2), ti.abs(x3), ti.abs(y0), ti.abs(y1), ti.abs(y2), ti.abs(y3)
    ).max()
    sx = X0.norm() + dX.norm()
    sy = Y0.norm() + dY.norm()
    sz = Z0.norm() + dZ.norm()
    eps_f = 16.0 * fp_epsilon() * (m * (sy * sz + sx * sz + sx * sy) + sx * sy * sz)

    t1, t2 = _monotone_breaks(X0, dX, Y0, dY, Z0, dZ)
    tau = NO_HIT
    for k in range(3):
        lo = ti.select(k == 0, 0.0, ti.select(k == 1, t1, t2))
        hi = ti.select(k == 0, t1, ti.select(k == 1, t2, 1.0))
        if tau == NO_HIT and (k == 0 or lo < hi):
            fl = _coplanarity(X0, dX, Y0, dY, Z0, dZ, lo)
            fr = _coplanarity(X0, dX, Y0, dY, Z0, dZ, hi)
            if not ((fl > eps_f and fr > eps_f) or (fl < -eps_f and fr < -eps_f)):
                ta = lo
                tb = hi
                if ti.abs(fl) > eps_f:
                    ta = _band_end(X0, dX, Y0, dY, Z0, dZ, lo, hi, ti.select(fl > 0.0, eps_f, -eps_f), True)
                if ti.abs(fr) > eps_f:
                    tb = _band_end(X0, dX, Y0, dY, Z0, dZ, lo, hi, ti.select(fr > 0.0, eps_f, -eps_f), False)
                # Conservative advancement over the near-coplanar times [ta, tb].
                t = ta
                for _ in range(ADVANCE_STEPS):
                    d = _distance(edge, x0, x1, x2, x3, y0, y1, y2, y3, t)
                    if d <= h:
                        tau = t
                        break
                    if speed <= 0.0 or t + (d - h) / speed > tb:
                        t = NO_HIT  # no contact in this band
                        break
                    t += (d - h) / speed
                if tau == NO_HIT and t != NO_HIT:
                    tau = t  # undecided after ADVANCE_STEPS: report the contact conservatively
    return tau


@ti.func
def ccd_point_triangle(p0, a0, b0, c0, p1, a1, b1, c1, thickness):
    """Earliest time tau in [0, 1] (fraction of the step) at which point p, moving linearly from p0 to p1,
    is coplanar with triangle abc (moving from a0 b0 c0 to a1 b1 c1) and within `thickness` [m] of it;
    NO_HIT (2.0) if never."""
    return _ccd(False, p0, a0, b0, c0, p1, a1, b1, c1, thickness)


@ti.func
def ccd_edge_edge(p0, q0, r0, s0, p1, q1, r1, s1, thickness):
    """Earliest time tau in [0, 1] at which edges pq and rs, moving linearly from (p0, q0), (r0, s0) to
    (p1, q1), (r1, s1), are coplanar and within `thickness` [m] of each other; NO_HIT (2.0) if never."""
    return _ccd(True, p0, q0, r0, s0, p1, q1, r1, s1, thickness)
