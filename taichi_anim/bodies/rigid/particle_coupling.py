"""Particles and rigid bodies acting on each other: particles, hard spheres and cloth vertices hit bodies
and push them, with equal and opposite impulses.

After the particle method's step, each particle inside a body (its centre closer than its radius to the
body's surface: the body's signed distance, geometry.py) and approaching it takes the impulse of a
frictional impact against the body's moving surface, j = -(1 + e) v_n / K with
K = 1/m + 1/M + n . ((I^-1 (r x n)) x r) (Mirtich & Canny, "Impulse-based simulation of rigid bodies",
1995, eq. 4; the particle is a point mass), Coulomb friction up to mu j; the body takes -j at the contact
point. The particle is then moved out to the surface (a position correction, no momentum). The body's
restitution and friction coefficients are used. A cloth vertex is a particle: a cloth lying on a body
weighs on it through these impulses.

Liquid particles are left out: they meet bodies through the liquid's pressure solve (bodies/fluid/).

The loop runs serially over the particles (each one's impulses land on the bodies in particle order: the
result does not depend on the thread count), testing every body's bounding sphere first."""

import taichi as ti

from ...runtime import compile_with, data_oriented
from .narrow_phase import body_sdf
from .quaternion import quat_matrix, world_inverse_inertia


@data_oriented
class ParticleCoupling:
    """The particle-body impacts of a model with particles and rigid bodies (owned by the bodies'
    solver); `impacts` counts the impulses of the last step."""

    def __init__(self, model):
        self.rot = model.rigid_array(self, "pc_rot", dims=(3, 3))
        self.inv_inertia = model.rigid_array(self, "pc_inv_inertia", dims=(3, 3))
        self.count = model.new_field(self, "pc_impacts", ti.i32, ())
        self.time = model.new_field(self, "pc_time", float, ())  # the colliders' time, for moving ones

    @property
    def impacts(self) -> int:
        """Particle-body impulses applied in the last step."""
        return int(self.count[None])

    @compile_with(cfg_optimization=False, advanced_optimization=False)
    @ti.kernel
    def apply(self, model: ti.template(), state: ti.template(), t: float):
        """Impacts of the particles alive at t [s] (the end of the particle step) on the bodies."""
        ti.loop_config(serialize=model.rigid_serial)
        for b in range(model.live_rigid()):
            r = quat_matrix(state.rigid_q[b])
            self.rot[b] = r
            inv = model.rigid_inv_moments[b]
            self.inv_inertia[b] = world_inverse_inertia(r, inv)
        self.count[None] = 0
        self.time[None] = t
        ti.loop_config(serialize=True)
        for i in range(model.live_particles()):
            if model.alive(state, i, t) and not model.liquid(i):
                self._particle(model, state, i)

    @ti.func
    def _outside_colliders(self, model: ti.template(), x, radius):
        """x moved out of any collider it was pushed into: a vertex squeezed between a body and the floor
        stays on the floor's side (colliders do not move; the body is pushed by the impulse instead)."""
        for c in ti.static(model.colliders):
            d, n, _ = c.contact(x, self.time[None])
            if d < radius:
                x += (radius - d) * n
        return x

    @ti.func
    def _particle(self, model: ti.template(), state: ti.template(), i):
        x, v = state.particle_x[i], state.particle_v[i]
        im, radius = model.inv_mass(i), model.radius(i)
        for b in range(model.live_rigid()):
            xb = state.rigid_x[b]
            if (x - xb).norm() < model.rigid_bound[b] + radius:
                d, n = body_sdf(model, b, xb, self.rot[b], x)
                sep = d - radius
                if sep < 0.0:
                    arm = x - radius * n - xb
                    vrel = v - state.rigid_v[b] - state.rigid_w[b].cross(arm)
                    vn = vrel.dot(n)
                    if vn < 0.0:
                        imb = model.rigid_inv_mass[b]
                        k = im + imb + n.dot((self.inv_inertia[b] @ arm.cross(n)).cross(arm))
                        if k > 0.0:
                            j = -(1.0 + model.rigid_restitution[b]) * vn / k
                            slip = vrel - vn * n
                            p = j * n
                            speed = slip.norm()
                            if speed > 1e-12:
                                # friction: stop the slip if the cone allows it, else slide at mu j
                                p -= ti.min(model.rigid_friction[b] * j, speed / k) * slip / speed
                            v += p * im
                            state.rigid_v[b] -= p * imb
                            state.rigid_w[b] -= self.inv_inertia[b] @ arm.cross(p)
                            self.count[None] += 1
                    if im > 0.0:
                        x -= sep * n  # out to the surface
                        x = self._outside_colliders(model, x, radius)
        state.particle_x[i] = x
        state.particle_v[i] = v
