"""Rotations as unit quaternions (x, y, z, w, scalar last, as in SciPy and Warp) and 3x3 matrices, in
NumPy: what colliders' keyframed motion and rigid bodies both convert with."""

import numpy as np


def quat_to_matrix(q) -> np.ndarray:
    """(..., 4) unit quaternions (x, y, z, w) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """(3,3) rotation matrix -> unit quaternion (x, y, z, w), from the largest of the four squared
    components (Shepperd, J. Guidance and Control 1(3), 1978), so no division by a small number."""
    tr = np.trace(m)
    cand = [tr, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(cand))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    else:
        i = k - 1
        j, c = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[c, c])
        q = [0.0, 0.0, 0.0, (m[c, j] - m[j, c]) / s]
        q[i] = 0.25 * s
        q[j] = (m[j, i] + m[i, j]) / s
        q[c] = (m[c, i] + m[i, c]) / s
    q = np.asarray(q)
    return q / np.linalg.norm(q)
