"""Rigid-body dynamics: d/dt (x, q, P, L) = (v, (1/2) w q, F, tau) with v = P / m and
w = R I^-1 R^T L (Baraff, "An Introduction to Physically Based Modeling: Rigid Body Simulation I",
SIGGRAPH 1997 course notes, sec. 2.9; orientation as a unit quaternion, sec. 4.2).

The Stepper's integrator chooses how this ODE is stepped (it answers `rigid_scheme`):
- an explicit Runge-Kutta tableau (explicit Euler, midpoint, RK4, Dormand-Prince's fifth-order weights):
  the tableau on (x, q, v, L), q renormalised after the step. Explicit Euler is the course's explicit
  formulation, every rate taken at the step's start: its energy grows by O(h) per unit time on a
  tumbling body (the gyroscopic term, w x L, is integrated explicitly).
- "semi_implicit" (symplectic and implicit Euler): kick v and L by the forces and torques, drift x with
  the new v and turn the body by the exact torque-free flow of the new L, approximated by the symplectic
  splitting of Dullweber, Leimkuhler & McLachlan (J. Chem. Phys. 107, 5840, 1997, eq. 3.6): rotations
  about the principal axes 1, 2, 3, 2, 1 for h/2, h/2, h, h/2, h/2. Each rotation turns the body and its
  body-frame momentum by opposite angles, so the world L is kept to round-off and the energy error stays
  bounded (second order, no drift) at any step: this is the stable default, with the gyroscopic term
  handled by the splitting rather than by an implicit solve (Catto 2015's implicit gyroscopic step also
  stabilises it, but dissipates energy and changes L).
Kinematic bodies move at their velocities exactly. In free fall every scheme is the method's own closed
form: x_n = x0 + n h v0 + beta n h^2 g with beta = (n+1)/2 (semi-implicit), (n-1)/2 (explicit Euler) or
n/2 (Runge-Kutta of order >= 2, exact).
"""

import numpy as np
import taichi as ti

from ...collision.motion import quat_rotate
from ...errors import DivergenceError, ParameterError
from ...runtime import compile_with, data_oriented
from .contacts import RigidContacts, default_capacity
from .particle_coupling import ParticleCoupling
from .quaternion import quat_matrix, quat_mul, quat_normalized, quat_rotation

# DLM's splitting: (principal axis, fraction of the step), symmetric, so the composition is second order.
SPLITTING = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


def body_acceleration(model) -> tuple:
    """The uniform acceleration [m/s^2] the scene's pointwise terms give rigid bodies: each term that
    acts on bodies says so with `body_acceleration()` (gravity); the others act on particles only."""
    g = np.zeros(3)
    for term in model.point_terms:
        accel = getattr(term, "body_acceleration", None)
        if accel is not None:
            g += np.asarray(accel(), dtype=np.float64)
    return tuple(float(c) for c in g)


@ti.func
def angular_momentum(q, w, inv_moments):
    """L = R I R^T w [kg m^2/s] (world axes) of a body whose principal frame is at q."""
    r = quat_matrix(q)
    local = r.transpose() @ w
    return r @ ti.Vector([local[k] / inv_moments[k] for k in ti.static(range(3))])


@ti.func
def angular_velocity(q, angular_mom, inv_moments):
    """w = R I^-1 R^T L [rad/s] (world axes)."""
    r = quat_matrix(q)
    return r @ (inv_moments * (r.transpose() @ angular_mom))


@ti.func
def free_rotation(q, angular_mom, inv_moments, h):
    """The orientation after h [s] of torque-free rotation with momentum L (world axes), by DLM's
    splitting (see the module's docstring); L is unchanged by construction."""
    pi = quat_matrix(q).transpose() @ angular_mom  # the momentum in the principal frame
    for k, f in ti.static(SPLITTING):
        j, m = ti.static((k + 1) % 3, (k + 2) % 3)
        theta = f * h * pi[k] * inv_moments[k]
        c, s = ti.cos(theta), ti.sin(theta)
        turn = ti.Vector([0.0, 0.0, 0.0, ti.cos(0.5 * theta)])
        turn[k] = ti.sin(0.5 * theta)
        q = quat_mul(q, turn)  # the body turns by theta about its axis k ...
        pj, pm = pi[j], pi[m]
        pi[j] = c * pj + s * pm  # ... and its body-frame momentum by -theta
        pi[m] = -s * pj + c * pm
    return quat_normalized(q)


@ti.func
def _row(m: ti.template(), j: ti.template(), n: ti.template()):
    return ti.Vector([m[j, c] for c in ti.static(range(n))])


@ti.func
def _set_row(m: ti.template(), j: ti.template(), value: ti.template()):
    for c in ti.static(range(value.n)):
        m[j, c] = value[c]


@data_oriented
class RigidDynamics:
    """The rigid kind's time stepping, first in the Stepper's solver list: after the method advanced
    the particles by h, it advances every body by h with the method's `rigid_scheme`."""

    name = "rigid bodies"
    takes_method = True  # make_solvers passes the Stepper's integrator

    def __init__(self, model, *, method, contacts=None):
        scheme = getattr(method, "rigid_scheme", None)
        if scheme is None:
            raise ParameterError(
                f"integrator {method.name!r} cannot step rigid bodies (it has no rigid_scheme)"
            )
        self.scheme = scheme
        self.method_name = method.name
        self.gravity = body_acceleration(model)
        # The last body found non-finite (-1: none), written by the stepping kernels, read by check(). From
        # the model's pool under buckets: a new field would compile the contact step again for the next
        # scene in a process.
        self._bad = model.new_field(self, "rigid_bad", ti.i32, ())
        self._bad[None] = -1
        self.contact_options = dict(contacts or {})
        self.contacts = None
        touching = model.rigid_count > 1 or model.collider_count > 0
        if contacts is not None and touching:
            if not isinstance(scheme, str):
                raise ParameterError(
                    f"integrator {method.name!r} steps rigid bodies in free flight only: their contacts need "
                    f"a semi-implicit method ('symplectic_euler' or 'implicit_euler'), or "
                    f"Builder.set_rigid_contacts(enabled=False)"
                )
            options = dict(contacts)
            options["capacity"] = options.get("capacity") or default_capacity(model)
            self.contacts = RigidContacts(model, **options)
        # Particles (and cloth vertices) and bodies push each other, when the scene has both. Liquid
        # particles meet bodies through the liquid's pressure solve: with liquid alone there is nothing
        # to couple (and no kernel to compile: 0.56 s of the pour demo's cold start).
        coupled = model.particle_count and not model.all_liquid and contacts is not None
        self.coupling = ParticleCoupling(model) if coupled else None

    def settings(self) -> dict:
        """The scheme and the bodies' acceleration, for run.json."""
        scheme = self.scheme if isinstance(self.scheme, str) else f"runge_kutta:{self.scheme.name}"
        out = {"integrator": self.method_name, "scheme": scheme, "gravity": list(self.gravity)}
        if self.contacts is not None:
            out["contacts"] = self.contact_options
        return out

    def substeps(self, model, state, dt: float) -> int:
        return 1

    def before_substep(self, model, state, h: float) -> None:
        pass

    def after_substep(self, model, state, h: float, step: int) -> None:
        if self.coupling is not None:  # the particles have moved to the end of the substep
            self.coupling.apply(model, state, state.time + h)
        keyframed = bool(model.rigid_motions)
        if self.contacts is not None:  # a semi-implicit scheme (the constructor refuses contacts otherwise)
            self.frame(model, state, h, 1)
            return
        if keyframed:  # their velocities over the substep, for the drift
            self._keyframes(model, state, state.time + 0.5 * h, False)
        if isinstance(self.scheme, str):
            self._kick(model, state, h)
            self._drift(model, state, h)
        else:
            self._runge_kutta(model, state, h)
        if keyframed:  # exactly where the keyframes put them at the substep's end
            self._keyframes(model, state, state.time + h, True)

    def runs_frames(self, model) -> bool:
        """Whether frame() can take a whole frame in one launch: contacts solved serially (the CPU, a
        scene under the serial size), with no particles to couple between the steps."""
        return self.contacts is not None and self.coupling is None and model.rigid_serial

    def frame(self, model, state, h: float, n: int) -> None:
        """n contact steps of h [s] from state.time in one launch (n > 1 only where runs_frames), as n
        after_substep calls would leave the bodies; the Stepper advances the time and reads check()."""
        c = self.contacts
        self._contact_step(
            model, state, state.time, h, n, c.collision_sweeps, c.iterations, c.relax_iterations,
            bool(model.rigid_motions),
        )  # fmt: skip

    def check(self, state) -> None:
        """DivergenceError if a body's pose or velocity is no longer finite, or the contacts overflowed."""
        if self.contacts is not None:
            self.contacts.check()
        bad = int(self._bad[None])
        if bad >= 0:
            self._bad[None] = -1
            raise DivergenceError(
                f"rigid body {bad}: non-finite position, orientation or velocity at t = {state.time:.6g} s",
                step=state.step_count,
                quantity="rigid_state",
            )

    @ti.func
    def _watch(self, state: ti.template(), i):
        """Record body i if its pose or velocity is no longer finite (check() reads it)."""
        s = state.rigid_x[i].sum() + state.rigid_q[i].sum()
        s += state.rigid_v[i].sum() + state.rigid_w[i].sum()
        if not (ti.abs(s) < ti.math.inf):  # NaN fails every comparison
            ti.atomic_max(self._bad[None], i)

    @ti.kernel
    def _keyframes(self, model: ti.template(), state: ti.template(), t: float, poses: ti.template()):
        self._move_keyframed(model, state, t, poses)

    @ti.func
    def _move_keyframed(self, model: ti.template(), state: ti.template(), t, poses: ti.template()):
        """Keyframed bodies at time t [s]: their velocities (omega and omega x (x - T) + dT/dt), and
        with `poses` their pose, R(t) x0 + T(t) and q(t) q0 from the rest pose (x0, q0)."""
        for k, motion, x0, q0 in ti.static(model.rigid_motions):
            q, tr, omega, vel = motion.motion_at(t)
            if ti.static(poses):
                state.rigid_x[k] = quat_rotate(q, ti.Vector(x0, dt=float)) + tr
                state.rigid_q[k] = quat_normalized(quat_mul(q, ti.Vector(q0, dt=float)))
            state.rigid_w[k] = omega
            state.rigid_v[k] = omega.cross(state.rigid_x[k] - tr) + vel

    @ti.func
    def _linear_accel(self, model: ti.template(), state: ti.template(), i):
        return ti.Vector(self.gravity, dt=float) + state.rigid_force[i] * model.rigid_inv_mass[i]

    # The contact step in one launch (a launch costs about 24 us here, more than a 20-box tower's kick,
    # drift or empty solve), compiled without Taichi's CFG passes and its "advanced" optimisations (store
    # forwarding, CSE across the kernel), which grow faster than linearly with a kernel's size. Measured
    # on a box pair on a plane, empty cache: 2.6 s to compile (3.7 s with the exact end-point distances,
    # face clipping and per-part OBBs added since), against 7.3 s for the three launches it
    # replaces (their detection 5.5 s with the CFG passes off alone) and 9 s more for this kernel with
    # the CFG passes off alone (about 4.5 minutes with them). A Gauss-Seidel sweep costs the same 40 ns
    # per contact within the noise; detection is 15-25 % slower (pyramid 0.55-0.60 -> 0.68-0.70 ms,
    # 1000-box bin 2.7-3.0 -> 3.3 ms), less than the launches saved on small scenes
    # (docs/guide/performance.md, "Compile time").
    @compile_with(cfg_optimization=False, advanced_optimization=False)
    @ti.kernel
    def _contact_step(
        self,
        model: ti.template(),
        state: ti.template(),
        t: float,
        h: float,
        steps: ti.i32,
        collision_sweeps: ti.i32,
        iterations: ti.i32,
        relax: ti.i32,
        keyframed: ti.template(),
    ):
        """`steps` contact steps of h [s] from time t [s] (one unless the loops are serial: then a frame
        of steps runs in this one launch, stopping after a step that overflowed the contacts or left a
        body non-finite, for check() to report)."""
        if ti.static(model.rigid_serial):
            now = t
            ti.loop_config(serialize=True)
            for _ in range(steps):
                self._one_contact_step(model, state, now, h, collision_sweeps, iterations, relax, keyframed)
                if self.contacts.found[None] > self.contacts.sizes[0] or self._bad[None] >= 0:
                    break
                now += h  # as the Stepper adds up state.time, step by step
        else:
            self._one_contact_step(model, state, t, h, collision_sweeps, iterations, relax, keyframed)

    @ti.func
    def _one_contact_step(
        self, model: ti.template(), state: ti.template(), t, h, collision_sweeps, iterations, relax,
        keyframed: ti.template(),
    ):  # fmt: skip
        """Kick, detection (contacts at time t [s]), preparation with the collision phase, the biased
        solve (`iterations` sweeps), drift, the relaxation (`relax` sweeps); keyframed bodies take their
        velocities at the step's middle and their poses at its end."""
        c = self.contacts
        if ti.static(keyframed):
            self._move_keyframed(model, state, t + 0.5 * h, False)
        self._kick_bodies(model, state, h)
        c.run_detect(model, state, t, h)
        c.run_prepare(model, state, h, collision_sweeps)
        if ti.static(model.rigid_serial):
            # Serial loops: the two solves are passes of one loop, so the kernel holds one copy of the
            # contact solve (a parallel drift must stay a loop at the kernel's top level).
            for relaxed in range(2):
                if relaxed == 1:
                    self._end_of_step(model, state, t, h, keyframed)
                c.run_solve(model, state, iterations if relaxed == 0 else relax, relaxed)
        else:
            c.run_solve(model, state, iterations, 0)
            self._end_of_step(model, state, t, h, keyframed)
            c.run_solve(model, state, relax, 1)  # and keeps the impulses for the next step

    @ti.func
    def _end_of_step(self, model: ti.template(), state: ti.template(), t, h, keyframed: ti.template()):
        """Between the biased solve and the relaxation: the drift, and keyframed bodies exactly where their
        keyframes put them at the step's end."""
        self._drift_bodies(model, state, h)
        if ti.static(keyframed):
            self._move_keyframed(model, state, t + h, True)

    @ti.kernel
    def _kick(self, model: ti.template(), state: ti.template(), h: float):
        self._kick_bodies(model, state, h)

    @ti.func
    def _kick_bodies(self, model: ti.template(), state: ti.template(), h):
        """Velocities by the forces and torques of the step: v += h a, w += h I_w^-1 tau (L += h tau)."""
        ti.loop_config(serialize=model.rigid_serial)
        for i in range(model.live_rigid()):
            if model.rigid_inv_mass[i] > 0.0:
                q = state.rigid_q[i]
                damp = ti.exp(-h * model.rigid_damping[i])  # the drag's exact decay over the step
                state.rigid_v[i] = damp[0] * state.rigid_v[i] + h * self._linear_accel(model, state, i)
                mom = angular_momentum(q, damp[1] * state.rigid_w[i], model.rigid_inv_moments[i])
                state.rigid_w[i] = angular_velocity(
                    q, mom + h * state.rigid_torque[i], model.rigid_inv_moments[i]
                )

    @ti.kernel
    def _drift(self, model: ti.template(), state: ti.template(), h: float):
        self._drift_bodies(model, state, h)

    @ti.func
    def _drift_bodies(self, model: ti.template(), state: ti.template(), h):
        """Poses by the (corrected) velocities: x += h v, and the torque-free turn of L = I_w w."""
        ti.loop_config(serialize=model.rigid_serial)
        for i in range(model.live_rigid()):
            x, q, v, w = state.rigid_x[i], state.rigid_q[i], state.rigid_v[i], state.rigid_w[i]
            inv = model.rigid_inv_moments[i]
            state.rigid_x[i] = x + h * v
            if model.rigid_inv_mass[i] == 0.0:  # kinematic: its velocities, exactly
                state.rigid_q[i] = quat_normalized(quat_mul(quat_rotation(w, h), q))
            else:
                mom = angular_momentum(q, w, inv)
                q1 = free_rotation(q, mom, inv, h)
                state.rigid_q[i] = q1
                state.rigid_w[i] = angular_velocity(q1, mom, inv)
            self._watch(state, i)

    @ti.func
    def _rates(self, model: ti.template(), state: ti.template(), i, q, v, mom):
        """(dx/dt, dq/dt, dv/dt, dL/dt) of body i at orientation q, velocity v, momentum mom."""
        qn = quat_normalized(q)
        w = angular_velocity(qn, mom, model.rigid_inv_moments[i])
        dq = 0.5 * quat_mul(ti.Vector([w[0], w[1], w[2], 0.0]), qn)
        c = model.rigid_damping[i]  # drag: -c v and -c L (the tableau integrates it to its order)
        return v, dq, self._linear_accel(model, state, i) - c[0] * v, state.rigid_torque[i] - c[1] * mom

    @ti.kernel
    def _runge_kutta(self, model: ti.template(), state: ti.template(), h: float):
        a, b, n = ti.static(self.scheme.a, self.scheme.b, len(self.scheme.b))
        ti.loop_config(serialize=model.rigid_serial)
        for i in range(model.live_rigid()):
            x0, q0, v0, w0 = state.rigid_x[i], state.rigid_q[i], state.rigid_v[i], state.rigid_w[i]
            inv = model.rigid_inv_moments[i]
            if model.rigid_inv_mass[i] == 0.0:
                state.rigid_x[i] = x0 + h * v0
                state.rigid_q[i] = quat_normalized(quat_mul(quat_rotation(w0, h), q0))
            else:
                m0 = angular_momentum(q0, w0, inv)
                # the stages' rates, one row per stage (Taichi scope has no growing lists)
                kx = ti.Matrix.zero(float, n, 3)
                kq = ti.Matrix.zero(float, n, 4)
                kv = ti.Matrix.zero(float, n, 3)
                km = ti.Matrix.zero(float, n, 3)
                for s in ti.static(range(n)):
                    q, v, mom = q0, v0, m0
                    for j in ti.static(range(s)):
                        if ti.static(a[s][j] != 0.0):
                            q += h * a[s][j] * _row(kq, j, 4)
                            v += h * a[s][j] * _row(kv, j, 3)
                            mom += h * a[s][j] * _row(km, j, 3)
                    dx, dq, dv, dm = self._rates(model, state, i, q, v, mom)
                    _set_row(kx, s, dx)
                    _set_row(kq, s, dq)
                    _set_row(kv, s, dv)
                    _set_row(km, s, dm)
                x1, q1, v1, m1 = x0, q0, v0, m0
                for s in ti.static(range(n)):
                    if ti.static(b[s] != 0.0):
                        x1 += h * b[s] * _row(kx, s, 3)
                        q1 += h * b[s] * _row(kq, s, 4)
                        v1 += h * b[s] * _row(kv, s, 3)
                        m1 += h * b[s] * _row(km, s, 3)
                q1 = quat_normalized(q1)
                state.rigid_x[i] = x1
                state.rigid_q[i] = q1
                state.rigid_v[i] = v1
                state.rigid_w[i] = angular_velocity(q1, m1, inv)
            self._watch(state, i)
