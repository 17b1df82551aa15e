"""Hard-sphere contacts: projection back to contact split by inverse mass, then restitution and Coulomb
friction along the line of centres (Witkin & Baraff course notes, "Particle dynamics", collisions;
Baraff, "Physically Based Modeling: Rigid Body Simulation", sec. 8, eq. 8-18: the impulse along n is
-(1 + e) v_rel.n / (1/m_a + 1/m_b), so each body takes its inverse-mass share and momentum is conserved).

After the integrator's step (the prediction x*, v*), the contact pass rebuilds the neighbour structure
on x*, lists each sphere's contacts in x* (and counts them), and runs, in cell order:
1. `iterations` Jacobi sweeps of position projection. Each pair's correction is scaled by
   min(1, omega / n_ij), n_ij = (n_i + n_j) / 2 the mean of the two spheres' contact counts (Macklin et
   al., "Unified Particle Physics for Real-Time Applications", SIGGRAPH 2014, sec. 4.2, eq. 11:
   averaging over a sphere's constraints so that dense piles do not overshoot, with over-relaxation
   1 <= omega <= 2). The scale is the same on both sides of a pair, so the two corrections stay equal and
   opposite in mass-weighted terms and every sweep conserves linear momentum; averaging by each sphere's
   own count did not (a sphere with two contacts took half of each correction while its partners took
   all of theirs, which lost 14% of a Newton's cradle's momentum at 8 sweeps). n is counted on the
   positions the previous sweep read (x* for the first two sweeps): the count of the positions being read
   is only known once the sweep is over;
2. velocities from positions, v = v* + (x - x*)/h, as in position-based dynamics (Müller et al. 2007,
   alg. 1, line 12), which keeps resting piles from sinking;
3. one velocity sweep over the pairs that overlapped at x* and were approaching: the relative normal
   velocity becomes -e times its value before the solve (e = 0 below rest_speed, so resting contacts do
   not jitter), and the tangential one loses at most mu times the normal change (Coulomb) (Müller et
   al., "Detailed Rigid Body Simulation with Extended Position Based Dynamics", 2020, sec. 3.6); each
   pair's change is divided by the larger of its two spheres' counts of such pairs (symmetric, as in 1).
A single pair is solved exactly (a mean of one). Candidate pairs come from the cells around each sphere's
position in x* (the same cells for both spheres of a pair, so both see the pair or neither does). The
count pass also lists each sphere's candidates within r_i + r_j + margin in x* (Verlet's neighbour list
with a skin, Verlet 1967, applied within one step): a later sweep walks that list instead of the 27
cells while no two spheres can have closed the margin, |x_i - x_i*| + max_j |x_j - x_j*| < margin,
which the sweeps track. It holds every pair the cells would give that can overlap, in the cells'
order, so the sums are the same bits. Sweeps
gather into ping-pong buffers: no float atomics, so a seed gives the same result at any thread count.
"""

import math
import warnings

import taichi as ti

from .. import runtime, validate
from ..runtime import data_oriented
from .neighbors import make_neighbor_search
from .response import project_spheres

CONTACTS_KEPT = 16  # listed contacts per sphere: equal spheres touch at most 12 without deep overlap
# Near lists: candidates within r_i + r_j + NEAR_MARGIN r_max in the prediction, at most NEAR_KEPT of
# them (equal spheres packed at contact have 12 within 2.5 r; a sphere with more falls back to the cells).
NEAR_MARGIN, NEAR_KEPT = 0.5, 24

# Sphere contacts run their loops serially on the CPU up to this many spheres (see SphereContacts).
SPHERE_SERIAL_UP_TO = 8192


def accumulator_types():
    """Per-sphere accumulators of the sweeps. Made after ti.init: a type made before it resolves
    `float` to f32 whatever the chosen precision."""
    vec3 = ti.types.vector(3, float)
    position = ti.types.struct(x=vec3, r=float, w=float, dx=vec3, n=ti.i32, c=ti.i32)
    velocity = ti.types.struct(
        x=vec3, v=vec3, xp=vec3, vp=vec3, r=float, w=float, inv_h=float, dv=vec3, n=ti.i32, c=ti.i32
    )
    return position, velocity


@ti.func
def pair_projection(d, ri, wi, rj, wj):
    """Position correction of sphere i that removes its share w_i / (w_i + w_j) of the overlap with j;
    d = x_i - x_j."""
    dist = d.norm()
    return wi / ti.max(wi + wj, 1e-30) * (ri + rj - dist) / dist * d


@ti.func
def pair_velocity(n, vi, wi, vj, wj, vn_before, e, mu, rest_speed):
    """Velocity change of sphere i for a contact of normal n (from j to i) that approached at
    vn_before = (v_i - v_j).n < 0 before the solve: the relative normal velocity becomes -e vn_before
    (0 below rest_speed); the relative tangential velocity loses at most mu times the normal change."""
    e_eff = e if -vn_before > rest_speed else 0.0
    target = -e_eff * vn_before
    vrel = vi - vj
    vn = vrel.dot(n)
    share = wi / ti.max(wi + wj, 1e-30)
    dv = share * (target - vn) * n
    vt = vrel - vn * n
    vt_norm = vt.norm()
    if mu > 0.0 and vt_norm > 1e-12:
        dv -= share * ti.min(mu * (target - vn_before), vt_norm) / vt_norm * vt
    return dv


@data_oriented
class _PositionSide:
    """One side of the position ping-pong: sphere centres in slot order, and each sphere's count of
    overlapping pairs in these positions (written by the sweep that reads them)."""

    def __init__(self, owner, x, count):
        self.owner = owner
        self.x = x
        self.count = count

    @ti.func
    def visit_velocity(self, i, k, ret: ti.template()):
        self.owner._visit_velocity(self, i, k, ret)


@data_oriented
class _Sweep:
    """The pair visits of one Jacobi sweep: positions from `src`, pair weights from the counts of `prev`
    (the side the previous sweep read)."""

    def __init__(self, owner, src: _PositionSide, prev: _PositionSide):
        self.owner = owner
        self.src = src
        self.prev = prev

    @ti.func
    def visit(self, i, k, ret: ti.template()):
        o = self.owner
        xj = self.src.x[k]
        rj = o.slot_radius(k)
        reach = ret.r + rj
        d = ret.x - xj
        d2 = d.norm_sqr()
        if d2 < reach * reach and k != i:
            if d2 <= 1e-24:
                # Coincident centres have no line of centres: separate them along x, the lower slot
                # going to -x, so that a stacked pair (e.g. from a point emitter) comes apart.
                d = ti.Vector([1e-12 if i > k else -1e-12, 0.0, 0.0], dt=float)
            # The pair's mean count: the same for both spheres of the pair (the larger of the two left
            # more overlap in the spheres demo, the smaller overshot).
            n = ti.max(0.5 * (ret.c + self.prev.count[k]), 1.0)
            scale = ti.min(1.0, o.relaxation / n)
            ret.dx += scale * pair_projection(d, ret.r, ret.w, rj, o.slot_inv_mass(k))
            ret.n += 1


@data_oriented
class ContactSpheres:
    """Sphere-sphere contacts of a model whose particles have radii, and sphere-collider contacts
    (the colliders' restitution and friction, against the surface offset by the radius).

    restitution e in [0, 1] (the course's formula is e = 1/2); friction mu >= 0; iterations: Jacobi
    sweeps per step; rest_speed [m/s]: approach speeds below it do not bounce; continuous: split each
    step into substeps so no sphere moves more than half the smallest radius relative to another (no
    tunnelling through spheres or walls), at most max_substeps; neighbor_search: "auto" | "brute" |
    "grid" | "hash_grid"; domain (lo, hi) [m] for the bounded grid (the scene's container), or None.

    A solver of the Stepper's list (solvers.py): `substeps`, then after each substep the method
    proposed, `after_substep` resolves the contacts of the prediction in place."""

    name = "sphere contacts"
    use_near_lists = True  # False: every later sweep scans the cells (the reference the tests compare)

    def __init__(
        self,
        model,
        *,
        restitution: float,
        friction: float,
        iterations: int,
        rest_speed: float,
        continuous: bool,
        max_substeps: int,
        neighbor_search: str,
        domain,
        relaxation: float = 2.0,
    ):
        # Read once from the model's public description; the model is passed to the kernels, not kept.
        self.particle_count = model.particle_count
        self.uniform_radius = model.uniform_radius or 0.0
        self.uniform_inv_mass = model.uniform_inv_mass
        self.restitution = validate.in_range("restitution", restitution, 0.0, 1.0)
        self.friction = validate.non_negative("friction", friction)
        self.iterations = validate.count("iterations", iterations, 1)
        self.relaxation = validate.in_range("relaxation", relaxation, 1.0, 2.0)
        self.rest_speed = validate.non_negative("rest_speed", rest_speed)
        self.continuous = bool(continuous)
        self.max_substeps = validate.count("max_substeps", max_substeps, 1)
        self._warned = False
        # Arrays of particle_capacity rows (the count, unless capacity buckets are on: then from the
        # model's pool, and every choice below goes by the capacity, so that any size of a bucket compiles
        # the same kernels; the loops run to the neighbour structure's live size).
        n = model.particle_capacity
        make = model.new_field
        # Small sphere counts are launch-bound on the CPU: a step is ~8 loops, each ~70-130 us more in
        # parallel than serial here (the second core waking up; benchmarks/results/step_breakdown.md).
        # A sphere's contact work is ~300 ns a sweep, far more than a particle's update, so the contact
        # loops go parallel from fewer elements than CPU_SERIAL_BELOW: on the 2-core Xeon 10^4 spheres
        # stepped in 10 ms in parallel against 14 ms serially, 6,000 tied, 3,000 were faster serially.
        self._serial = runtime.backend_name() == "cpu" and n <= SPHERE_SERIAL_UP_TO
        self.max_radius = model.max_radius
        self.min_radius = model.min_sphere_radius  # points (radius 0) may share the scene
        # A pair touches when |x_i - x_j| < r_i + r_j <= 2 r_max: cells of that size hold every contact.
        self.neighbors = make_neighbor_search(
            n, 2.0 * self.max_radius, domain=domain, method=neighbor_search, make=make
        )
        # Slot-order copies: the prediction x* is the neighbour structure's own sorted copy; v*, and the
        # two sides of the position ping-pong.
        self.x_pred = self.neighbors.sorted_x
        self.v_pred = make(self, "spheres_v_pred", float, n, (3,))
        # The prediction's contacts, listed in visiting order: the first sweep and the velocity sweep,
        # whose contacts are exactly these, walk the list instead of the 27 cells (the same pairs in the
        # same order, so the same sums). A sphere with more falls back to the cells.
        self.slot_contacts = make(self, "spheres_slot_contacts", ti.i32, (n, CONTACTS_KEPT))
        self.slot_contact_count = make(self, "spheres_slot_contact_count", ti.i32, n)
        self.slot_approach_count = make(self, "spheres_slot_approach_count", ti.i32, n)  # approaching pairs
        # Near lists (see the module's docstring): the later sweeps' candidates while the drift allows.
        # Only the sweeps after the first walk them: with one sweep, listing and tracking would be cost
        # alone (the spheres demo's single sweep ran 27 % slower with them).
        self.near_lists = self.use_near_lists and self.iterations > 1
        self.near_margin = NEAR_MARGIN * self.max_radius
        near = self.near_lists
        self.slot_near = make(self, "spheres_slot_near", ti.i32, (n, NEAR_KEPT)) if near else None
        self.slot_near_count = make(self, "spheres_slot_near_count", ti.i32, n) if near else None
        self.drift = make(self, "spheres_drift", float, ())  # max |x - x*| of the last sweep's result
        self.pred = _PositionSide(self, self.x_pred, self.slot_contact_count)
        xs = [make(self, f"spheres_x{s}", float, n, (3,)) for s in range(2)]
        counts = [make(self, f"spheres_count{s}", ti.i32, n) for s in range(2)]
        self.sides = [_PositionSide(self, x, c) for x, c in zip(xs, counts, strict=True)]
        # Sweep k reads src and the counts of the side sweep k - 1 read: the first two the prediction's,
        # then the two sides in turn.
        a, b = self.sides
        self.sweeps = [_Sweep(self, self.pred, self.pred), _Sweep(self, a, self.pred)]
        self.sweeps += [_Sweep(self, b, a), _Sweep(self, a, b)]
        self._per_slot = model.per_particle_radius or model.per_particle_mass
        self.slot_r = make(self, "spheres_slot_r", float, n) if self._per_slot else None
        self.slot_w = make(self, "spheres_slot_w", float, n) if self._per_slot else None
        self._position_acc, self._velocity_acc = accumulator_types()
        self.max_speed = make(self, "spheres_max_speed", float, ())
        self.overlap = make(self, "spheres_overlap", float, ())
        self.contact_count = make(self, "spheres_contact_count", ti.i32, ())

    def settings(self) -> dict:
        return {
            "restitution": self.restitution,
            "friction": self.friction,
            "iterations": self.iterations,
            "relaxation": self.relaxation,
            "rest_speed": self.rest_speed,
            "continuous": self.continuous,
            "neighbor_search": self.neighbors.describe(),
        }

    @ti.func
    def slot_radius(self, k):
        r = ti.cast(self.uniform_radius, float)
        if ti.static(self._per_slot):
            r = self.slot_r[k]
        return r

    @ti.func
    def slot_inv_mass(self, k):
        w = ti.cast(self.uniform_inv_mass, float)
        if ti.static(self._per_slot):
            w = self.slot_w[k]
        return w

    # -- pair visits -----------------------------------------------------------------------------------

    @ti.func
    def _visit_count(self, i, k, ret: ti.template()):
        """Lists and counts the pairs that overlap in the prediction (in ret.n), and lists the candidates
        within the near margin (in ret.c, which the count pass does not otherwise use)."""
        reach = ret.r + self.slot_radius(k)
        d2 = (ret.x - self.x_pred[k]).norm_sqr()
        if d2 < reach * reach and k != i:
            if ret.n < CONTACTS_KEPT:
                self.slot_contacts[i, ret.n] = k
            ret.n += 1
        if ti.static(self.near_lists):
            near = reach + self.near_margin
            if d2 < near * near and k != i:
                if ret.c < NEAR_KEPT:
                    self.slot_near[i, ret.c] = k
                ret.c += 1

    @ti.func
    def _approaching(self, i, k, ret: ti.template()):
        """Whether pair (i, k) overlapped in the prediction and was approaching, and its normal."""
        reach = ret.r + self.slot_radius(k)
        d = ret.xp - self.x_pred[k]
        d2 = d.norm_sqr()
        n = ti.Vector.zero(float, 3)
        vn_before = ti.cast(0.0, float)
        hit = False
        if 1e-24 < d2 < reach * reach:
            n = d / ti.sqrt(d2)
            vn_before = (ret.vp - self.v_pred[k]).dot(n)
            hit = vn_before < 0.0
        return hit, vn_before

    @ti.func
    def _visit_approach_count(self, i, k, ret: ti.template()):
        hit, _ = self._approaching(i, k, ret)
        if hit:
            ret.n += 1

    @ti.func
    def _visit_velocity(self, side: ti.template(), i, k, ret: ti.template()):
        """Restitution and friction for a pair that overlapped in the prediction and was approaching."""
        hit, vn_before = self._approaching(i, k, ret)
        if hit:
            # The normal of the solved positions: the one the projection separated along.
            ds = ret.x - side.x[k]
            ns = ds / ti.max(ds.norm(), 1e-30)
            vj = self.v_pred[k] + (side.x[k] - self.x_pred[k]) * ret.inv_h
            dv = pair_velocity(
                ns, ret.v, ret.w, vj, self.slot_inv_mass(k), vn_before,
                self.restitution, self.friction, self.rest_speed,
            )  # fmt: skip
            ret.dv += dv / ti.max(ret.c, self.slot_approach_count[k], 1)  # the same share for both
            ret.n += 1

    # -- step ------------------------------------------------------------------------------------------

    def substeps(self, model, state, dt: float) -> int:
        """Substeps for this step: 1, or with `continuous` enough that 2 v_max h <= r_min / 2."""
        if not self.continuous:
            return 1
        self._max_speed(model, state, state.time)
        travel = 2.0 * float(self.max_speed[None]) * dt
        need = max(1, math.ceil(travel / (0.5 * self.min_radius)))
        if need > self.max_substeps and not self._warned:
            warnings.warn(
                f"sphere contacts: a step of {dt:g} s needs {need} substeps to keep spheres moving at "
                f"{self.max_speed[None]:.3g} m/s from passing through each other; capped at "
                f"max_substeps={self.max_substeps} (raise it or lower dt)",
                RuntimeWarning,
                stacklevel=3,
            )
            self._warned = True
        return int(min(self.max_substeps, need))

    def before_substep(self, model, state, h: float) -> None:
        """Nothing: the contacts are found in the prediction, after the method's substep."""

    def after_substep(self, model, state, h: float, step: int) -> None:
        """Resolve contacts after a step of size h (state holds its prediction, ending at time + h)."""
        death = state.particle_death if state.has_lifetimes else None
        self.neighbors.build(state.particle_x, model.particle_count, death=death, t=state.time + h)
        a, b = self.sides
        for it in range(self.iterations):
            sweep = self.sweeps[it if it < 2 else 2 + it % 2]
            self._project(model, state, sweep, b if it % 2 else a, it == 0, state.time + h)
        self._velocities(state, b if self.iterations % 2 == 0 else a, 1.0 / h, step)

    @ti.func
    def _gather(self, model: ti.template(), state: ti.template(), k):
        """Slot k's predicted velocity (and radius, inverse mass) from the state, by particle index."""
        i = self.neighbors.sorted_id[k]
        self.v_pred[k] = state.particle_v[i]
        if ti.static(self._per_slot):
            self.slot_r[k] = model.radius(i)
            self.slot_w[k] = model.inv_mass(i)

    @ti.func
    def _listed(self, k, visit: ti.template(), ret: ti.template(), p):
        """visit(k, j, ret) for slot k's contacts in the prediction: from its list, or from the cells
        around p (its position in the prediction) if it has more than the list holds."""
        listed = self.slot_contact_count[k]
        if listed <= CONTACTS_KEPT:
            for c in range(listed):
                visit(k, self.slot_contacts[k, c], ret)
        else:
            self.neighbors.for_each_candidate(k, p, visit, ret)

    @ti.kernel
    def _project(
        self,
        model: ti.template(),
        state: ti.template(),
        sweep: ti.template(),
        dst: ti.template(),
        first: ti.template(),
        t_end: float,
    ):
        ns = self.neighbors
        if ti.static(first):
            if ti.static(self._per_slot):
                # A pass of its own (top-level loops run one after the other): the pass below reads the
                # neighbours' radii and masses, which must be this build's, not the last one's.
                ti.loop_config(serialize=self._serial)
                for k in range(ns.size[None]):
                    self._gather(model, state, k)
            # Every sphere's contacts in the prediction, before any sweep reads a neighbour's count.
            ti.loop_config(serialize=self._serial)
            for k in range(ns.size[None]):
                if ti.static(not self._per_slot):
                    self._gather(model, state, k)  # only v*, which no count reads: fused, one pass less
                acc = self._position_acc(
                    x=self.x_pred[k], r=self.slot_radius(k), w=0.0, dx=ti.Vector.zero(float, 3), n=0, c=0
                )
                ns.for_each_candidate(k, acc.x, self._visit_count, acc)
                self.slot_contact_count[k] = acc.n
                if ti.static(self.near_lists):
                    self.slot_near_count[k] = acc.c
        # The largest drift from the prediction among the positions this sweep reads (the last sweep's
        # result); this sweep's own is gathered for the next.
        drift = ti.cast(0.0, float)
        if ti.static(not first):
            drift = self.drift[None]
        self.drift[None] = 0.0
        ti.loop_config(serialize=self._serial)
        for k in range(ns.size[None]):
            acc = self._position_acc(
                x=sweep.src.x[k],
                r=self.slot_radius(k),
                w=self.slot_inv_mass(k),
                dx=ti.Vector.zero(float, 3),
                n=0,
                c=sweep.prev.count[k],
            )
            if ti.static(first):
                self._listed(k, sweep.visit, acc, self.x_pred[k])
            else:
                self._near(k, sweep.visit, acc, drift)
                sweep.src.count[k] = acc.n
            x = acc.x + acc.dx
            if ti.static(model.collider_count > 0):
                if acc.w > 0.0:  # pinned spheres are kinematic: colliders never move them
                    x, _ = project_spheres(model.colliders, x, ti.Vector.zero(float, 3), acc.r, 0.0, t_end)
            dst.x[k] = x
            if ti.static(self.near_lists):
                ti.atomic_max(self.drift[None], (x - self.x_pred[k]).norm())

    @ti.func
    def _near(self, k, visit: ti.template(), acc: ti.template(), drift):
        """visit(k, j, acc) for every candidate of slot k that can overlap it at acc.x: from its near list
        while no pair can have closed the margin since the prediction (this sphere's drift plus the
        largest, with 10 % to spare for rounding), else from the cells around its place in the
        prediction (the same cells for both spheres of a pair: their current positions may have crossed
        a cell boundary)."""
        if ti.static(self.near_lists):
            listed = self.slot_near_count[k]
            own = (acc.x - self.x_pred[k]).norm()
            if listed <= NEAR_KEPT and own + drift < 0.9 * self.near_margin:
                for c in range(listed):
                    visit(k, self.slot_near[k, c], acc)
            else:
                self.neighbors.for_each_candidate(k, self.x_pred[k], visit, acc)
        else:
            self.neighbors.for_each_candidate(k, self.x_pred[k], visit, acc)

    @ti.kernel
    def _velocities(self, state: ti.template(), side: ti.template(), inv_h: float, step: ti.i32):
        ns = self.neighbors
        # Each sphere's count of approaching contacts, before any sphere reads a neighbour's.
        ti.loop_config(serialize=self._serial)
        for k in range(ns.size[None]):
            acc = self._velocity_acc(
                x=self.x_pred[k],
                v=self.v_pred[k],
                xp=self.x_pred[k],
                vp=self.v_pred[k],
                r=self.slot_radius(k),
                w=self.slot_inv_mass(k),
                inv_h=inv_h,
                dv=ti.Vector.zero(float, 3),
                n=0,
                c=0,
            )
            self._listed(k, self._visit_approach_count, acc, acc.xp)
            self.slot_approach_count[k] = acc.n
        ti.loop_config(serialize=self._serial)
        for k in range(ns.size[None]):
            x = side.x[k]
            acc = self._velocity_acc(
                x=x,
                v=self.v_pred[k] + (x - self.x_pred[k]) * inv_h,  # v* + what the projection moved / h
                xp=self.x_pred[k],
                vp=self.v_pred[k],
                r=self.slot_radius(k),
                w=self.slot_inv_mass(k),
                inv_h=inv_h,
                dv=ti.Vector.zero(float, 3),
                n=0,
                c=self.slot_approach_count[k],
            )
            self._listed(k, side.visit_velocity, acc, acc.xp)
            v = acc.v + acc.dv
            total = x.sum() + v.sum()
            if ti.math.isnan(total) or ti.math.isinf(total):
                ti.atomic_add(state.nonfinite_count[None], 1)
                ti.atomic_min(state.nonfinite_step[None], step)
            i = ns.sorted_id[k]
            state.particle_x[i] = x
            state.particle_v[i] = v

    @ti.kernel
    def _max_speed(self, model: ti.template(), state: ti.template(), t: float):
        self.max_speed[None] = 0.0
        ti.loop_config(serialize=self._serial)
        for i in range(model.live_particles()):
            if model.alive(state, i, t):
                ti.atomic_max(self.max_speed[None], state.particle_v[i].norm())

    def check(self, state) -> None:
        """Nothing to read: a sphere-contact step cannot fail on its own (the watchdog sees its result)."""

    def separation_speed(self, model, state, dt: float) -> float:
        """[m/s] the speed spheres placed overlapping get when the first step pushes them apart (overlap
        / dt): the watchdog's speed bound allows it."""
        return self.overlap_stats(model, state)[0] / dt

    # -- diagnostics -----------------------------------------------------------------------------------

    def overlap_stats(self, model, state) -> tuple[float, int]:
        """(largest overlap r_i + r_j - |x_i - x_j| [m] over all touching pairs, number of such pairs)
        in the current state: the measure of how well the last solve separated the spheres. It rebuilds
        the neighbour structure (the solver's scratch), so call it between steps."""
        death = state.particle_death if state.has_lifetimes else None
        self.neighbors.build(state.particle_x, model.particle_count, death=death, t=state.time)
        self._overlaps(model, state)
        return float(self.overlap[None]), int(self.contact_count[None]) // 2

    @ti.func
    def _overlap_visit(self, i, k, ret: ti.template()):
        if k != i:
            gap = (ret.x - self.x_pred[k]).norm() - ret.r - self.slot_radius(k)
            if gap < 0.0:
                ret.dx[0] = ti.max(ret.dx[0], -gap)
                ret.n += 1

    @ti.kernel
    def _overlaps(self, model: ti.template(), state: ti.template()):
        self.overlap[None] = 0.0
        self.contact_count[None] = 0
        ti.loop_config(serialize=self._serial)
        for k in range(self.neighbors.size[None]):
            self._gather(model, state, k)
        ti.loop_config(serialize=self._serial)
        for k in range(self.neighbors.size[None]):
            p = self._position_acc(
                x=self.x_pred[k], r=self.slot_radius(k), w=0.0, dx=ti.Vector.zero(float, 3), n=0, c=0
            )
            self.neighbors.for_each_candidate(k, p.x, self._overlap_visit, p)
            ti.atomic_max(self.overlap[None], p.dx[0])
            ti.atomic_add(self.contact_count[None], p.n)
