"""Rigid contacts: detection (narrow_phase.py) and sequential impulses with warm starting and Coulomb
friction (Catto, "Iterative Dynamics with Temporal Coherence", GDC 2005, and "Fast and Simple Physics
using Sequential Impulses", GDC 2006: accumulated impulses clamped, normal >= 0 and friction within the
cone mu lambda_n), with the soft step of Box2D v3 (Catto, "Solver2D", 2024): the biased solve pushes
penetrations out at beta / h of their depth past a slop (at most `max_push` m/s), the positions move,
then relaxation iterations without the bias take that push back out of the velocities, so stacks do not
gain energy from their own correction. Restitution is a collision phase before the solve (_collide:
Guendelman et al. 2003) on contacts that approach faster than `bounce_speed` and were not already pushing
in the step before.

Everything runs serially on the CPU (Gauss-Seidel over the contacts, in the order they were found), so
results are deterministic at any thread count."""

import numpy as np
import taichi as ti

from ...errors import DivergenceError
from ...runtime import compile_with, data_oriented, np_float
from .gjk import gjk
from .narrow_phase import NO_BODY, geom_sdf, obb_overlap, pose, support
from .quaternion import world_inverse_inertia
from .sat import polytope_axis

# Pairs of bodies reaching each level of the cascade, then pairs of their convex parts: past the parts'
# bounding spheres, and given the exact test (past the parts' OBBs too, for bodies of several parts).
CASCADE_LEVELS = ("pairs", "spheres", "aabb", "obb", "touching", "part_spheres", "exact_tests")
# Sweeps of the collision phase: an impact passes one contact per sweep against the contacts' order
# (along it, all in one sweep).
COLLISION_SWEEPS = 4
# A contact's side: a's point against b (0), b's point against a (1), the pair's closest features (2:
# an edge-edge axis, or two round cores' closest points), or where an edge of a (3) or of b (4) leaves the
# other polytope's face (face clipping).
SIDES = 5
FEATURES = 2
CLIPPED = 3


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


@data_oriented
class RigidContacts:
    """The contact buffers and kernels of the bodies' solver. iterations / relax_iterations: sweeps of the
    biased solve and of the relaxation per step; beta: the fraction of a penetration pushed out per step;
    slop [m]: the penetration left alone; max_push [m/s]; bounce_speed [m/s]: approaches slower than this
    do not bounce; capacity: contacts held (DivergenceError from check() when a step finds more)."""

    def __init__(self, model, *, iterations, relax_iterations, beta, slop, max_push, bounce_speed, capacity):
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
        self.prev_count[None] = 0
        # read at run time (not compile-time constants): a scene of another size compiles nothing new
        self.sizes = make(self, "rc_sizes", ti.i64, 3)
        others = model.rigid_geom_count + len(self.colliders)
        features = max(model.rigid_point_count, 2 * model.rigid_edge_count, 1)  # points, edges' two ends
        self.sizes.from_numpy(np.array([capacity, others, features]))

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

    @ti.func
    def _add(self, a, b, geom, other, side, point, p, n, sep, vs, mu, e):
        """Contact of body a (its geom `geom`) with body b (NO_BODY: a collider), keyed by (geom, the
        other geom or collider slot `other`, side, point) for the next step's warm start."""
        slot = self.found[None]
        self.found[None] += 1
        if slot < self.sizes[0]:
            self.a[slot] = a
            self.b[slot] = b
            self.key[slot] = ((ti.i64(geom) * self.sizes[1] + other) * SIDES + side) * self.sizes[2] + point
            self.point[slot] = p
            self.normal[slot] = n
            self.sep[slot] = sep
            self.surface_v[slot] = vs
            self.mu[slot] = mu
            self.e[slot] = e

    @ti.func
    def _reach(self, model: ti.template(), state: ti.template(), i, h):
        """How far body i's surface can move in a step of h [s]: |v| h + |w| h times its bound."""
        return h * (state.rigid_v[i].norm() + state.rigid_w[i].norm() * model.rigid_bound[i])

    @ti.func
    def _material(self, model: ti.template(), a, b):
        """(friction, restitution) of a contact between bodies a and b."""
        mu = ti.sqrt(model.rigid_friction[a] * model.rigid_friction[b])
        return mu, ti.max(model.rigid_restitution[a], model.rigid_restitution[b])

    @ti.func
    def _points_in(self, model: ti.template(), pair, poses, side, pair_n, face, margin):
        """Geom ga's points against geom gb's signed distance (side 0), or gb's against ga's (side 1), for
        pair = (body a, body b, ga, gb) and poses = (origin, rotation) of ga and of gb; contacts are
        stored with the lower body first and the normal from b towards a. Two polytopes share one normal,
        the pair's separating-axis normal `pair_n` (sat.py), with each point's gap measured along it from
        `face` (gb's extent along it for side 0, ga's for side 1): a corner on a corner would otherwise
        take any face's normal. Round shapes take the signed distance's normal; a round shape's point
        outside a polytope takes its exact distance and normal by GJK (gjk.py), not the planes' lower
        bound, which past a face's edge reads a sphere clear of the edge as penetrating (0.7 s of
        compile, on the kernel compiled as dynamics.py says; 2.7 s with Taichi's passes). Where two equal
        faces lie on each other, both sides find the same corners: the doubled contacts are kept
        (removing them made a 20-box tower creep 17 mm in 10 s instead of 1.2)."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        src, dst = ga, gb
        xs, rs, xd, rd = xa, ra, xb, rb
        if side == 1:
            src, dst = gb, ga
            xs, rs, xd, rd = xb, rb, xa, ra
        mu, e = self._material(model, a, b)
        exact = model.geom_round[src] != 0 and model.geom_round[dst] == 0
        for k in range(model.geom_point_start[src], model.geom_point_start[src + 1]):
            p = xs + rs @ model.geom_points[k]
            radius = model.geom_point_radius[k]
            d, n = geom_sdf(model, dst, xd, rd, p)
            if exact and d > 0.0 and d - radius < margin:
                d, _, closest = gjk(model, -1, p, rs, dst, xd, rd)
                if d > 0.0:
                    n = (p - closest) / d
            sep = d - radius
            if sep < margin:
                normal = n if side == 0 else -n
                point = p - radius * n
                if pair_n.norm_sqr() > 0.0:
                    normal = pair_n
                    sep = pair_n.dot(p) - face if side == 0 else face - pair_n.dot(p)
                if sep < margin:
                    zero = ti.Vector.zero(float, 3)
                    self._add(a, b, ga, gb, side, k, point, normal, sep, zero, mu, e)

    @ti.func
    def _edges_clipped(self, model: ti.template(), pair, poses, side, pair_n, face, margin):
        """Face clipping for two polytopes whose separating axis is a face normal (the contact polygon
        of Sutherland & Hodgman's clipping, 1974, which ODE's and Box2D's box tests take): each edge of
        ga (side 0; gb's for side 1) is cut to the prism of gb's face, that is against every plane of gb
        but the one facing ga (Cyrus & Beck, 1978), and where a plane cut it, the cut point within the
        margin of gb's face is a contact. Its vertices are _points_in's; the cut points are the contact
        polygon's corners that are no vertex, as where two beams cross with no corner over the other. A
        point cut by two planes at once is on gb's edge between them, below gb's vertex that _points_in
        finds: not added again."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        src, dst = ga, gb
        xs, rs, xd, rd = xa, ra, xb, rb
        toward = pair_n  # from gb towards ga: gb's face facing ga
        if side == 1:
            src, dst = gb, ga
            xs, rs, xd, rd = xb, rb, xa, ra
            toward = -pair_n
        facing, best = -1, ti.cast(-2.0, float)
        for k in range(model.geom_plane_start[dst], model.geom_plane_start[dst + 1]):
            plane = model.geom_planes[k]
            along = (rd @ ti.Vector([plane[0], plane[1], plane[2]])).dot(toward)
            if along > best:
                facing, best = k, along
        # on a plane to the round-off of the coordinates: not cut by it
        tol = ti.static(64.0 * float(np.finfo(np_float()).eps)) * (xd.norm() + model.geom_bound[dst])
        # A cut point this close to a vertex of either (a thousandth of the smaller part's size) is that
        # vertex's contact again: two stacked boxes a few microradians apart would otherwise add cut
        # points next to their corners, which come and go with the sign of the angle (a 20-box tower
        # drifted 13 mm in 10 s instead of 1).
        near = tol + 1e-3 * ti.min(model.geom_bound[src], model.geom_bound[dst])
        mu, e = self._material(model, a, b)
        # Only against a reference face, one whose normal is the axis (to 0.8 degrees): gb's polytope
        # without its facing plane is the face's prism only then. Past a tilted gb's ridge it would hold
        # points far above gb that read as touching along the axis (a plank on a tilted box's ridge then
        # stayed level, held in the air). The other side's reference face clips this pair.
        if best < 1.0 - 1e-4:
            facing = -1
        for ei in range(model.geom_edge_start[src], model.geom_edge_start[src + 1] if facing >= 0 else 0):
            edge = model.geom_edges[ei]
            p0 = xs + rs @ ti.Vector([edge[0, 0], edge[0, 1], edge[0, 2]])
            p1 = xs + rs @ ti.Vector([edge[1, 0], edge[1, 1], edge[1, 2]])
            gap0 = toward.dot(p0) - face if side == 0 else face - pair_n.dot(p0)
            gap1 = toward.dot(p1) - face if side == 0 else face - pair_n.dot(p1)
            if ti.min(gap0, gap1) < margin:
                # the part of the edge inside the prism: t in [t0, t1]; an end cut by two planes at once
                # (within `near`) is on gb's edge between them, an end not cut is ga's vertex: `tied`
                t0, t1 = ti.cast(0.0, float), ti.cast(1.0, float)
                tied0, tied1 = True, True
                for k in range(model.geom_plane_start[dst], model.geom_plane_start[dst + 1]):
                    if k != facing:
                        plane = model.geom_planes[k]
                        n = rd @ ti.Vector([plane[0], plane[1], plane[2]])
                        d = plane[3] + n.dot(xd)
                        f0, f1 = n.dot(p0) - d, n.dot(p1) - d
                        if ti.abs(f0) <= near and ti.abs(f1) <= near:
                            t0 = 2.0  # along this side plane: its cut points are gb's vertices
                        elif f0 > tol and f1 > tol:
                            t0 = 2.0  # wholly outside this plane
                        elif f0 > tol:
                            t, slack = f0 / (f0 - f1), near / (f0 - f1)
                            if t > t0 + slack:
                                t0, tied0 = t, False
                            elif t >= t0 - slack:
                                tied0 = True
                        elif f1 > tol:
                            t, slack = f0 / (f0 - f1), near / (f1 - f0)
                            if t < t1 - slack:
                                t1, tied1 = t, False
                            elif t <= t1 + slack:
                                tied1 = True
                if t0 < t1:
                    for end in range(2):
                        t = t0 if end == 0 else t1
                        sep = gap0 + t * (gap1 - gap0)  # the gap is linear along the edge
                        if sep < margin and not (tied0 if end == 0 else tied1):
                            p = p0 + t * (p1 - p0)
                            zero = ti.Vector.zero(float, 3)
                            point = 2 * ei + end
                            self._add(a, b, ga, gb, CLIPPED + side, point, p, pair_n, sep, zero, mu, e)

    @ti.func
    def _cores(self, model: ti.template(), pair, poses, margin):
        """One contact at the closest points of two geoms' cores (GJK), for a round shape that meets the
        other with none of its points: a capsule across another, or across a box's edge."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        dist, pa, pb = gjk(model, ga, xa, ra, gb, xb, rb)
        if dist > 0.0:  # cores that meet: deep inside, where the points' contacts hold the pair
            n = (pa - pb) / dist
            sep = dist - model.geom_radius[ga] - model.geom_radius[gb]
            if sep < margin:
                mu, e = self._material(model, a, b)
                point = pa - model.geom_radius[ga] * n
                self._add(a, b, ga, gb, FEATURES, 0, point, n, sep, ti.Vector.zero(float, 3), mu, e)

    @ti.func
    def _geoms(self, model: ti.template(), state: ti.template(), a, b, xa, ra, margin, skip_obb):
        """The contacts of bodies a (pose xa, ra) and b, part by part (one pair for simple shapes), and
        (the pairs of parts whose bounding spheres meet, those given the exact test, 1 if any contact was
        found else 0). The cascade goes on inside
        bodies of several parts: each pair of parts passes its bounding spheres, then its OBBs (Gottschalk
        et al.'s test, as between bodies; skipped with skip_obb), before the exact test."""
        parted = (model.rigid_geom_start[a + 1] - model.rigid_geom_start[a] > 1) or (
            model.rigid_geom_start[b + 1] - model.rigid_geom_start[b] > 1
        )
        xb, rb = state.rigid_x[b], self.rot[b]
        found = self.found[None]
        near, exact = 0, 0
        for ga in range(model.rigid_geom_start[a], model.rigid_geom_start[a + 1]):
            pa, qa = model.geom_pose(ga, xa, ra)
            for gb in range(model.rigid_geom_start[b], model.rigid_geom_start[b + 1]):
                pb, qb = model.geom_pose(gb, xb, rb)
                test = False
                if (pa - pb).norm() <= model.geom_bound[ga] + model.geom_bound[gb] + margin:
                    near += 1
                    test = True
                    if parted and not skip_obb:  # with one part each, the bodies' OBB test was this one
                        test = obb_overlap(model.geom_half[ga], model.geom_half[gb], qa, qb, pb - pa, margin)
                if test:
                    exact += 1
                    pair = (a, b, ga, gb)
                    poses = (pa, qa, pb, qb)
                    before = self.found[None]
                    # Two polytopes: the closest points of two edges where an edge-edge axis separates
                    # them least, else both geoms' vertices along the face normal that does (sat.py).
                    # Each contact routine appears once in the kernel: a copy per case made the
                    # detection compile seconds longer.
                    polytopes = model.geom_round[ga] == 0 and model.geom_round[gb] == 0
                    pair_n = ti.Vector.zero(float, 3)
                    faces = ti.Vector.zero(float, 2)
                    edge = False
                    if polytopes:
                        normal, sep, edge_wins, point = polytope_axis(model, ga, pa, qa, gb, pb, qb)
                        edge = edge_wins
                        if edge:
                            if sep < margin:
                                mu, e = self._material(model, a, b)
                                zero = ti.Vector.zero(float, 3)
                                self._add(a, b, ga, gb, FEATURES, 0, point, normal, sep, zero, mu, e)
                        else:
                            pair_n = normal
                            faces = ti.Vector(
                                [support(model, gb, pb, qb, normal), -support(model, ga, pa, qa, -normal)]
                            )
                    if not edge:
                        for side in range(2):
                            self._points_in(model, pair, poses, side, pair_n, faces[side], margin)
                        # Face clipping where the vertices found are fewer than 4 (a heuristic: 4 found
                        # are corners of the contact polygon, though not always all of them, e.g. two
                        # quads overlapping in a hexagon), as on a stack or a pyramid, where clipping
                        # found nothing new and took 13 % of a pyramid's step.
                        if polytopes and self.found[None] - before < 4:
                            for side in range(2):
                                self._edges_clipped(model, pair, poses, side, pair_n, faces[side], margin)
                    if not polytopes and self.found[None] == before:
                        self._cores(model, pair, poses, margin)
        return near, exact, ti.i32(self.found[None] > found)

    @ti.func
    def run_detect(self, model: ti.template(), state: ti.template(), t, h):
        """Every contact of the bodies' current poses (time t [s] for moving colliders) that can close
        within the step h [s]: the margin grows with the bodies' speeds, so a fast body meets what lies in
        its path (speculative contacts, Catto 2013) instead of passing through it."""
        self.found[None] = 0
        # each body's rotation and world inverse inertia, once per step
        ti.loop_config(serialize=model.rigid_serial)
        for i in range(model.live_rigid()):
            r = pose(state, i)[1]
            self.rot[i] = r
            inv = model.rigid_inv_moments[i]
            self.inv_inertia[i] = world_inverse_inertia(r, inv)
        pairs, spheres, aabbs, obbs, touching, part_spheres, exact_tests = 0, 0, 0, 0, 0, 0, 0
        ti.loop_config(serialize=True)
        for a in range(model.live_rigid()):
            xa, ra = state.rigid_x[a], self.rot[a]
            reach_a = self._reach(model, state, a, h)
            for b in range(a + 1, model.live_rigid()):
                if model.rigid_inv_mass[a] == 0.0 and model.rigid_inv_mass[b] == 0.0:
                    continue
                level, margin = self._cascade(model, state, a, xa, ra, reach_a, b, h, 3, False)
                # counted in registers, written once below: a loop of global adds per pair (one per
                # level reached) made the 1000-box bin's step 1.4 ms longer (half a million pairs)
                pairs += 1
                if level >= 1:
                    spheres += 1
                    if level >= 2:
                        aabbs += 1
                        if level == 3:
                            obbs += 1
                            near, exact, touched = self._geoms(model, state, a, b, xa, ra, margin, False)
                            part_spheres += near
                            exact_tests += exact
                            touching += touched
            if model.rigid_inv_mass[a] > 0.0:
                self._collider_contacts(model, a, xa, ra, t, self.margin + reach_a)
        counts = ti.Vector([pairs, spheres, aabbs, obbs, touching, part_spheres, exact_tests])
        for level in ti.static(range(len(CASCADE_LEVELS))):
            self.cascade_counts[level] = counts[level]
        self.count[None] = ti.min(self.found[None], ti.i32(self.sizes[0]))

    @ti.func
    def _cascade(self, model: ti.template(), state: ti.template(), a, xa, ra, reach_a, b, h, stop, skip_obb):
        """(the last level of the cascade that bodies a and b pass, up to `stop`: 0 none, 1 bounding
        spheres, 2 world AABBs (each OBB projected on the world axes), 3 OBBs (passed unseen with
        skip_obb); the contact margin of the pair [m], grown by how far each can move within h)."""
        d = state.rigid_x[b] - xa
        margin = self.margin + reach_a + self._reach(model, state, b, h)
        level = 0
        if stop >= 1 and d.norm() <= model.rigid_bound[a] + model.rigid_bound[b] + margin:
            level = 1
            rb = self.rot[b]  # read only here: most pairs stop at the spheres
            reach = ti.abs(ra) @ model.rigid_half[a] + ti.abs(rb) @ model.rigid_half[b] + margin
            if stop >= 2 and not (ti.abs(d) > reach).any():
                level = 2
                if stop >= 3:
                    if skip_obb:  # nested: Taichi's `or` would run the OBB test anyway
                        level = 3
                    elif obb_overlap(model.rigid_half[a], model.rigid_half[b], ra, rb, d, margin):
                        level = 3
        return level, margin

    @compile_with(cfg_optimization=False, advanced_optimization=False)  # as the step's kernel is
    @ti.kernel
    def cascade_pairs(
        self, model: ti.template(), state: ti.template(), h: float, stop: ti.i32, skip_obb: ti.i32
    ) -> ti.i32:
        """How many pairs of bodies (with a dynamic one) pass the cascade up to level `stop` (0: all
        such pairs, 1 bounding spheres, 2 AABBs, 3 OBBs, 4 the exact test finding a contact, whose
        contacts are then written over this step's), from the poses now; skip_obb: AABBs straight to the
        exact test, and the parts' bounding spheres too. With stop 4 it also writes the parts' counts
        (cascade()'s part_spheres and exact_tests). What benchmarks/rigid_cascade.py times level by
        level; the step does not call it."""
        self.found[None] = 0
        passed, part_spheres, exact_tests = 0, 0, 0
        ti.loop_config(serialize=True)
        for a in range(model.live_rigid()):
            xa, ra = state.rigid_x[a], self.rot[a]
            reach_a = self._reach(model, state, a, h)
            for b in range(a + 1, model.live_rigid()):
                if model.rigid_inv_mass[a] != 0.0 or model.rigid_inv_mass[b] != 0.0:
                    level, margin = self._cascade(
                        model, state, a, xa, ra, reach_a, b, h, ti.min(stop, 3), skip_obb
                    )
                    if stop == 4 and level == 3:
                        near, exact, touched = self._geoms(model, state, a, b, xa, ra, margin, skip_obb)
                        part_spheres += near
                        exact_tests += exact
                        if touched:
                            level = 4
                    if level >= stop:
                        passed += 1
        if stop == 4:
            self.cascade_counts[5] = part_spheres
            self.cascade_counts[6] = exact_tests
        self.count[None] = ti.min(self.found[None], ti.i32(self.sizes[0]))
        return passed

    @ti.func
    def _collider_contacts(self, model: ti.template(), a, xa, ra, t, margin):
        for c, collider in ti.static(tuple(enumerate(self.colliders))):
            mu = ti.sqrt(model.rigid_friction[a] * collider.friction)
            e = ti.max(model.rigid_restitution[a], collider.restitution)
            slot = ti.i32(self.sizes[1]) - ti.static(len(self.colliders)) + c  # no size baked in
            for g in range(model.rigid_geom_start[a], model.rigid_geom_start[a + 1]):
                xg, rg = model.geom_pose(g, xa, ra)
                for k in range(model.geom_point_start[g], model.geom_point_start[g + 1]):
                    p = xg + rg @ model.geom_points[k]
                    radius = model.geom_point_radius[k]
                    d, n, vs = collider.contact(p, t)
                    # A mesh collider answers only within its reach (farther points read as `reach`): its
                    # contacts are found from there, however fast the body.
                    if d >= ti.static(getattr(collider, "reach", 1e30) - 1e-9):
                        continue
                    if ti.static(collider.shell):
                        # An open surface has no inside: the body is on its centre's side, and a point of
                        # it past the sheet is penetrating (not outside on the far side, to be pushed
                        # through).
                        if n.dot(xa - p) < 0.0:
                            n, d = -n, -d
                    sep = d - radius
                    if sep < margin:
                        self._add(a, NO_BODY, g, slot, 0, k, p - radius * n, n, sep, vs, mu, e)

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
    def _mass_along(self, model: ti.template(), c, u):
        a, b = self.a[c], self.b[c]
        ka = self.inv_inertia[a] @ self.ra[c].cross(u)
        k = model.rigid_inv_mass[a] + u.dot(ka.cross(self.ra[c]))
        if b != NO_BODY:
            kb = self.inv_inertia[b] @ self.rb[c].cross(u)
            k += model.rigid_inv_mass[b] + u.dot(kb.cross(self.rb[c]))
        return 1.0 / ti.max(k, 1e-30)

    @ti.func
    def _find_previous(self, key):
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
        ti.loop_config(serialize=True)
        for c in range(self.count[None]):
            a, b = self.a[c], self.b[c]
            n = self.normal[c]
            self.ra[c] = self.point[c] - state.rigid_x[a]
            if b != NO_BODY:
                self.rb[c] = self.point[c] - state.rigid_x[b]
            t1, t2 = tangent_basis(n)
            self.t1[c], self.t2[c] = t1, t2
            self.k[c] = ti.Vector([self._mass_along(model, c, n), self._mass_along(model, c, t1),
                                   self._mass_along(model, c, t2)])  # fmt: skip

            ja = ti.Matrix.rows([self.ra[c].cross(n), self.ra[c].cross(t1), self.ra[c].cross(t2)])
            self.jac_a[c] = ja
            self.resp_a[c] = ja @ self.inv_inertia[a]  # rows (I^-1 j)^T: I^-1 is symmetric
            jb = ti.Matrix.zero(float, 3, 3)
            if b != NO_BODY:
                jb = ti.Matrix.rows([self.rb[c].cross(n), self.rb[c].cross(t1), self.rb[c].cross(t2)])
                self.resp_b[c] = jb @ self.inv_inertia[b]
            self.jac_b[c] = jb

            sep = self.sep[c]
            biased = -sep / h  # speculative: the gap may close within the step, no more
            relaxed = biased
            if sep <= 0.0:
                biased = ti.min(self.beta / h * ti.max(-sep - self.slop, 0.0), self.max_push)
                relaxed = 0.0
            impulse = ti.Vector.zero(float, 3)
            prev = self._find_previous(self.key[c])
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
    def run_solve(self, model: ti.template(), state: ti.template(), sweeps, relaxed: ti.template()):
        """`sweeps` Gauss-Seidel sweeps: friction, then the normal impulse, contact by contact; the
        normal targets are the biased ones, or with `relaxed` the unbiased ones, after which the impulses
        are kept for the next step's warm start (_store)."""
        ti.loop_config(serialize=True)
        for _ in range(sweeps):
            for c in range(self.count[None]):
                self._solve_contact(model, state, c, relaxed)
        if ti.static(relaxed):
            ti.loop_config(serialize=True)
            self._store()

    @ti.func
    def _solve_contact(self, model: ti.template(), state: ti.template(), c, relaxed: ti.template()):
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
        ln = ti.max(lam[0] + (self.target[c][relaxed] - vn) * k[0], 0.0)
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
