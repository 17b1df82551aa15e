"""The rigid kind's state part: per body the centre of mass, the orientation of its principal frame,
the velocity, the angular velocity (world axes) and the external force and torque the user applies;
their NumPy access in the user's frame (the shape's origin and orientation)."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import bulk, validate
from ...errors import ParameterError
from ...runtime import data_oriented
from .quaternion import matrix_to_quat, quat_conjugate, quat_product, quat_to_matrix


@dataclass
class RigidSnapshot:
    """Rigid bodies at one instant, as NumPy arrays in the frames `add_rigid_body` took: position (B,3)
    [m] of each shape's origin, orientation (B,4) (x, y, z, w) of its frame, velocity (B,3) [m/s] of its
    centre of mass, angular_velocity (B,3) [rad/s] in world axes; com (B,3) [m] the centres of mass."""

    time: float
    position: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    com: np.ndarray


@data_oriented
class RigidState:
    """State methods of the rigid kind (the State inherits them): rigid_x (B,3) [m] centres of mass,
    rigid_q (B,4) orientations of the principal frames, rigid_v (B,3) [m/s], rigid_w (B,3) [rad/s] in
    world axes, rigid_force (B,3) [N] and rigid_torque (B,3) [N m] applied at the centre of mass and kept
    until changed (set_rigid_force). None without bodies."""

    def _init_rigid(self, model) -> None:
        self.rigid_x = self.rigid_q = self.rigid_v = self.rigid_w = None
        self.rigid_force = self.rigid_torque = None
        if not model.rigid_count:
            return
        arr = model.rigid_array
        self.rigid_x = arr(self, "rigid_x", dims=(3,))
        self.rigid_q = arr(self, "rigid_q", dims=(4,))
        self.rigid_v = arr(self, "rigid_v", dims=(3,))
        self.rigid_w = arr(self, "rigid_w", dims=(3,))
        self.rigid_force = arr(self, "rigid_force", dims=(3,))
        self.rigid_torque = arr(self, "rigid_torque", dims=(3,))

    def _start_rigid(self, model) -> None:
        if not model.rigid_count:
            return
        start = {k: v.copy() for k, v in model._rigid_start.items()}
        for k, motion, x0, q0 in model.rigid_motions:  # keyframed: where the keyframes have it at t = 0
            r, tr = motion.pose(0.0)
            start["x"][k] = r @ np.asarray(x0) + tr
            start["q"][k] = quat_product(matrix_to_quat(r), np.asarray(q0))
        zero = model.rigid_padded(np.zeros((model.rigid_count, 3)))
        fills = [(getattr(self, f"rigid_{n}"), model.rigid_padded(start[n])) for n in ("x", "q", "v", "w")]
        bulk.fill([*fills, (self.rigid_force, zero), (self.rigid_torque, zero)])  # one launch (bulk.py)

    def _save_rigid(self, into, whole_trail: bool) -> None:
        if self.model.rigid_count:
            self._copy_rigid(self.model, self, into)

    @ti.kernel
    def _copy_rigid(self, model: ti.template(), src: ti.template(), dst: ti.template()):
        for i in range(model.live_rigid()):
            dst.rigid_x[i] = src.rigid_x[i]
            dst.rigid_q[i] = src.rigid_q[i]
            dst.rigid_v[i] = src.rigid_v[i]
            dst.rigid_w[i] = src.rigid_w[i]
            dst.rigid_force[i] = src.rigid_force[i]
            dst.rigid_torque[i] = src.rigid_torque[i]

    def _rigid_rows(self, field) -> np.ndarray:
        return bulk.read([field], self.model.rigid_count)[0].astype(np.float64)

    def rigid_snapshot(self) -> RigidSnapshot:
        """The bodies now, in the frames add_rigid_body took (see RigidSnapshot)."""
        model = self.model
        b = model.rigid_count
        if not b:
            z3, z4 = np.zeros((0, 3)), np.zeros((0, 4))
            return RigidSnapshot(self.time, z3, z4, z3, z3, z3)
        rows = bulk.read([self.rigid_x, self.rigid_q, self.rigid_v, self.rigid_w], b)  # one launch
        x, q, v, w = (a.astype(np.float64) for a in rows)
        q_shape = quat_product(q, quat_conjugate(model.rigid_principal))
        q_shape /= np.linalg.norm(q_shape, axis=1, keepdims=True)
        origin = x - np.einsum("bij,bj->bi", quat_to_matrix(q_shape), model.rigid_com)
        return RigidSnapshot(self.time, origin, q_shape, v, w, x)

    def set_rigid_force(self, body: int, force=(0.0, 0.0, 0.0), *, point=None, torque=(0.0, 0.0, 0.0)):
        """Apply `force` [N] (world axes) to `body` at world `point` [m] (default: its centre of mass)
        plus a pure `torque` [N m], from now until changed (set zeros to stop). The force acts at the
        centre of mass with the torque (point - com) x force added."""
        body = validate.count("body", body, 0, max(self.model.rigid_count - 1, 0))
        if not self.model.rigid_count:
            raise ParameterError("set_rigid_force: the scene has no rigid bodies")
        f = np.asarray(validate.vec3("force", force))
        tau = np.asarray(validate.vec3("torque", torque))
        if point is not None:
            com = self._rigid_rows(self.rigid_x)[body]
            tau = tau + np.cross(np.asarray(validate.vec3("point", point)) - com, f)
        self.rigid_force[body] = f.tolist()
        self.rigid_torque[body] = tau.tolist()
