"""Rigid bodies in the liquid, two ways (Akinci et al., "Versatile Rigid-Fluid Coupling for
Incompressible SPH", SIGGRAPH 2012, sec. 4): every body's surface carries boundary samples (half a
spacing inside, as the walls' in boundary.py) that move with it. A fluid particle counts them in its
density and its pressure solves like the walls' samples, moving at the body's velocity at the sample,
v_b = v + w x (x_b - x); each pair's pressure correction of the particle, m_i dv_i = -m_i h kappa_i
psi_b grad W_ib, is given back to the body as the opposite impulse at the sample (eq. 11-12: the body
takes -F_i<-b), so momentum is exchanged exactly and a body floats where the pressure's push balances
its weight (Archimedes).

The impulses are summed serially over the fluid particles (the same order at any thread count) and
applied to the bodies' velocities after each solve; the bodies' solver, first in the Stepper's list,
moves them with those velocities in the next substep."""

import numpy as np
import taichi as ti

from ...rotations import quat_to_matrix
from ...runtime import data_oriented, np_float
from ..rigid.quaternion import quat_matrix
from .boundary import mesh_samples


def body_samples(model, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(local (S,3) [m] in each body's principal frame about its centre of mass, body (S,) int): samples
    about `spacing` apart, half a spacing inside every body's surface (shape.triangles())."""
    local, owner = [], []
    for b, shape in enumerate(model.rigid_shapes):
        v, f = shape.triangles()
        x = mesh_samples(np.asarray(v, dtype=np.float64), f, spacing)
        key = np.round(x / (1e-4 * spacing)).astype(np.int64)
        x = x[np.sort(np.unique(key, axis=0, return_index=True)[1])]
        to_shape = quat_to_matrix(model.rigid_principal[b])  # principal frame -> shape frame
        local.append((x - model.rigid_com[b]) @ to_shape)
        owner.append(np.full(len(x), b))
    return np.concatenate(local), np.concatenate(owner)


@data_oriented
class BodySamples:
    """The boundary samples of a model's rigid bodies: local positions, owners and volumes (static),
    world positions and velocities (each substep), the impulses the liquid gives back."""

    def __init__(self, model, spacing: float, make):
        local, owner = body_samples(model, spacing)
        self.count = len(local)
        self._local, self._owner = local, owner
        self.local = make(self, "fluid_body_local", float, self.count, (3,))
        self.owner = make(self, "fluid_body_owner", ti.i32, self.count)
        self.psi = make(self, "fluid_body_psi", float, self.count)  # filled by the solver (_volumes)
        self.x = make(self, "fluid_body_x", float, self.count, (3,))  # world, at the substep's start
        self.v = make(self, "fluid_body_v", float, self.count, (3,))
        self.local.from_numpy(local.astype(np_float()))
        self.owner.from_numpy(owner.astype(np.int32))
        b = model.rigid_count
        self.impulse = make(self, "fluid_body_impulse", float, b, (3,))
        self.moment = make(self, "fluid_body_moment", float, b, (3,))

    def apart(self, reach: float):
        """(positions field (S,3), lo, hi): every body's samples in its own frame, the bodies set side by
        side along x more than `reach` [m] apart, so that a neighbour search finds each body's own
        samples only (their volumes, psi_b)."""
        extent = float(np.abs(self._local).max()) if self.count else 0.0
        step = 2.0 * extent + 2.0 * reach
        x = self._local.copy()
        x[:, 0] += step * self._owner
        field = ti.Vector.field(3, float, self.count)
        field.from_numpy(x.astype(np_float()))
        return field, x.min(axis=0) - reach, x.max(axis=0) + reach

    @ti.kernel
    def place(self, model: ti.template(), state: ti.template()):
        """World positions and velocities of the samples from the bodies' poses now."""
        for s in range(self.count):
            b = self.owner[s]
            arm = quat_matrix(state.rigid_q[b]) @ self.local[s]
            self.x[s] = state.rigid_x[b] + arm
            self.v[s] = state.rigid_v[b] + state.rigid_w[b].cross(arm)

    @ti.kernel
    def move(self, model: ti.template(), state: ti.template()):
        """The samples' velocities from the bodies' velocities now (positions stay the substep's start)."""
        for s in range(self.count):
            b = self.owner[s]
            self.v[s] = state.rigid_v[b] + state.rigid_w[b].cross(self.x[s] - state.rigid_x[b])
