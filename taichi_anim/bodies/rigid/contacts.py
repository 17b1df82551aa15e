"""Rigid contacts: the buffers, detection (detection.py) and sequential impulses with warm starting and
Coulomb friction (Catto, "Iterative Dynamics with Temporal Coherence", GDC 2005, and "Fast and Simple Physics
using Sequential Impulses", GDC 2006: accumulated impulses clamped, normal >= 0 and friction within the
cone mu lambda_n), with the soft step of Box2D v3 (Catto, "Solver2D", 2024): the biased solve pushes
penetrations out at beta / h of their depth past a slop (at most `max_push` m/s), the positions move,
then relaxation iterations without the bias take that push back out of the velocities, so stacks do not
gain energy from their own correction. Restitution is a collision phase before the solve (_collide:
Guendelman et al. 2003) on contacts that approach faster than `bounce_speed` and were not already pushing
in the step before.

Everything runs serially on the CPU (Gauss-Seidel over the contacts, in the order they were found), so
results are deterministic at any thread count."""

import taichi as ti

from ...errors import DivergenceError
from ...runtime import data_oriented
from .detection import CASCADE_LEVELS, ContactDetection
from .narrow_phase import NO_BODY
from .obb_tree import STACK

# Sweeps of the collision phase: an impact passes one contact per sweep against the contacts' order
# (along it, all in one sweep).
COLLISION_SWEEPS = 4


@ti.func
def tangent_basis(n):
    """Two unit tangents completing unit n to an orthonormal basis (Duff et al., "Building an Orthonormal
    Basis, Revisited", JCGT 2017, listing 3): continuous except across n.z = 0."""
    sign = 1.0 if n[2] >= 0.0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t1 = ti.Vector([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])
    t2 = ti.Vector([b, sign + n[1] * n[1] * a, -n[1]])
    return t1, t2


@ti.func
def _row_dots(m, n):
    """(m[i] . n[i]) for the three rows of two 3x3 matrices."""
    return ti.Vector([m[i, 0] * n[i, 0] + m[i, 1] * n[i, 1] + m[i, 2] * n[i, 2] for i in ti.static(range(3))])


@data_oriented
class RigidContacts(ContactDetection):
    """The contact buffers and kernels of the bodies' solver. iterations / relax_iterations: sweeps of the
    biased solve and of the relaxation per step; beta: the fraction of a penetration pushed out per step;
    slop [m]: the penetration left alone; max_push [m/s]; bounce_speed [m/s]: approaches slower than this
    do not bounce; capacity: contacts held (DivergenceError from check() when a step finds more);
    manifold_points: 4 keeps at most four contacts per pair of convex parts (_reduce), 0 all."""

    def __init__(self, model, *, iterations, relax_iterations, beta, slop, max_push, bounce_speed, capacity,
                 manifold_points):  # fmt: skip
        self.iterations = iterations
        self.relax_iterations = relax_iterations
        self.collision_sweeps = COLLISION_SWEEPS
        self.beta, self.slop, self.max_push, self.bounce_speed = beta, slop, max_push, bounce_speed
        self.margin = model.RIGID_MARGIN
        self.capacity = capacity
        self.colliders = tuple(model.colliders)
        cap = capacity
        make = model.new_field
        vec = dict(dims=(3,))
        self.a = make(self, "rc_a", ti.i32, cap)
        self.b = make(self, "rc_b", ti.i32, cap)
        self.key = make(self, "rc_key", ti.i64, cap)
        self.point = make(self, "rc_point", float, cap, **vec)
        self.normal = make(self, "rc_normal", float, cap, **vec)  # from b towards a
        self.sep = make(self, "rc_sep", float, cap)
        self.surface_v = make(self, "rc_surface_v", float, cap, **vec)
        self.mu = make(self, "rc_mu", float, cap)
        self.e = make(self, "rc_e", float, cap)
        self.ra = make(self, "rc_ra", float, cap, **vec)
        self.rb = make(self, "rc_rb", float, cap, **vec)
        self.t1 = make(self, "rc_t1", float, cap, **vec)
        self.t2 = make(self, "rc_t2", float, cap, **vec)
        self.k = make(self, "rc_k", float, cap, **vec)  # effective masses along n, t1, t2
        # Per contact and direction (rows n, t1, t2): the angular Jacobians r x u of a and b and their
        # responses I^-1 (r x u), so that a sweep's update is dot products and scaled adds (Catto 2006).
        mat = dict(dims=(3, 3))
        self.jac_a = make(self, "rc_jac_a", float, cap, **mat)
        self.jac_b = make(self, "rc_jac_b", float, cap, **mat)
        self.resp_a = make(self, "rc_resp_a", float, cap, **mat)
        self.resp_b = make(self, "rc_resp_b", float, cap, **mat)
        self.target = make(self, "rc_target", float, cap, dims=(2,))  # biased, relaxed normal speeds
        self.bounce = make(self, "rc_bounce", float, cap)  # e where the contact may bounce, else 0
        self.impulse = make(self, "rc_impulse", float, cap, **vec)  # accumulated (n, t1, t2) [N s]
        self.prev_key = make(self, "rc_prev_key", ti.i64, cap)
        self.prev_impulse = make(self, "rc_prev_impulse", float, cap, **vec)  # world vector [N s]
        self.count = make(self, "rc_count", ti.i32, ())
        self.prev_count = make(self, "rc_prev_count", ti.i32, ())
        self.found = make(self, "rc_found", ti.i32, ())  # contacts found, also past the capacity
        self.cascade_counts = make(self, "rc_cascade", ti.i32, len(CASCADE_LEVELS))
        self.inv_inertia = model.rigid_array(self, "rc_inv_inertia", dims=(3, 3))  # world, per body
        self.rot = model.rigid_array(self, "rc_rot", dims=(3, 3))  # each body's rotation at the step start
        self.stack = make(self, "rc_stack", ti.i32, STACK, dims=(2,))  # the trees' walk (detection.py)
        self._init_broad_phase(model)
        # read at run time (not compile-time constants): a scene of another size compiles nothing new
        self.sizes = make(self, "rc_sizes", ti.i64, 3)
        others = model.rigid_geom_count + len(self.colliders)
        features = max(model.rigid_point_count, 2 * model.rigid_edge_count, 1)  # points, edges' two ends
        self._start(capacity, others, features)
        # a compile-time switch: scenes that keep every corner compile no reduction code
        self.manifold_points = manifold_points

    # One launch: Python-scope writes (and from_numpy) are a kernel per field, each compiled with an empty
    # cache (about 17 ms for a writer, 35 ms for from_numpy) in every run with contacts.
    @ti.kernel
    def _start(self, capacity: ti.i64, others: ti.i64, features: ti.i64):
        """The sizes the kernels read, and no contacts or sorted bodies kept from an earlier step."""
        self.sizes[0], self.sizes[1], self.sizes[2] = capacity, others, features
        self.prev_count[None] = 0
        self.sweep_sorted[None] = 0

    def cascade(self) -> dict:
        """Pairs of bodies that reached each level of the cascade in the last step, then pairs of their
        parts: those whose bounding spheres met (part_spheres) and those given the exact test
        (exact_tests)."""
        return dict(zip(CASCADE_LEVELS, (int(c) for c in self.cascade_counts.to_numpy()), strict=True))

    def check(self) -> None:
        """DivergenceError when the last step found more contacts than the buffers hold."""
        found = int(self.found[None])
        if found > self.capacity:
            raise DivergenceError(
                f"rigid contacts: {found} found, the buffers hold {self.capacity} "
                f"(Builder.set_rigid_contacts(capacity=...))",
                quantity="rigid_contacts",
                value=found,
            )

    # -- detection --------------------------------------------------------------------------------------

    # -- the solve --------------------------------------------------------------------------------------

    @ti.func
    def _relative_velocity(self, state: ti.template(), c):
        a, b = self.a[c], self.b[c]
        v = state.rigid_v[a] + state.rigid_w[a].cross(self.ra[c]) - self.surface_v[c]
        if b != NO_BODY:
            v -= state.rigid_v[b] + state.rigid_w[b].cross(self.rb[c])
        return v

    @ti.func
    def _apply(self, model: ti.template(), state: ti.template(), c, impulse):
        """Impulse [N s] on a at its anchor, and minus it on b."""
        a, b = self.a[c], self.b[c]
        state.rigid_v[a] += impulse * model.rigid_inv_mass[a]
        state.rigid_w[a] += self.inv_inertia[a] @ self.ra[c].cross(impulse)
        if b != NO_BODY:
            state.rigid_v[b] -= impulse * model.rigid_inv_mass[b]
            state.rigid_w[b] -= self.inv_inertia[b] @ self.rb[c].cross(impulse)

    @ti.func
    def _find_previous(self, key, guess):
        """The slot of `key` among the last step's contacts (sorted), or -1: slot `guess` when it holds
        the key (the contacts come in the last step's order, so the slot after the last one found mostly
        does), else by binary search."""
        found = -1
        if guess < self.prev_count[None]:  # nested: Taichi's `and` evaluates both sides
            if self.prev_key[guess] == key:
                found = guess
        if found < 0:
            found = self._search_previous(key)
        return found

    @ti.func
    def _search_previous(self, key):
        """The slot of `key` among the last step's contacts (sorted), or -1 (binary search)."""
        lo, hi = 0, self.prev_count[None]
        while lo < hi:
            mid = (lo + hi) // 2
            if self.prev_key[mid] < key:
                lo = mid + 1
            else:
                hi = mid
        found = -1
        if lo < self.prev_count[None]:  # nested: Taichi's `and` evaluates both sides (no short circuit)
            if self.prev_key[lo] == key:
                found = lo
        return found

    @ti.func
    def run_prepare(self, model: ti.template(), state: ti.template(), h, collision_sweeps):
        """Anchors, effective masses, targets; the last step's impulses applied again (warm start); then
        the collision phase (_collide)."""
        guess = 0  # where the last step's impulse of the next contact most likely is (_find_previous)
        ti.loop_config(serialize=True)
        for c in range(self.count[None]):
            a, b = self.a[c], self.b[c]
            n = self.normal[c]
            ra = self.point[c] - state.rigid_x[a]
            self.ra[c] = ra
            t1, t2 = tangent_basis(n)
            self.t1[c], self.t2[c] = t1, t2
            ja = ti.Matrix.rows([ra.cross(n), ra.cross(t1), ra.cross(t2)])
            resp = ja @ self.inv_inertia[a]  # rows (I^-1 j)^T: I^-1 is symmetric
            self.jac_a[c], self.resp_a[c] = ja, resp
            # inverse effective masses along n, t1, t2: 1/m + (r x u) . I^-1 (r x u) per body
            k = model.rigid_inv_mass[a] + _row_dots(ja, resp)
            jb = ti.Matrix.zero(float, 3, 3)
            if b != NO_BODY:
                rb = self.point[c] - state.rigid_x[b]
                self.rb[c] = rb
                jb = ti.Matrix.rows([rb.cross(n), rb.cross(t1), rb.cross(t2)])
                resp_b = jb @ self.inv_inertia[b]
                self.resp_b[c] = resp_b
                k += model.rigid_inv_mass[b] + _row_dots(jb, resp_b)
            self.jac_b[c] = jb
            self.k[c] = 1.0 / ti.max(k, 1e-30)

            sep = self.sep[c]
            biased = -sep / h  # speculative: the gap may close within the step, no more
            relaxed = biased
            if sep <= 0.0:
                biased = ti.min(self.beta / h * ti.max(-sep - self.slop, 0.0), self.max_push)
                relaxed = 0.0
            impulse = ti.Vector.zero(float, 3)
            prev = self._find_previous(self.key[c], guess)
            if prev >= 0:
                guess = prev + 1
            self.target[c] = ti.Vector([biased, relaxed])
            # Restitution (_collide, before the solve) only where the contact was not pushing last step:
            # a contact that was is resting, and the solver's leftover there (a tall stack's first steps)
            # is no impact to restitute.
            self.bounce[c] = 0.0
            pushing = False
            if prev >= 0:  # nested: `or` would read prev_impulse[-1]
                pushing = self.prev_impulse[prev].dot(n) > 0.0
            if self.e[c] > 0.0 and not pushing:
                self.bounce[c] = self.e[c]
            if prev >= 0:
                p = self.prev_impulse[prev]
                ln = ti.max(p.dot(n), 0.0)
                lt = ti.Vector([p.dot(t1), p.dot(t2)])
                limit = self.mu[c] * ln
                if lt.norm() > limit:
                    lt *= limit / lt.norm()
                impulse = ti.Vector([ln, lt[0], lt[1]])
                self._apply(model, state, c, ln * n + lt[0] * t1 + lt[1] * t2)
            self.impulse[c] = impulse
        self._collide(model, state, h, collision_sweeps)

    @ti.func
    def run_solve(self, model: ti.template(), state: ti.template(), sweeps, relaxed):
        """`sweeps` Gauss-Seidel sweeps: friction, then the normal impulse, contact by contact; the
        normal targets are the biased ones (relaxed 0), or the unbiased ones (1), after which the
        impulses are kept for the next step's warm start (_store)."""
        ti.loop_config(serialize=True)
        for _ in range(sweeps):
            for c in range(self.count[None]):
                self._solve_contact(model, state, c, relaxed)
        if relaxed == 1:
            ti.loop_config(serialize=True)
            self._store()

    @ti.func
    def _solve_contact(self, model: ti.template(), state: ti.template(), c, relaxed):
        """One contact's friction, then normal impulse, on the bodies' velocities (held in registers)."""
        a, b = self.a[c], self.b[c]
        n, t1, t2 = self.normal[c], self.t1[c], self.t2[c]
        ja, ra = self.jac_a[c], self.resp_a[c]
        jb, rb = self.jac_b[c], self.resp_b[c]
        ima = model.rigid_inv_mass[a]
        va, wa = state.rigid_v[a], state.rigid_w[a]
        imb = ti.cast(0.0, float)
        vb, wb = ti.Vector.zero(float, 3), ti.Vector.zero(float, 3)
        if b != NO_BODY:
            imb = model.rigid_inv_mass[b]
            vb, wb = state.rigid_v[b], state.rigid_w[b]
        lam = self.impulse[c]
        k = self.k[c]
        # relative velocity along (n, t1, t2): u . (va - vb - vs) + (ra x u) . wa - (rb x u) . wb
        rel = ti.Matrix.rows([n, t1, t2]) @ (va - vb - self.surface_v[c]) + ja @ wa - jb @ wb
        # One effective mass for both tangents (the smaller): the update is then along -v_t, and the
        # cone's clamp keeps friction opposite the slip (two different masses would turn it and make a
        # sliding box drift sideways and yaw).
        kt = ti.min(k[1], k[2])
        lt = ti.Vector([lam[1] - rel[1] * kt, lam[2] - rel[2] * kt])
        limit = self.mu[c] * lam[0]
        if lt.norm() > limit:
            lt *= limit / ti.max(lt.norm(), 1e-30)
        d1, d2 = lt[0] - lam[1], lt[1] - lam[2]
        p = d1 * t1 + d2 * t2
        va += p * ima
        wa += d1 * ti.Vector([ra[1, 0], ra[1, 1], ra[1, 2]]) + d2 * ti.Vector([ra[2, 0], ra[2, 1], ra[2, 2]])
        vb -= p * imb
        wb -= d1 * ti.Vector([rb[1, 0], rb[1, 1], rb[1, 2]]) + d2 * ti.Vector([rb[2, 0], rb[2, 1], rb[2, 2]])
        vn = n.dot(va - vb - self.surface_v[c]) + ti.Vector([ja[0, 0], ja[0, 1], ja[0, 2]]).dot(wa)
        vn -= ti.Vector([jb[0, 0], jb[0, 1], jb[0, 2]]).dot(wb)
        targets = self.target[c]
        target = targets[0] if relaxed == 0 else targets[1]
        ln = ti.max(lam[0] + (target - vn) * k[0], 0.0)
        dn = ln - lam[0]
        va += dn * ima * n
        wa += dn * ti.Vector([ra[0, 0], ra[0, 1], ra[0, 2]])
        state.rigid_v[a], state.rigid_w[a] = va, wa
        if b != NO_BODY:
            vb -= dn * imb * n
            wb -= dn * ti.Vector([rb[0, 0], rb[0, 1], rb[0, 2]])
            state.rigid_v[b], state.rigid_w[b] = vb, wb
        self.impulse[c] = ti.Vector([ln, lt[0], lt[1]])

    @ti.func
    def _collide(self, model: ti.template(), state: ti.template(), h: float, sweeps: ti.i32):
        """The collision phase of Guendelman, Bridson & Fedkiw ("Nonconvex rigid bodies with stacking",
        SIGGRAPH 2003, sec. 7), before the contact solve: sweeps over the contacts that may bounce; one
        approaching faster than bounce_speed, and closing its gap within the step, leaves at e times its
        approach speed *now*, so an impact passes along a row in one sweep (Newton's cradle). These
        impulses are not accumulated: the contact solve that follows cannot take a bounce back."""
        ti.loop_config(serialize=True)
        for _ in range(sweeps):
            for c in range(self.count[None]):
                if self.bounce[c] > 0.0:
                    n = self.normal[c]
                    vn = self._relative_velocity(state, c).dot(n)
                    if vn < -self.bounce_speed and self.sep[c] + vn * h < 0.0:
                        self._apply(model, state, c, (-self.bounce[c] * vn - vn) * self.k[c][0] * n)

    @ti.func
    def _store(self):
        """Keep this step's impulses (world vectors) under their keys, sorted for the next step's binary
        search: by insertion, as the contacts come nearly sorted (in order but for compounds' parts).
        Serial: the caller configures the loop so."""
        for c in range(self.count[None]):
            lam = self.impulse[c]
            key = self.key[c]
            impulse = lam[0] * self.normal[c] + lam[1] * self.t1[c] + lam[2] * self.t2[c]
            slot = c
            while slot > 0:
                if self.prev_key[slot - 1] > key:
                    self.prev_key[slot] = self.prev_key[slot - 1]
                    self.prev_impulse[slot] = self.prev_impulse[slot - 1]
                    slot -= 1
                else:
                    break
            self.prev_key[slot] = key
            self.prev_impulse[slot] = impulse
        self.prev_count[None] = self.count[None]


def default_capacity(model) -> int:
    """Contacts the buffers hold by default: every point touching a few others, and every collider."""
    points = max(model.rigid_point_count, 1)
    return int(min(max(256, points * (4 + len(model.colliders))), 1 << 24))


__all__ = ["CASCADE_LEVELS", "RigidContacts", "default_capacity"]
