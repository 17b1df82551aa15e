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
from .sph_kernel import cubic_w_numpy


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

    def __init__(self, model, *, spacing: float, support: float, rest_density: float, layer_share: float,
                 make):  # fmt: skip
        local, owner = body_samples(model, spacing)
        self.count = len(local)
        self.support, self.rest_density, self.layer_share = support, rest_density, layer_share
        self.local = make(self, "fluid_body_local", float, self.count, (3,))
        self.owner = make(self, "fluid_body_owner", ti.i32, self.count)
        self.psi = make(self, "fluid_body_psi", float, self.count)
        self.x = make(self, "fluid_body_x", float, self.count, (3,))  # world, at the substep's start
        self.v = make(self, "fluid_body_v", float, self.count, (3,))
        self.local.from_numpy(local.astype(np_float()))
        self.owner.from_numpy(owner.astype(np.int32))
        self.psi.from_numpy(self._volumes(local, owner, spacing).astype(np_float()))
        b = model.rigid_count
        self.impulse = make(self, "fluid_body_impulse", float, b, (3,))
        self.moment = make(self, "fluid_body_moment", float, b, (3,))

    def _volumes(self, local, owner, spacing: float) -> np.ndarray:
        """psi_b = rho0 V_b, V_b = 1 / sum over the same body's samples of W (boundary.py), per body with
        NumPy in blocks of rows (bodies hold a few thousand samples)."""
        psi = np.zeros(len(local))
        for b in np.unique(owner):
            idx = np.flatnonzero(owner == b)
            x = local[idx]
            total = np.zeros(len(idx))
            for s in range(0, len(idx), 512):
                r = np.linalg.norm(x[s : s + 512, None, :] - x[None, :, :], axis=2)
                total[s : s + 512] = cubic_w_numpy(r, self.support).sum(axis=1)
            psi[idx] = self.layer_share * self.rest_density / total
        return psi

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
