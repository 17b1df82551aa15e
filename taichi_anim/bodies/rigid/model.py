"""The rigid kind's model part: per body its shape, mass, inertia and the frame its dynamics runs in
(centre of mass and principal axes), as NumPy arrays for users and as fields for kernels."""

import numpy as np
import taichi as ti

from ... import capacity
from ...runtime import data_oriented, np_float


@data_oriented
class RigidModel:
    """Model methods of the rigid kind (the Model inherits them).

    rigid_count; rigid_mass (B,) [kg]; rigid_inertia (B,3,3) [kg m^2] about the centre of mass, in the
    body's (shape's) frame; rigid_com (B,3) [m] the centre of mass in that frame; rigid_kinematic (B,)
    bool; rigid_shapes: the shapes. Fields for kernels (None without bodies): rigid_inv_mass (B,)
    [1/kg] and rigid_inv_moments (B,3) [1/(kg m^2)] in the principal frame (0 for kinematic bodies)."""

    def _init_rigid(self, *, bodies) -> None:
        b = len(bodies)
        self.rigid_count = b
        self.rigid_shapes = tuple(x["shape"] for x in bodies)
        stack = lambda k, shape: np.array([x[k] for x in bodies], dtype=np.float64).reshape((b, *shape))
        self.rigid_mass = stack("mass", ())
        self.rigid_inertia = stack("inertia", (3, 3))
        self.rigid_com = stack("com", (3,))
        self.rigid_principal = stack("principal", (4,))  # principal frame -> shape frame
        self.rigid_moments = stack("moments", (3,))
        self.rigid_kinematic = np.array([x["kinematic"] for x in bodies], dtype=bool)
        self._rigid_start = {k: stack(k, (n,)) for k, n in (("x", 3), ("q", 4), ("v", 3), ("w", 3))}
        for a in (self.rigid_mass, self.rigid_inertia, self.rigid_com, self.rigid_kinematic):
            a.setflags(write=False)
        # The options the Stepper builds the bodies' solver from (solvers.SOLVERS): none to give.
        self.rigid_dynamics = {} if b else None
        self.rigid_capacity = capacity.bucket(b) if self.size_buckets else b
        self.rigid_live = self.rigid_inv_mass = self.rigid_inv_moments = None
        if not b:
            return
        if self.size_buckets:
            self.rigid_live = self.new_field(self, "rigid_live", ti.i32, ())
            self.rigid_live[None] = b
        dynamic = ~self.rigid_kinematic
        self.rigid_inv_mass = self.rigid_array(self, "rigid_inv_mass")
        self.rigid_inv_mass.from_numpy(self.rigid_padded(np.where(dynamic, 1.0 / self.rigid_mass, 0.0)))
        self.rigid_inv_moments = self.rigid_array(self, "rigid_inv_moments", dims=(3,))
        inv = np.where(dynamic[:, None], 1.0 / self.rigid_moments, 0.0)
        self.rigid_inv_moments.from_numpy(self.rigid_padded(inv))

    def rigid_array(self, owner, role: str, dtype=float, dims: tuple = ()):
        """A field of rigid_capacity rows with elements of `dims`, for `owner` (pooled under buckets)."""
        return self.new_field(owner, role, dtype, (self.rigid_capacity,), dims)

    def rigid_padded(self, a) -> np.ndarray:
        """`a` (rigid_count rows) with zero rows up to rigid_capacity, as the float fields' dtype."""
        return capacity.padded(a, self.rigid_capacity, np_float())

    @ti.func
    def live_rigid(self):
        """Bodies the kernels loop over (a 0-d field under buckets, else a compile-time constant)."""
        if ti.static(self.size_buckets):
            return self.rigid_live[None]
        else:
            return self.rigid_count
