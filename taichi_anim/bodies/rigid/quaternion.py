"""Unit quaternions (x, y, z, w) for rigid-body orientation, in Taichi scope and in NumPy. q rotates a
vector as q v q*; q1 * q2 applies q2 first (Hamilton product, as Eigen, Newton and USD's quatf)."""

import numpy as np
import taichi as ti

# The Hamilton product and quaternion -> matrix are the colliders' motion's and rotations.py's.
from ...collision.motion import quat_mul as quat_mul
from ...rotations import matrix_to_quat as _matrix_to_quat
from ...rotations import quat_to_matrix as quat_to_matrix


@ti.func
def quat_matrix(q):
    """The rotation matrix of a unit quaternion q."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    return ti.Matrix(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@ti.func
def quat_rotation(w, h):
    """The unit quaternion of a rotation by angle |w| h about w / |w| (w [rad/s], h [s]): exp(h w / 2)."""
    angle = w.norm() * h
    s = 0.5 * h  # sin(x)/x -> 1 as the angle vanishes: the axis part is h w / 2 then
    if angle > 1e-8:
        s = ti.sin(0.5 * angle) / angle * h
    return ti.Vector([w[0] * s, w[1] * s, w[2] * s, ti.cos(0.5 * angle)])


@ti.func
def world_inverse_inertia(r, inv_moments):
    """R diag(inv_moments) R^T: a body's inverse inertia in world axes, its principal frame at R."""
    return (
        r
        @ ti.Matrix([[inv_moments[0], 0, 0], [0, inv_moments[1], 0], [0, 0, inv_moments[2]]])
        @ r.transpose()
    )


@ti.func
def quat_normalized(q):
    return q / q.norm()


def matrix_to_quat(r) -> np.ndarray:
    """A proper rotation matrix (3,3) -> its unit quaternion (x, y, z, w), with w >= 0."""
    q = _matrix_to_quat(np.asarray(r, dtype=np.float64))
    return q if q[3] >= 0 else -q


def quat_product(a, b) -> np.ndarray:
    """The Hamilton product a b of (..., 4) quaternions (x, y, z, w), in NumPy."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    av, bv, aw, bw = a[..., :3], b[..., :3], a[..., 3:], b[..., 3:]
    v = aw * bv + bw * av + np.cross(av, bv)
    return np.concatenate([v, aw * bw - np.sum(av * bv, axis=-1, keepdims=True)], axis=-1)


def quat_conjugate(q) -> np.ndarray:
    q = np.array(q, dtype=np.float64)
    q[..., :3] *= -1.0
    return q
