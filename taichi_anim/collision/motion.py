"""Keyframed motion: a collider's rigid motion, x_world = R(t) p + T(t) for a point p of its own frame,
and attachments (pinned particles that follow keyframed or rigidly moving targets).

Translation is piecewise linear between keyframes; rotation is spherical linear interpolation (slerp,
Shoemake, "Animating Rotation with Quaternion Curves", SIGGRAPH 1985, eq. on p. 249: the shortest arc
at constant angular velocity), written as R(t) = R_k Rot(a_k, s theta_k) with the relative rotation
R_k^T R_{k+1} = Rot(a_k, theta_k) precomputed per segment and Rot from Rodrigues' formula. Before the
first keyframe and after the last the pose is held (velocity 0). The pose is evaluated inside the
kernels from fields written once when the model is built, so a moving collider costs no Python work
per step. Quaternions are (x, y, z, w), scalar last (as in SciPy and Warp).
"""

import math

import numpy as np
import taichi as ti
from taichi.lang import impl

from .. import bulk, validate
from ..errors import ParameterError
from ..rotations import matrix_to_quat, quat_to_matrix
from ..runtime import data_oriented, np_float


def _rotations(rotations, count: int) -> np.ndarray:
    """Validated (K,3,3) rotation matrices from (K,4) quaternions or (K,3,3) matrices (or None)."""
    if rotations is None:
        return np.tile(np.eye(3), (count, 1, 1))
    r = np.asarray(rotations, dtype=np.float64)
    if r.shape == (count, 4):
        validate.finite_array("rotations", r, (4,))
        norm = np.linalg.norm(r, axis=1)
        if np.any(norm < 1e-12):
            raise ParameterError(f"rotations: quaternion {int(np.argmin(norm))} is zero")
        return quat_to_matrix(r / norm[:, None])
    if r.shape == (count, 3, 3):
        validate.finite_array("rotations", r, (3, 3))
        err = np.abs(np.einsum("kji,kjl->kil", r, r) - np.eye(3)).max(axis=(1, 2))
        det = np.linalg.det(r)
        bad = (err > 1e-6) | (det < 0.0)
        if bad.any():
            k = int(np.argmax(bad))
            raise ParameterError(
                f"rotations: matrix {k} is not a rotation (|R^T R - I| = {err[k]:.3g}, det = {det[k]:.3g})"
            )
        return r
    raise ParameterError(
        f"rotations must have shape ({count}, 4) (quaternions x, y, z, w) or ({count}, 3, 3), got {r.shape}"
    )


def _times(times) -> np.ndarray:
    t = validate.finite_array("times", np.atleast_1d(np.asarray(times, dtype=np.float64)))
    if t.ndim != 1 or len(t) == 0:
        raise ParameterError(f"times must be a non-empty 1-D array [s], got shape {t.shape}")
    step = np.diff(t)
    if np.any(step <= 0.0):
        k = int(np.argmax(step <= 0.0))
        raise ParameterError(
            f"times must increase strictly, got times[{k}] = {t[k]} >= times[{k + 1}] = {t[k + 1]}"
        )
    return t


@data_oriented
class RigidMotion:
    """A rigid motion from keyframes: times (K,) [s] strictly increasing; translations (K,3) [m];
    rotations (K,4) unit quaternions (x, y, z, w) or (K,3,3) matrices, default identity. A point p of
    the collider's own frame is at R(t) p + T(t) in the world."""

    def __init__(self, times, translations, rotations=None):
        self.times = _times(times)
        k = len(self.times)
        self.translations = validate.finite_array("translations", translations, (3,))
        if len(self.translations) != k:
            raise ParameterError(
                f"translations must have one row per keyframe ({k}), got {len(self.translations)}"
            )
        self.rotations = _rotations(rotations, k)
        self.count = k
        # Per segment: the relative rotation R_k^T R_{k+1} as an axis (in R_k's frame) and an angle in
        # [0, pi] (the shortest arc, as slerp takes it).
        self.axes = np.tile([1.0, 0.0, 0.0], (k, 1))
        self.angles = np.zeros(k)
        for s in range(k - 1):
            q = matrix_to_quat(self.rotations[s].T @ self.rotations[s + 1])
            if q[3] < 0.0:
                q = -q
            sin_half = np.linalg.norm(q[:3])
            self.angles[s] = 2.0 * np.arctan2(sin_half, q[3])
            if sin_half > 1e-15:
                self.axes[s] = q[:3] / sin_half
        self._program = None  # the Taichi program the fields were allocated in

    @classmethod
    def from_transform(cls, transform, times) -> "RigidMotion":
        """Sample a callable transform(t) -> (R (3,3) rotation, T (3,) [m]) at `times` (K,) [s]; between
        samples the motion interpolates (a rotation of more than pi between samples is aliased)."""
        t = _times(times)
        rs, ts = [], []
        for ti_ in t:
            r, tr = transform(float(ti_))
            rs.append(np.asarray(r, dtype=np.float64))
            ts.append(np.asarray(tr, dtype=np.float64).reshape(-1))
        return cls(t, np.array(ts), np.array(rs))

    def settings(self) -> dict:
        """The motion's keyframes for run.json."""
        return {"keyframes": self.count, "start": float(self.times[0]), "end": float(self.times[-1])}

    # -- Python-side evaluation (tests, drawing) -----------------------------------------------------------

    def _locate(self, t: float) -> tuple[int, float]:
        times = self.times
        if self.count == 1 or t <= times[0]:
            return 0, 0.0
        if t >= times[-1]:
            return self.count - 2, 1.0
        k = int(np.searchsorted(times, t, side="right")) - 1
        return k, (t - times[k]) / (times[k + 1] - times[k])

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(R (3,3), T (3,) [m]) at time t [s]."""
        k, s = self._locate(float(t))
        if self.count == 1:
            return self.rotations[0].copy(), self.translations[0].copy()
        a, th = self.axes[k], s * self.angles[k]
        cross = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        rot = np.eye(3) + np.sin(th) * cross + (1.0 - np.cos(th)) * cross @ cross
        return self.rotations[k] @ rot, (1 - s) * self.translations[k] + s * self.translations[k + 1]

    def apply(self, p, t: float) -> np.ndarray:
        """Points p (N,3) of the collider's frame placed in the world at time t [s]."""
        r, tr = self.pose(t)
        return np.asarray(p, dtype=np.float64) @ r.T + tr

    # -- fields and kernel-side evaluation ---------------------------------------------------------------

    def allocate(self) -> None:
        """Write the keyframes into fields (once per Taichi program, after Taichi is initialised; models
        sharing this motion share the fields)."""
        program = impl.get_runtime().prog
        if self._program is program:
            return
        self._program = program
        k = self.count
        span = np.diff(self.times) if k > 1 else np.zeros(0)
        quats = np.array([matrix_to_quat(r) for r in self.rotations])
        # Per segment (the last row unused): rotation axis and half angle in the keyframe's frame, the
        # world angular velocity R_k a_k theta_k / dt_k and the translation's velocity.
        omega = np.zeros((k, 3))
        vel = np.zeros((k, 3))
        if k > 1:
            omega[:-1] = (
                np.einsum("kij,kj->ki", self.rotations[:-1], self.axes[:-1])
                * (self.angles[:-1] / span)[:, None]
            )
            vel[:-1] = np.diff(self.translations, axis=0) / span[:, None]
        self.key_t = ti.field(float, k)
        self.key_T = ti.Vector.field(3, float, k)
        self.key_q = ti.Vector.field(4, float, k)
        self.seg_axis = ti.Vector.field(3, float, k)
        self.seg_half_angle = ti.field(float, k)
        self.seg_omega = ti.Vector.field(3, float, k)
        self.seg_velocity = ti.Vector.field(3, float, k)
        bulk.fill(  # one launch: from_numpy is a kernel per field (bulk.py)
            [
                (self.key_t, self.times),
                (self.key_T, self.translations),
                (self.key_q, quats),
                (self.seg_axis, self.axes),
                (self.seg_half_angle, 0.5 * self.angles),
                (self.seg_omega, omega),
                (self.seg_velocity, vel),
            ]
        )

    @ti.func
    def _segment(self, t):
        return keyframe_segment(self.key_t, self.count, t)

    @ti.func
    def pose_at(self, t):
        """(q, T) at time t: the rotation as a unit quaternion (x, y, z, w) and the translation."""
        k, s = self._segment(t)
        return self._pose(k, s)

    @ti.func
    def _pose(self, k, s):
        q = self.key_q[k]
        tr = self.key_T[k]
        if ti.static(self.count > 1):
            half = s * self.seg_half_angle[k]
            q = quat_mul(q, _vec4(ti.sin(half) * self.seg_axis[k], ti.cos(half)))
            tr = (1.0 - s) * tr + s * self.key_T[k + 1]
        return q, tr

    @ti.func
    def motion_at(self, t):
        """(q, T, omega, dT/dt) at time t: the pose and its angular and linear velocity (0 outside the
        keyframes, where the pose is held)."""
        k, s = self._segment(t)
        q, tr = self._pose(k, s)
        omega = ti.Vector.zero(float, 3)
        vel = ti.Vector.zero(float, 3)
        if ti.static(self.count > 1):
            if self.key_t[0] < t and t < self.key_t[self.count - 1]:
                omega = self.seg_omega[k]
                vel = self.seg_velocity[k]
        return q, tr, omega, vel

    @ti.func
    def to_local(self, x, t):
        """World point x at time t in the collider's frame."""
        q, tr = self.pose_at(t)
        return quat_rotate_inverse(q, x - tr)

    @ti.func
    def to_world(self, p, t):
        """Point p of the collider's frame in the world at time t."""
        q, tr = self.pose_at(t)
        return quat_rotate(q, p) + tr

    @ti.func
    def rotate(self, n, t):
        """A direction of the collider's frame in the world at time t."""
        q, _ = self.pose_at(t)
        return quat_rotate(q, n)

    @ti.func
    def velocity(self, x, t):
        """Velocity [m/s] at time t of the collider's material point at world position x:
        omega x (x - T) + dT/dt, with omega = R_k a_k theta_k / (t_{k+1} - t_k) on segment k (slerp turns
        at a constant rate about an axis that the rotation leaves fixed); 0 outside the keyframes."""
        _, tr, omega, vel = self.motion_at(t)
        return omega.cross(x - tr) + vel


@ti.func
def keyframe_segment(key_t: ti.template(), count: ti.template(), t):
    """(k, s): the segment k of the `count` keyframe times key_t that holds t, and the fraction s in
    [0, 1] along it, t clamped to the keyframes. A binary search unrolled to a fixed number of branch-free
    halvings: small code, as it is inlined in every collider test."""
    k = 0
    s = ti.cast(0.0, float)
    if ti.static(count > 1):
        last = count - 1
        tc = ti.min(ti.max(t, key_t[0]), key_t[last])
        lo, hi = 0, last
        for _ in ti.static(range(max(1, math.ceil(math.log2(count - 1))))):
            mid = (lo + hi) // 2
            go = key_t[mid] <= tc  # invariant: key_t[lo] <= tc <= key_t[hi]
            lo = ti.select(go, mid, lo)
            hi = ti.select(go, hi, mid)
        k = ti.min(lo, last - 1)
        s = ti.min((tc - key_t[k]) / (key_t[k + 1] - key_t[k]), 1.0)
    return k, s


@ti.func
def _vec4(v, w):
    return ti.Vector([v[0], v[1], v[2], w], dt=float)


@ti.func
def quat_mul(a, b):
    """Hamilton product of quaternions (x, y, z, w)."""
    u = ti.Vector([a[0], a[1], a[2]], dt=float)
    v = ti.Vector([b[0], b[1], b[2]], dt=float)
    return _vec4(a[3] * v + b[3] * u + u.cross(v), a[3] * b[3] - u.dot(v))


@ti.func
def quat_rotate(q, v):
    """v rotated by the unit quaternion q (x, y, z, w): v + 2 u x (u x v + w v)."""
    u = ti.Vector([q[0], q[1], q[2]], dt=float)
    return v + 2.0 * u.cross(u.cross(v) + q[3] * v)


@ti.func
def quat_rotate_inverse(q, v):
    """v rotated by the inverse (conjugate) of the unit quaternion q."""
    u = ti.Vector([q[0], q[1], q[2]], dt=float)
    return v + 2.0 * u.cross(u.cross(v) - q[3] * v)


@data_oriented
class Attachment:
    """Pinned particles that follow a target trajectory a user animates: keyframes times (K,) [s]
    strictly increasing and positions (K, P, 3) [m], linearly interpolated and held outside the range,
    or a RigidMotion that carries the particles' positions as built (rest (P, 3) [m]) rigidly. The
    Stepper sets x = target(t + h) and v = (target(t + h) - x(t)) / h at the end of each step."""

    def __init__(self, particles, *, times=None, positions=None, motion=None, rest=None):
        self.particles = np.asarray(particles, dtype=np.int64)
        self.count = len(self.particles)
        self.motion = motion
        self.moving_rigidly = motion is not None  # compile-time branch
        if motion is None:
            self.times = _times(times)
            self.positions = validate.finite_array("positions", positions)
            want = (len(self.times), self.count, 3)
            if self.positions.shape != want:
                raise ParameterError(
                    f"positions must have shape (K, P, 3) = {want} (K keyframe times, P particles), "
                    f"got {self.positions.shape}"
                )
        else:
            self.rest = np.asarray(rest, dtype=np.float64)
        self._program = None

    def settings(self) -> dict:
        out = {"particles": self.count}
        if self.motion is not None:
            out["motion"] = self.motion.settings()
        else:
            out["keyframes"] = len(self.times)
        return out

    def target(self, t: float) -> np.ndarray:
        """(P, 3) target positions [m] at time t [s] (NumPy; the kernels evaluate the same)."""
        if self.motion is not None:
            return self.motion.apply(self.rest, t)
        times = self.times
        if len(times) == 1 or t <= times[0]:
            return self.positions[0].copy()
        if t >= times[-1]:
            return self.positions[-1].copy()
        k = int(np.searchsorted(times, t, side="right")) - 1
        s = (t - times[k]) / (times[k + 1] - times[k])
        return (1.0 - s) * self.positions[k] + s * self.positions[k + 1]

    def allocate(self) -> None:
        """Write the keyframes (or the rest positions and the motion) into fields, once per program."""
        program = impl.get_runtime().prog
        if self._program is program:
            return
        self._program = program
        f = np_float()
        if self.motion is not None:
            self.motion.allocate()
            self.rest_x = ti.Vector.field(3, float, self.count)
            self.rest_x.from_numpy(self.rest.astype(f))
        else:
            self.key_count = len(self.times)
            self.key_t = ti.field(float, self.key_count)
            self.key_x = ti.Vector.field(3, float, (self.key_count, self.count))
            self.key_t.from_numpy(self.times.astype(f))
            self.key_x.from_numpy(self.positions.astype(f))

    @ti.func
    def position(self, j, t):
        """Target position of the attachment's particle j at time t."""
        x = ti.Vector.zero(float, 3)
        if ti.static(self.moving_rigidly):
            x = self.motion.to_world(self.rest_x[j], t)
        else:
            k, s = keyframe_segment(self.key_t, self.key_count, t)
            x = self.key_x[k, j]
            if ti.static(self.key_count > 1):
                x = (1.0 - s) * x + s * self.key_x[k + 1, j]
        return x


def attachment_codes(particle_count: int, attachments, field=None) -> "ti.Field":
    """(N,) int32 field: for each particle -1, or j * A + a for particle j of attachment a (A of them);
    `field`: the int32 field to fill (its rows past N get -1 too), or None for a new one of N rows."""
    count = len(attachments)
    field = ti.field(ti.i32, particle_count) if field is None else field
    codes = np.full(field.shape[0], -1, dtype=np.int32)
    for a, att in enumerate(attachments):
        att.allocate()
        codes[att.particles] = np.arange(att.count) * count + a
    field.from_numpy(codes)
    return field


@ti.func
def follow_attachments(attachments: ti.template(), codes: ti.template(), i, x0, x, v, t_end, h):
    """(x, v) of particle i at the end of a step of length h ending at t_end: its target and the
    velocity that reaches it from x0, if the particle is attached; else x, v unchanged."""
    code = codes[i]
    if code >= 0:
        count = ti.static(len(attachments))
        a = code % count
        j = code // count
        for k in ti.static(range(count)):
            if a == k:
                x = attachments[k].position(j, t_end)
        v = (x - x0) / h
    return x, v
