"""Colliders as signed distances (positive outside the solid) with a swept segment test; static or
moving rigidly (collision/motion.py).

Each collider provides `@ti.func`s of a world point x and a time t [s]: `sdf(x, t)`, `normal(x, t)`
(outward, for projection), `velocity(x, t)` (the surface's velocity there, 0 for a static collider) and
`sweep(x0, x1, t, h, r) -> (tau, n, v_surface)`: the fraction tau in [0, 1] of the step [t, t + h], along
which a sphere of radius r (0 for a point) goes from x0 to x1, at which it touches the solid (2.0 if it
does not), the touched face's normal and the surface's velocity there. A sphere touches when
sdf(x, t) < r. A static collider (`moving` False) ignores t and compiles to the time-free tests; a moving
one runs the same shape tests in its own frame, the step's start point placed with the start pose and its
end point with the end pose (exact for translations, first order in the angle turned per step for
rotations). Segment-box uses the slab method (Kay & Kajiya, "Ray Tracing Complex Scenes", 1986).

What the rest of the engine asks of a collider (`Collider`; the watchdog, USD export and renderers ask
the collider, never its class, and `check_collider` refuses one that lacks a part, when the Model
allocates it):
  kind                      a short name: the USD prim's name and the kind in its customData
  restitution, friction     the response's coefficients; moving, heavy, shell, needs_prepare: flags the
                            response code branches on at compile time
  local_points() (P,3) [m]  points spanning its finite geometry in its own frame (a plane: its point
                            nearest the origin); sample_points(t) places them in the world at t [s]
  key_times() (K,) [s]      when its motion is keyed (empty when static); velocity_bound() [m/s] its
                            surface's largest speed (by default the chord speed of its sample points
                            between key times)
  surface(bounds) -> (V (V,3) [m], F (F,k))   its surface in its own frame (a plane: a square covering
                            bounds (lo, hi) [m]); surface_at(t, bounds) -> V in the world at t
  motion                    a RigidMotion (USD writes it as transform ops) or None; deforming: True when
                            its vertices move on their own (USD writes surface_at per frame)
  half_space() -> (n, offset) | None   a plane's n . x = offset (USD draws six as one container)
  distance_bound (optional, default False)   True when sdf(x, t) never exceeds the distance to the
                            solid at any time: lets blocked frames skip its tests on clear paths
  allocate(reach, model)    writes what its kernels read into fields, once the Model exists (reach [m]:
                            the largest particle radius; per-size arrays from model.new_field, so that
                            they follow capacity buckets)
"""

import math
from enum import Enum

import numpy as np
import taichi as ti

from ..errors import ParameterError
from ..runtime import data_oriented
from .motion import quat_rotate, quat_rotate_inverse

NO_HIT = 2.0
# A point counts as on a surface up to this distance [m]: projection leaves contacts exactly there only to
# round-off, and a swept test that required sdf >= r strictly would miss the next step's impact.
ON_SURFACE = 1e-6
# A path whose approach to a surface is below this fraction of its length (the cosine of its angle with the
# surface) slides along it: round-off decides the sign of such an approach, and counting it as an impact
# at tau = 0 would stop a sliding particle for the step. The end-of-step projection handles those.
GRAZING = 1e-5


class CollisionMode(Enum):
    """How a particle that crossed a collider during a step is treated.

    PROJECTION: the course's formula — move the end point back onto the surface, reflect the normal
    velocity (x -= phi n; v_n -> -e v_n). Cheap, but misses a particle that crosses a thin solid in one step.
    BACKWARD: backward search — find the time of impact inside the step from the swept segment, respond
    there, and finish the rest of the step with the new velocity.
    """

    PROJECTION = "projection"
    BACKWARD = "backward"


COLLIDER_METHODS = (
    "sdf",
    "normal",
    "velocity",
    "contact",
    "sweep",
    "allocate",
    "settings",
    "local_points",
    "sample_points",
    "key_times",
    "velocity_bound",
    "surface",
    "surface_at",
    "half_space",
)
COLLIDER_ATTRIBUTES = (
    "kind",
    "restitution",
    "friction",
    "moving",
    "heavy",
    "shell",
    "needs_prepare",
    "deforming",
)


def check_collider(collider) -> None:
    """Raise ParameterError naming the collider's class and every method or attribute it lacks (the
    collider protocol: this module's docstring)."""
    missing = [m for m in COLLIDER_METHODS if not callable(getattr(collider, m, None))]
    missing += [a for a in COLLIDER_ATTRIBUTES if getattr(collider, a, None) is None]
    if missing:
        raise ParameterError(
            f"collider {type(collider).__name__} lacks: {', '.join(missing)} (the collider protocol: "
            "taichi_anim/collision/colliders.py)"
        )


class Collider:
    """Base of colliders: the defaults of the protocol (module docstring). A subclass gives `kind`,
    `local_points` and `surface` (and the `@ti.func` tests; ColliderAnalytic builds them from shape tests
    in the collider's own frame)."""

    kind = None
    motion = None
    deforming = False
    needs_prepare = False  # no Python-side work before a step
    heavy = False  # small tests: `collide` may unroll them
    shell = False  # a solid: a particle that crossed its surface ends inside, where projection finds it
    # Whether sdf(x, t) is at most the distance from x to the solid, at every time (a static collider
    # whose sdf is exact or a lower bound): a path shorter than sdf(x0) - r then touches nothing
    # (response.path_is_clear), which the blocked frame's packs use to skip the swept tests.
    distance_bound = False

    def key_times(self) -> np.ndarray:
        """Times [s] its motion is keyed at (K,); empty for a static collider."""
        return np.zeros(0) if self.motion is None else np.asarray(self.motion.times, dtype=np.float64)

    def sample_points(self, t: float) -> np.ndarray:
        """local_points placed in the world at time t [s] (P,3) [m]."""
        local = np.asarray(self.local_points(), dtype=np.float64).reshape(-1, 3)
        return local if self.motion is None else self.motion.apply(local, t)

    def velocity_bound(self) -> float:
        """The largest speed [m/s] of its sample points between consecutive key times (0 if static)."""
        times = self.key_times()
        speed = 0.0
        frames = [self.sample_points(float(t)) for t in times]
        for k in range(len(times) - 1):
            dt = times[k + 1] - times[k]
            chord = np.linalg.norm(frames[k + 1] - frames[k], axis=1)
            speed = max(speed, float(np.max(chord, initial=0.0)) / dt)
        return speed

    def surface_at(self, t: float, bounds=None) -> np.ndarray:
        """The vertices (V,3) [m] of `surface(bounds)` in the world at time t [s]."""
        v = np.asarray(self.surface(bounds)[0], dtype=np.float64)
        return v if self.motion is None else self.motion.apply(v, t)

    def half_space(self):
        """(n, offset) of a plane n . x = offset bounding the solid n . x < offset; None otherwise."""
        return None


class ColliderAnalytic(Collider):
    """What analytic colliders share: the time protocol around shape tests in the collider's own frame
    (`_sdf`, `_normal`, `_sweep`), and an optional RigidMotion. `moving` is a compile-time flag: response
    code reads surface velocities only when a collider moves. A new analytic shape subclasses it with
    those three `@ti.func`s, `kind`, `local_points` and `surface`."""

    @property
    def moving(self) -> bool:
        return self.motion is not None

    @property
    def distance_bound(self) -> bool:
        """Static analytic shapes have exact signed distances (plane, box, sphere)."""
        return self.motion is None

    def allocate(self, reach: float = 0.0, model=None) -> None:
        """Write what the kernels read into fields (called once by the Model, after Taichi starts; reach
        [m]: the largest particle radius the collider will be queried with; model: the Model, whose
        allocator a collider with per-size arrays uses). Checks the protocol first."""
        check_collider(self)
        if self.motion is not None:
            self.motion.allocate()

    def _settings(self, **shape) -> dict:
        out = {**shape, "restitution": self.restitution, "friction": self.friction}
        if self.motion is not None:
            out["motion"] = self.motion.settings()
        return out

    @ti.func
    def sdf(self, x, t):
        p = x
        if ti.static(self.moving):
            p = self.motion.to_local(x, t)
        return self._sdf(p)

    @ti.func
    def normal(self, x, t):
        n = ti.Vector.zero(float, 3)
        if ti.static(self.moving):
            q, tr = self.motion.pose_at(t)
            n = quat_rotate(q, self._normal(quat_rotate_inverse(q, x - tr)))
        else:
            n = self._normal(x)
        return n

    @ti.func
    def velocity(self, x, t):
        v = ti.Vector.zero(float, 3)
        if ti.static(self.moving):
            v = self.motion.velocity(x, t)
        return v

    @ti.func
    def contact(self, x, t):
        """(sdf, normal, surface velocity) at x, t from one evaluation of the pose."""
        d = ti.cast(0.0, float)
        n = ti.Vector.zero(float, 3)
        v = ti.Vector.zero(float, 3)
        if ti.static(self.moving):
            q, tr, omega, vel = self.motion.motion_at(t)
            p = quat_rotate_inverse(q, x - tr)
            d, n, v = self._sdf(p), quat_rotate(q, self._normal(p)), omega.cross(x - tr) + vel
        else:
            d, n = self._sdf(x), self._normal(x)
        return d, n, v

    @ti.func
    def sweep(self, x0, x1, t, h, r):
        tau = ti.cast(NO_HIT, float)
        n = ti.Vector.zero(float, 3)
        vs = ti.Vector.zero(float, 3)
        if ti.static(self.moving):
            # The segment in the collider's frame: start point with the start pose, end with the end pose.
            m = self.motion
            tau, n = self._sweep(m.to_local(x0, t), m.to_local(x1, t + h), r)
            if tau <= 1.0:
                q, tr, omega, vel = m.motion_at(t + tau * h)
                n = quat_rotate(q, n)
                vs = omega.cross(x0 + tau * (x1 - x0) - tr) + vel
        else:
            tau, n = self._sweep(x0, x1, r)
        return tau, n, vs


@data_oriented
class ColliderPlane(ColliderAnalytic):
    """Half-space n . x < offset is solid (in the motion's frame, if it moves). normal (3,) unit, offset
    [m], restitution e in [0, 1], friction mu >= 0 (Coulomb, on the collision impulse); motion: a
    RigidMotion or None (static)."""

    def __init__(self, normal, offset: float, restitution: float, friction: float, motion=None):
        self.n = tuple(float(c) for c in normal)
        self.offset = float(offset)
        self.restitution = float(restitution)
        self.friction = float(friction)
        self.motion = motion

    kind = "plane"

    def settings(self) -> dict:
        return self._settings(type="plane", normal=self.n, offset=self.offset)

    def local_points(self) -> np.ndarray:
        """Its point nearest the frame's origin (1,3) [m]: a plane has no finite extent."""
        return np.asarray(self.n)[None, :] * self.offset

    def surface(self, bounds=None):
        """A square quad on the plane covering bounds (lo, hi) [m] (plane_square)."""
        return plane_square(np.asarray(self.n), self.offset, bounds)

    def half_space(self):
        """(n, offset): the solid is n . x < offset."""
        return self.n, self.offset

    @ti.func
    def _sdf(self, x):
        return ti.Vector(self.n, dt=float).dot(x) - self.offset

    @ti.func
    def _normal(self, x):
        return ti.Vector(self.n, dt=float)

    @ti.func
    def _sweep(self, x0, x1, r):
        d0 = self._sdf(x0) - r
        d1 = self._sdf(x1) - r
        tau = NO_HIT
        if d0 >= -ON_SURFACE and d1 < 0.0 and d0 - d1 > GRAZING * (x1 - x0).norm():
            tau = ti.max(d0, 0.0) / (ti.max(d0, 0.0) - d1)
        return tau, ti.Vector(self.n, dt=float)


@data_oriented
class ColliderSolidBox(ColliderAnalytic):
    """Solid box lo <= x <= hi [m], axis-aligned in the motion's frame (a thin one is a slab); particles
    stay outside."""

    def __init__(self, lo, hi, restitution: float, friction: float, motion=None):
        self.lo = tuple(float(c) for c in lo)
        self.hi = tuple(float(c) for c in hi)
        self.restitution = float(restitution)
        self.friction = float(friction)
        self.motion = motion

    kind = "box"

    def settings(self) -> dict:
        return self._settings(type="solid_box", lo=self.lo, hi=self.hi)

    def local_points(self) -> np.ndarray:
        """Its 8 corners (8,3) [m]."""
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        return np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])

    def surface(self, bounds=None):
        """8 vertices and 6 outward quads (box_mesh)."""
        return box_mesh(np.asarray(self.lo), np.asarray(self.hi))

    @ti.func
    def _face(self, x):
        """Distance to the nearest face from inside, and that face's outward normal."""
        lo = ti.Vector(self.lo, dt=float)
        hi = ti.Vector(self.hi, dt=float)
        best = 1e30
        n = ti.Vector.zero(float, 3)
        for a in ti.static(range(3)):
            if x[a] - lo[a] < best:
                best = x[a] - lo[a]
                n = -ti.Vector.unit(3, a, float)
            if hi[a] - x[a] < best:
                best = hi[a] - x[a]
                n = ti.Vector.unit(3, a, float)
        return best, n

    @ti.func
    def _sdf(self, x):
        lo = ti.Vector(self.lo, dt=float)
        hi = ti.Vector(self.hi, dt=float)
        q = ti.max(lo - x, x - hi)
        outside = ti.max(q, 0.0).norm()
        inside_depth, _ = self._face(x)
        return outside if q.max() > 0.0 else -inside_depth

    @ti.func
    def _normal(self, x):
        _, n = self._face(x)
        return n

    @ti.func
    def _sweep(self, x0, x1, r):
        # The box grown by r on every side (its corners square, not rounded: conservative).
        lo = ti.Vector(self.lo, dt=float) - r
        hi = ti.Vector(self.hi, dt=float) + r
        d = x1 - x0
        t_enter = -1e30
        t_exit = 1e30
        axis = 0
        for a in ti.static(range(3)):
            if ti.abs(d[a]) < 1e-20:
                if x0[a] < lo[a] or x0[a] > hi[a]:
                    t_exit = -1.0  # parallel to this slab and outside it: no hit
            else:
                ta = (lo[a] - x0[a]) / d[a]
                tb = (hi[a] - x0[a]) / d[a]
                t_near = ti.min(ta, tb)
                if t_near > t_enter:
                    t_enter = t_near
                    axis = a
                t_exit = ti.min(t_exit, ti.max(ta, tb))
        tau = NO_HIT
        n = ti.Vector.zero(float, 3)
        # An impact enters through the face of `axis`: the start point lies at most ON_SURFACE behind it
        # (not inside the box, as near a square corner of the grown box) and the path is not sliding
        # along it.
        entering = t_enter * ti.abs(d[axis]) >= -ON_SURFACE and ti.abs(d[axis]) > GRAZING * d.norm()
        if (
            t_enter <= t_exit
            and t_enter <= 1.0
            and self._sdf(x0) >= r - ON_SURFACE
            and t_exit >= 0.0
            and entering
        ):
            tau = ti.max(t_enter, 0.0)
            n[axis] = -1.0 if d[axis] > 0.0 else 1.0
        return tau, n


@data_oriented
class ColliderSphere(ColliderAnalytic):
    """Solid ball |x - center| < radius [m] (center in the motion's frame); particles (and cloth
    vertices, radius = thickness) stay out."""

    def __init__(self, center, radius: float, restitution: float, friction: float, motion=None):
        self.center = tuple(float(c) for c in center)
        self.radius = float(radius)
        self.restitution = float(restitution)
        self.friction = float(friction)
        self.motion = motion

    kind = "sphere"

    def settings(self) -> dict:
        return self._settings(type="sphere", center=self.center, radius=self.radius)

    def local_points(self) -> np.ndarray:
        """The 6 poles along the axes (6,3) [m]."""
        return np.asarray(self.center) + self.radius * np.vstack([np.eye(3), -np.eye(3)])

    def surface(self, bounds=None):
        """A UV sphere of outward triangles (sphere_mesh)."""
        return sphere_mesh(np.asarray(self.center), self.radius)

    @ti.func
    def _sdf(self, x):
        return (x - ti.Vector(self.center, dt=float)).norm() - self.radius

    @ti.func
    def _normal(self, x):
        d = x - ti.Vector(self.center, dt=float)
        n = ti.Vector([0.0, 1.0, 0.0], dt=float)  # the centre itself: push up (any direction is valid)
        length = d.norm()
        if length > 1e-12:
            n = d / length
        return n

    @ti.func
    def _sweep(self, x0, x1, r):
        # First root of |x0 + tau (x1 - x0) - c| = R + r on [0, 1] (segment against the grown ball).
        c = ti.Vector(self.center, dt=float)
        rr = self.radius + r
        d = x1 - x0
        m = x0 - c
        a = d.dot(d)
        b = m.dot(d)
        q = m.dot(m) - rr * rr
        tau = NO_HIT
        n = ti.Vector.zero(float, 3)
        disc = b * b - a * q
        approach = b < -GRAZING * ti.sqrt(a * m.dot(m))
        if q >= -2.0 * rr * ON_SURFACE and a > 1e-30 and approach and disc >= 0.0:
            t_hit = (-b - ti.sqrt(disc)) / a
            if t_hit <= 1.0:
                tau = ti.max(t_hit, 0.0)
                n = self._normal(x0 + tau * d)
        return tau, n


# ---- surfaces for drawing and export (NumPy)

PLANE_HALF_SIZE = 1.0  # [m] half side of the square drawn for a plane without scene bounds


def plane_square(n, offset, bounds):
    """A square (4 vertices, 1 quad facing n) on the plane n.x = offset, centred on the projection of
    the bounds' centre (or the origin), half side half the bounds' diagonal (or PLANE_HALF_SIZE)."""
    centre, half = np.zeros(3), PLANE_HALF_SIZE
    if bounds is not None:
        lo, hi = bounds
        centre, half = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    centre = centre - (centre @ n - offset) * n
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)  # u, w, n right-handed: the quad u, w, -u, -w runs counter-clockwise about n
    v = centre + half * np.array([u + w, -u + w, -u - w, u - w])
    return v, np.array([[0, 1, 2, 3]])


def box_mesh(lo, hi):
    """The box lo..hi as 8 vertices and 6 outward-facing quads."""
    v = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    return v, np.array(faces)


def sphere_mesh(centre, radius, rings: int = 16, segments: int = 32):
    """A UV sphere: vertices on the sphere of `radius` [m] at `centre`, outward triangles."""
    theta = np.linspace(0.0, math.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), -np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    v = np.vstack([[0.0, 1.0, 0.0], ring, [0.0, -1.0, 0.0]]) * radius + centre
    faces = []
    s = segments
    for j in range(s):
        faces.append([0, 1 + j, 1 + (j + 1) % s])
        last = 1 + (rings - 2) * s
        faces.append([len(v) - 1, last + (j + 1) % s, last + j])
        for i in range(rings - 2):
            a, b = 1 + i * s + j, 1 + i * s + (j + 1) % s
            faces += [[a, a + s, b + s], [a, b + s, b]]
    return v, np.array(faces)


_RigidCollider = ColliderAnalytic  # the former name
