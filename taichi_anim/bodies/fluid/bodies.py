"""Rigid bodies in the liquid, two ways (Akinci et al., "Versatile Rigid-Fluid Coupling for
Incompressible SPH", SIGGRAPH 2012, sec. 4): every body's surface carries boundary samples (half a
spacing inside, as the walls' in boundary.py) that move with it. A fluid particle counts them in its
density and its pressure solves like the walls' samples, moving at the body's velocity at the sample,
v_b = v + w x (x_b - x); each pair's pressure correction of the particle, m_i dv_i = -m_i h kappa_i
psi_b grad W_ib, is given back to the body as the opposite impulse at the sample (eq. 11-12: the body
takes -F_i<-b), so momentum is exchanged exactly and a body floats where the pressure's push balances
its weight (Archimedes).

Cloth couples the same way, as a sheet: samples about a spacing apart on every cloth triangle (at
fixed barycentric coordinates, so they follow the cloth as it deforms), moving at the interpolated
vertex velocities; each impulse goes back to the triangle's three vertices by the same weights. A
sheet has no inside: its samples lie on it and the liquid stays about a spacing from it on either side.

The impulses are summed serially over the fluid particles (the same order at any thread count) and
applied to the bodies' and the cloth vertices' velocities after each solve; the bodies' solver, first
in the Stepper's list, and the method move them with those velocities in the next substep."""

import numpy as np
import taichi as ti

from ... import bulk
from ...rotations import quat_to_matrix
from ...runtime import data_oriented
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


def cloth_samples(model, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rest positions (S,3) [m], triangle corners (S,3) particle indices, barycentric weights (S,3)):
    samples at most `spacing` apart on every cloth triangle (model.triangles), each point once."""
    if model.triangle_count == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3))
    x0 = model._x0
    rest, corners, weights = [], [], []
    for tri in model.triangles:
        a, b, c = x0[tri[0]], x0[tri[1]], x0[tri[2]]
        nu = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing)))
        nv = max(1, int(np.ceil(np.linalg.norm(c - a) / spacing)))
        i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
        u, v = (i / nu).ravel(), (j / nv).ravel()
        keep = u + v <= 1.0 + 1e-9
        w = np.stack([1.0 - u[keep] - v[keep], u[keep], v[keep]], 1)
        rest.append(w @ np.stack([a, b, c]))
        corners.append(np.broadcast_to(tri, w.shape))
        weights.append(w)
    rest, corners, weights = np.concatenate(rest), np.concatenate(corners), np.concatenate(weights)
    key = np.round(rest / (1e-4 * spacing)).astype(np.int64)
    first = np.sort(np.unique(key, axis=0, return_index=True)[1])  # a shared edge's points once
    return rest[first], corners[first], weights[first]


def sphere_particles(model) -> np.ndarray:
    """(P,) the hard spheres the liquid meets: added particles of radius > 0, neither liquid nor a cloth's
    vertices (nor an emitter's, whose particles come and go)."""
    n = model._static_count
    keep = model.particle_radii(np.arange(n)) > 0.0
    keep[model.fluid_particles[model.fluid_particles < n]] = False
    if model.triangle_count:
        keep[np.unique(model.triangles)] = False
    return np.flatnonzero(keep)


def sphere_samples(model, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(offsets (S,3) [m] from their sphere's centre, sphere particle (S,), sphere number (S,)): points
    about a spacing apart (a Fibonacci lattice) on a sphere half a spacing inside each hard sphere's
    surface; a sphere of less than 3/4 of a spacing's radius gets one sample, at its centre."""
    spheres = sphere_particles(model)
    radius = model.particle_radii(spheres).astype(np.float64)
    offsets, owner, number = [], [], []
    for k, p in enumerate(spheres):
        r = radius[k] - 0.5 * spacing
        count = max(1, round(4.0 * np.pi * r * r / (spacing * spacing))) if r >= 0.25 * spacing else 1
        if count == 1:
            o = np.zeros((1, 3))
        else:
            i = np.arange(count) + 0.5
            z = 1.0 - 2.0 * i / count
            t = np.pi * (1.0 + 5.0**0.5) * i
            ring = np.sqrt(1.0 - z * z)
            o = r * np.stack([ring * np.cos(t), z, ring * np.sin(t)], 1)
        offsets.append(o)
        owner.append(np.full(len(o), p))
        number.append(np.full(len(o), k))
    if not offsets:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(offsets), np.concatenate(owner), np.concatenate(number)


@data_oriented
class BodySamples:
    """The boundary samples that move: the rigid bodies' (local positions, owner >= 0), and points that
    follow particles (owner -1): the cloth's (triangle corners and weights) and the hard spheres' (the
    sphere's particle with weight 1, and an offset). Their volumes (static), world positions and
    velocities (each substep), the impulses the liquid gives back."""

    def __init__(self, model, spacing: float, make):
        local, owner = body_samples(model, spacing) if model.rigid_count else (np.zeros((0, 3)), np.zeros(0))
        rest, corners, weights = cloth_samples(model, spacing)
        offsets, sphere, number = sphere_samples(model, spacing)
        self.rigid_count, self.cloth_count, self.sphere_count = len(local), len(rest), len(offsets)
        self.count = n = len(local) + len(rest) + len(offsets)
        self.has_rigid = model.rigid_count > 0  # compile-time
        self.has_points = len(rest) + len(offsets) > 0
        # Each sample's own group, for its volume: a body, the cloth, or a sphere.
        centres = model._x0[sphere] if len(sphere) else np.zeros((0, 3))
        self._local = np.concatenate([local, rest, centres + offsets])
        b = model.rigid_count
        self._group = np.concatenate([owner, np.full(len(rest), b), b + 1 + number]).astype(np.int64)
        self._make = make  # the model's pool under capacity buckets (apart() takes a field from it too)
        self.local = make(self, "fluid_body_local", float, n, (3,))
        self.owner = make(self, "fluid_body_owner", ti.i32, n)
        self.corners = make(self, "fluid_body_corners", ti.i32, n, (3,))
        self.weights = make(self, "fluid_body_weights", float, n, (3,))
        self.psi = make(self, "fluid_body_psi", float, n)  # filled by the solver (_volumes_pass)
        self.x = make(self, "fluid_body_x", float, n, (3,))  # world, at the substep's start
        self.v = make(self, "fluid_body_v", float, n, (3,))
        zeros = np.zeros((len(rest), 3))
        one = np.zeros((len(offsets), 3))
        one[:, 0] = 1.0
        bulk.fill(  # one launch: from_numpy is a kernel per field (bulk.py)
            [
                (self.local, np.concatenate([local, zeros, offsets])),
                (self.owner, np.concatenate([owner, np.full(len(rest) + len(offsets), -1)])),
                (
                    self.corners,
                    np.concatenate([np.zeros((len(local), 3)), corners, np.repeat(sphere[:, None], 3, 1)]),
                ),
                (self.weights, np.concatenate([np.zeros((len(local), 3)), weights, one])),
            ]
        )
        self.impulse = make(self, "fluid_body_impulse", float, max(b, 1), (3,))
        self.moment = make(self, "fluid_body_moment", float, max(b, 1), (3,))

    def apart(self, reach: float):
        """(positions field (S,3), lo, hi): every body's samples in its own frame, the cloth's and the
        spheres' at rest, the groups set side by side along x more than `reach` [m] apart, so that a
        neighbour search finds each group's own samples only (their volumes, psi_b)."""
        extent = float(np.abs(self._local).max()) if self.count else 0.0
        step = 2.0 * extent + 2.0 * reach
        x = self._local.copy()
        x[:, 0] += step * self._group
        # From the pool: a new field would compile the grid's build again for the next scene in a process.
        field = self._make(self, "fluid_body_apart", float, self.count, (3,))
        bulk.fill([(field, x)])  # with the caller's other arrays, in an open bulk.batch()
        return field, x.min(axis=0) - reach, x.max(axis=0) + reach

    @ti.func
    def _point(self, state: ti.template(), s):
        """A point sample's position and velocity from its particles (a cloth triangle's corners, or a
        sphere's centre with its offset)."""
        x, v = self.local[s], ti.Vector.zero(float, 3)
        for c in ti.static(range(3)):
            i = self.corners[s][c]
            x += self.weights[s][c] * state.particle_x[i]
            v += self.weights[s][c] * state.particle_v[i]
        return x, v

    @ti.kernel
    def place(self, model: ti.template(), state: ti.template()):
        """World positions and velocities of the samples from the bodies' poses and the particles now."""
        self.place_pass(model, state)

    @ti.func
    def place_pass(self, model: ti.template(), state: ti.template()):
        """place's work, for a kernel that runs it among other passes (serial_substep.py)."""
        for s in range(self.count):
            b = self.owner[s]
            if b >= 0:
                if ti.static(self.has_rigid):
                    arm = quat_matrix(state.rigid_q[b]) @ self.local[s]
                    self.x[s] = state.rigid_x[b] + arm
                    self.v[s] = state.rigid_v[b] + state.rigid_w[b].cross(arm)
            else:
                if ti.static(self.has_points):
                    self.x[s], self.v[s] = self._point(state, s)

    @ti.kernel
    def move(self, model: ti.template(), state: ti.template()):
        """The samples' velocities from the bodies' and particles' velocities now (positions stay the
        substep's start)."""
        self.move_pass(model, state)

    @ti.func
    def move_pass(self, model: ti.template(), state: ti.template()):
        """move's work, for a kernel that runs it among other passes (serial_substep.py)."""
        for s in range(self.count):
            b = self.owner[s]
            if b >= 0:
                if ti.static(self.has_rigid):
                    self.v[s] = state.rigid_v[b] + state.rigid_w[b].cross(self.x[s] - state.rigid_x[b])
            else:
                if ti.static(self.has_points):
                    _, self.v[s] = self._point(state, s)
