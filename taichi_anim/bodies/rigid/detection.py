"""Rigid contact detection: per pair of bodies the cascade (bounding spheres, AABBs, OBBs: narrow_phase.py)
and, past it, the exact contacts of their convex parts, and every body's points against the colliders.
Contact generation: a polytope pair's separating axis (sat.py), each polytope's vertices within the other
along it, face clipping where few were found, GJK for round cores (gjk.py). The contacts of one pair of
parts are kept to four where asked (manifold.py). Serial: the contacts come in the same order on every run."""

import numpy as np
import taichi as ti

from ...runtime import compile_with, data_oriented, np_float
from .broad_phase import BroadPhase
from .gjk import gjk
from .manifold import ManifoldReduction
from .narrow_phase import NO_BODY, geom_sdf, obb_overlap, pose, support
from .quaternion import world_inverse_inertia
from .sat import polytope_axis, segment_axis

# Pairs of bodies reaching each level of the cascade, then pairs of their convex parts: past the parts'
# bounding spheres, and given the exact test (past the parts' OBBs too, for bodies of several parts).
CASCADE_LEVELS = ("pairs", "spheres", "aabb", "obb", "touching", "part_spheres", "exact_tests")
# A contact's side: a's point against b (0), b's point against a (1), the pair's closest features (2:
# an edge-edge axis, or two round cores' closest points), or where an edge of a (3) or of b (4) leaves the
# other polytope's face (face clipping).
SIDES = 5
FEATURES = 2
CLIPPED = 3


@data_oriented
class ContactDetection(BroadPhase, ManifoldReduction):
    """Detection methods of RigidContacts (contacts.py), which holds the buffers they fill."""

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
        (removing them made a 20-box tower creep 17 mm in 10 s instead of 1.2).

        Side 2 is _cores' pass (the cores' closest points, for round shapes that met with none of their
        points): one pass of the loop, sharing its one GJK call, so that the kernel holds one copy of
        GJK instead of two (the pile demo's contact step: 16 % of its front end was the two)."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        src, dst = ga, gb
        xs, rs, xd, rd = xa, ra, xb, rb
        if side == 1:
            src, dst = gb, ga
            xs, rs, xd, rd = xb, rb, xa, ra
        mu, e = self._material(model, a, b)
        exact = model.geom_round[src] != 0 and model.geom_round[dst] == 0
        on_core = ti.static(64.0 * float(np.finfo(np_float()).eps)) * (xd.norm() + model.geom_bound[dst])
        first, last = model.geom_point_start[src], model.geom_point_start[src + 1]
        if side == 2:
            first, last = 0, 1
        for k in range(first, last):
            # a mesh's vertex that another of its prisms holds, or a prism's inner corner, is skipped
            if side == 2 or model.geom_contact_point[k]:
                zero = ti.Vector.zero(float, 3)
                p, radius, d, n = zero, ti.cast(0.0, float), ti.cast(0.0, float), zero
                on = False  # on the other's core, to round-off: no way out known here (_cores_crossing)
                query = side == 2  # GJK: the cores (side 2), or a round point outside a polytope
                if side < 2:
                    p = xs + rs @ model.geom_points[k]
                    radius = model.geom_point_radius[k]
                    d, n = geom_sdf(model, dst, xd, rd, p)
                    if ti.static(model.rigid_has_round):
                        on = model.geom_round[dst] != 0 and d + model.geom_radius[dst] <= on_core
                    if ti.static(model.rigid_round_and_polytopes):
                        query = exact and d > 0.0 and d - radius < margin and not on
                dist, closest_s, closest_d = ti.cast(0.0, float), zero, zero
                if ti.static(model.rigid_has_round):
                    if query:
                        qs, qx = src, xs  # side 2: ga's core (src is ga)
                        if side < 2:
                            qs, qx = -1, p
                        dist, closest_s, closest_d = gjk(model, qs, qx, rs, dst, xd, rd)
                if ti.static(model.rigid_has_round):
                    if side == 2:
                        self._cores_found(model, pair, poses, dist, closest_s, closest_d, margin)
                if side < 2 and not on:
                    if query:
                        d = dist
                        if d > 0.0:
                            n = (p - closest_d) / d
                    self._point_contact(model, pair, poses, side, pair_n, face, margin, src, dst, k, p,
                                        radius, d, n, mu, e)  # fmt: skip

    @ti.func
    def _point_contact(self, model: ti.template(), pair, poses, side, pair_n, face, margin, src, dst, k, p,
                       radius, d, n, mu, e):  # fmt: skip
        """_points_in's contact of point k of geom src (at p, of `radius`) at signed distance d (normal n)
        from geom dst, if within the margin."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        rs, rd = ra, rb
        if side == 1:
            rs, rd = rb, ra
        sep = d - radius
        if ti.static(model.rigid_prisms and model.rigid_has_round):
            # a round shape's point on a triangle, or a mesh's vertex in a round shape: only along a
            # direction the triangle's surface faces (_inactive); its neighbours hold the contact
            if model.geom_prism[dst] and model.geom_round[src]:
                if self._inactive(model, dst, rd, n):
                    sep = margin
            if model.geom_prism[src] and model.geom_round[dst]:
                if self._inactive(model, src, rs, -n):
                    sep = margin
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
    def _off_surface(self, model: ti.template(), ga, qa, gb, qb, normal):
        """_inactive for a pair of geoms of which one is a prism, `normal` running from gb towards ga."""
        prism, q, out = gb, qb, normal
        if model.geom_prism[ga]:
            prism, q, out = ga, qa, -normal
        return self._inactive(model, prism, q, out)

    @ti.func
    def _inactive(self, model: ti.template(), prism, q, out):
        """Whether the direction `out` (a contact normal out of geom `prism`, a mesh's triangle as a prism
        turned by q) points out of the triangle somewhere no surface faces: neither along the triangle's
        normal nor out across one of its active edges (at right angles to the edge, out of its side).
        Elsewhere it is a side of the prism or an edge shared with a flat neighbour, inside the surface
        (Bullet's and Jolt's internal edges): the shape touches the neighbouring triangles, not this
        one, and makes no contact with it. Pushing along such a direction, a box sliding over a flat
        mesh of 768 triangles caught on the shared edges (2 -> 0.27 m/s, spun at 6 rad/s); taking the
        triangle's normal instead pushed a box on a slab's top 0.42 m sideways, out of a side wall's
        prism that reaches under the top."""
        inactive = out.dot(q @ ti.Vector([0.0, 0.0, 1.0])) < 1.0 - 1e-6
        if inactive:
            start = model.geom_point_start[prism]
            for k in ti.static(range(3)):
                if (model.geom_active[prism] >> k) & 1:
                    plane = model.geom_planes[model.geom_plane_start[prism] + 2 + k]
                    side = q @ ti.Vector([plane[0], plane[1], plane[2]])
                    along = q @ (model.geom_points[start + (k + 1) % 3] - model.geom_points[start + k])
                    if ti.abs(out.dot(along)) <= 1e-3 * along.norm() and out.dot(side) > 0.0:
                        inactive = False
        return inactive

    @ti.func
    def _cores_found(self, model: ti.template(), pair, poses, dist, pa, pb, margin):
        """One contact at the closest points pa, pb of two geoms' cores (GJK, `dist` apart: _points_in's
        side 2), for a round shape that meets the other with none of its points: a capsule across
        another, or across a box's edge; where the cores meet, two round cores crossing
        (_cores_crossing) or a round core through a polytope (_core_through)."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        if dist > 0.0:
            n = (pa - pb) / dist
            sep = dist - model.geom_radius[ga] - model.geom_radius[gb]
            if ti.static(model.rigid_prisms):
                if model.geom_prism[ga] != model.geom_prism[gb]:
                    if self._off_surface(model, ga, ra, gb, rb, n):
                        sep = margin  # this triangle's neighbours hold the contact
            if sep < margin:
                mu, e = self._material(model, a, b)
                point = pa - model.geom_radius[ga] * n
                self._add(a, b, ga, gb, FEATURES, 0, point, n, sep, ti.Vector.zero(float, 3), mu, e)
        elif model.geom_round[ga] and model.geom_round[gb]:
            self._cores_crossing(model, pair, poses, pa, margin)
        elif ti.static(model.rigid_round_and_polytopes):
            if model.geom_round[ga] != model.geom_round[gb]:
                self._core_through(model, pair, poses, margin)

    @ti.func
    def _cores_crossing(self, model: ti.template(), pair, poses, meet, margin):
        """Two round shapes whose cores meet (at `meet`): two capsules pushed across each other. They part
        along the common normal of their cores, n = d_a x d_b (the direction that moves two crossing
        lines apart; where the cores are parallel, the centres' offset across a's core, or along it for
        cores on one line), by the cores' overlap along n plus both radii: one contact at the meeting
        point."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        a0, a1 = xa + ra @ model.geom_seg0[ga], xa + ra @ model.geom_seg1[ga]
        b0, b1 = xb + rb @ model.geom_seg0[gb], xb + rb @ model.geom_seg1[gb]
        da, db = a1 - a0, b1 - b0
        offset = 0.5 * (a0 + a1 - b0 - b1)  # from b's core centre to a's
        n = da.cross(db)
        if n.norm_sqr() <= 1e-12 * da.norm_sqr() * db.norm_sqr():  # parallel, or a sphere's point core
            axis = da if da.norm_sqr() > 0.0 else db
            n = offset
            if axis.norm_sqr() > 0.0:
                n = offset - axis * axis.dot(offset) / axis.norm_sqr()
            if n.norm_sqr() <= 1e-12 * offset.norm_sqr():
                n = offset  # on one line: apart along it
        if n.norm_sqr() == 0.0:
            n = ti.Vector([0.0, 1.0, 0.0], float)  # centres on one line along the cores: any way out
        n = n.normalized()
        if n.dot(offset) < 0.0:
            n = -n
        core = ti.min(n.dot(a0), n.dot(a1)) - ti.max(n.dot(b0), n.dot(b1))
        sep = core - model.geom_radius[ga] - model.geom_radius[gb]
        if sep < margin:
            mu, e = self._material(model, a, b)
            point = meet - model.geom_radius[ga] * n
            self._add(a, b, ga, gb, FEATURES, 0, point, n, sep, ti.Vector.zero(float, 3), mu, e)

    @ti.func
    def _core_through(self, model: ti.template(), pair, poses, margin):
        """A round shape whose core passes through a polytope with neither end point within reach of it
        (a capsule across a thin wall, pushed in): contacts at both ends of the core along the shortest
        way out (sat.py's segment_axis, the depth EPA would find), each its own gap along that axis."""
        a, b, ga, gb = pair
        xa, ra, xb, rb = poses
        rnd, poly = ga, gb
        xr, rr, xp, rp = xa, ra, xb, rb
        sign = 1.0  # the stored normal runs from b towards a
        if model.geom_round[gb]:
            rnd, poly = gb, ga
            xr, rr, xp, rp = xb, rb, xa, ra
            sign = -1.0
        s0, s1 = xr + rr @ model.geom_seg0[rnd], xr + rr @ model.geom_seg1[rnd]
        depth, u = segment_axis(model, s0, s1, poly, xp, rp)  # u: from the polytope outwards
        if depth > 0.0:
            h = support(model, poly, xp, rp, u)
            radius = model.geom_radius[rnd]
            mu, e = self._material(model, a, b)
            for end in range(1 if (s1 - s0).norm_sqr() == 0.0 else 2):
                s = s0 if end == 0 else s1
                sep = u.dot(s) - h - radius
                if sep < margin:
                    zero = ti.Vector.zero(float, 3)
                    self._add(a, b, ga, gb, FEATURES, 1 + end, s - radius * u, sign * u, sep, zero, mu, e)

    @ti.func
    def _geoms(self, model: ti.template(), state: ti.template(), a, b, xa, ra, margin, skip_obb):
        """The contacts of bodies a (pose xa, ra) and b, part by part (one pair for simple shapes), and
        (the pairs of tree nodes whose bounding spheres met, the pairs of parts given the exact test, 1
        if any contact was found else 0). The cascade goes on inside bodies of several parts, down their
        trees of oriented boxes (obb_tree.py): a pair of nodes passes its bounding spheres, then its OBBs
        (Gottschalk et al.'s test, as between bodies; their world AABBs instead with skip_obb), before
        the larger node is opened, and a pair of leaves, before the exact test of their parts."""
        parted = (model.rigid_geom_start[a + 1] - model.rigid_geom_start[a] > 1) or (
            model.rigid_geom_start[b + 1] - model.rigid_geom_start[b] > 1
        )
        xb, rb = state.rigid_x[b], self.rot[b]
        found = self.found[None]
        near, exact = 0, 0
        if ti.static(model.rigid_parted):
            self.stack[0] = ti.Vector([model.rigid_node_start[a], model.rigid_node_start[b]])
            top = 1
            while top > 0:
                top -= 1
                na, nb = self.stack[top][0], self.stack[top][1]
                ca, qa = xa + ra @ model.node_offset[na], ra @ model.node_rot[na]
                cb, qb = xb + rb @ model.node_offset[nb], rb @ model.node_rot[nb]
                if (ca - cb).norm() <= model.node_bound[na] + model.node_bound[nb] + margin:
                    near += 1
                    test = True
                    if parted:  # with one part each, the bodies' OBB test was this one
                        ha, hb = model.node_half[na], model.node_half[nb]
                        if skip_obb:
                            test = not (ti.abs(cb - ca) > ti.abs(qa) @ ha + ti.abs(qb) @ hb + margin).any()
                        else:
                            test = obb_overlap(ha, hb, qa, qb, cb - ca, margin)
                    if test:
                        leaf_a, leaf_b = model.node_child[na][0] < 0, model.node_child[nb][0] < 0
                        if leaf_a and leaf_b:
                            exact += 1
                            ga, gb = model.node_geom[na], model.node_geom[nb]
                            self._exact(model, a, b, ga, gb, xa, ra, xb, rb, margin)
                        else:
                            # open the node that is no leaf, the larger one where neither is
                            open_a = leaf_b or (not leaf_a and model.node_bound[na] >= model.node_bound[nb])
                            for k in ti.static(range(2)):
                                pair = ti.Vector([model.node_child[na][k], nb])
                                if not open_a:
                                    pair = ti.Vector([na, model.node_child[nb][k]])
                                self.stack[top] = pair
                                top += 1
        else:  # one part each: the bodies' OBB test was the parts'
            ga, gb = model.rigid_geom_start[a], model.rigid_geom_start[b]
            pa, pb = xa + ra @ model.geom_offset[ga], xb + rb @ model.geom_offset[gb]
            if (pa - pb).norm() <= model.geom_bound[ga] + model.geom_bound[gb] + margin:
                near, exact = 1, 1
                self._exact(model, a, b, ga, gb, xa, ra, xb, rb, margin)
        return near, exact, ti.i32(self.found[None] > found)

    @ti.func
    def _exact(self, model: ti.template(), a, b, ga, gb, xa, ra, xb, rb, margin):
        """The exact test of geom ga of body a (pose xa, ra) and geom gb of body b (xb, rb): its contacts.
        Two polytopes: the closest points of two edges where an edge-edge axis separates them least,
        else both geoms' vertices along the face normal that does (sat.py); none where one is a mesh's
        triangle and the axis runs inside the mesh's surface (_inactive). Each contact routine appears
        once in the kernel: a copy per case made the detection compile seconds longer."""
        pa, qa = model.geom_pose(ga, xa, ra)
        pb, qb = model.geom_pose(gb, xb, rb)
        pair = (a, b, ga, gb)
        poses = (pa, qa, pb, qb)
        before = self.found[None]
        polytopes = model.geom_round[ga] == 0 and model.geom_round[gb] == 0
        pair_n = ti.Vector.zero(float, 3)
        faces = ti.Vector.zero(float, 2)
        edge = False
        inside = False
        if polytopes:
            normal, sep, edge_wins, point = polytope_axis(model, ga, pa, qa, gb, pb, qb)
            edge = edge_wins
            if ti.static(model.rigid_prisms):
                if model.geom_prism[ga] != model.geom_prism[gb]:
                    # an axis inside the surface: this triangle is not what the shape touches
                    inside = self._off_surface(model, ga, qa, gb, qb, normal)
            if edge:
                if sep < margin and not inside:
                    mu, e = self._material(model, a, b)
                    zero = ti.Vector.zero(float, 3)
                    self._add(a, b, ga, gb, FEATURES, 0, point, normal, sep, zero, mu, e)
            else:
                pair_n = normal
                faces = ti.Vector([support(model, gb, pb, qb, normal), -support(model, ga, pa, qa, -normal)])
        if not edge and not inside:
            # sides 0 and 1: each geom's points in the other; side 2 (shapes with round cores): the cores'
            # closest points, for a round shape whose points found no contact (one pass of _points_in)
            for side in range(ti.static(3 if model.rigid_has_round else 2)):
                if side < 2 or (not polytopes and self.found[None] == before):
                    self._points_in(model, pair, poses, side, pair_n, faces[side % 2], margin)
            # Face clipping where the vertices found are fewer than 4 (a heuristic: 4 found are corners
            # of the contact polygon, though not always all of them, e.g. two quads overlapping in a
            # hexagon), as on a stack or a pyramid, where clipping found nothing new and took 13 % of a
            # pyramid's step.
            if polytopes and self.found[None] - before < 4:
                for side in range(2):
                    self._edges_clipped(model, pair, poses, side, pair_n, faces[side], margin)
        if ti.static(self.manifold_points):
            self._reduce(before)

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
        # Room for one body (rigid_capacity 1: a scene with one body, as the pour demo's box) leaves no
        # pair to search: the sweep and the pairs' exact tests, most of this kernel, are not compiled.
        if ti.static(model.rigid_capacity > 1):
            self._sweep(model, state, h)  # broad_phase.py: the pairs whose spheres may meet
        # pairs with a dynamic body, all of them counted (the sweep leaves out what cannot meet)
        fixed = 0
        ti.loop_config(serialize=True)
        for i in range(model.live_rigid()):
            if model.rigid_inv_mass[i] == 0.0:
                fixed += 1
        n = model.live_rigid()
        pairs64 = ti.i64(n) * (n - 1) // 2 - ti.i64(fixed) * (fixed - 1) // 2
        pairs = ti.i32(ti.min(pairs64, 2147483647))  # the counts are i32
        spheres, aabbs, obbs, touching, part_spheres, exact_tests = 0, 0, 0, 0, 0, 0
        ti.loop_config(serialize=True)
        for a in range(model.live_rigid()):
            xa, ra = state.rigid_x[a], self.rot[a]
            reach_a = self._reach(model, state, a, h)
            if ti.static(model.rigid_capacity > 1):
                count, first = self._partners(model, a)
                for k in range(count):
                    b = self._partner(a, first, k)
                    if model.rigid_inv_mass[a] == 0.0 and model.rigid_inv_mass[b] == 0.0:
                        continue
                    level, margin = self._cascade(model, state, a, xa, ra, reach_a, b, h, 3, False)
                    # counted in registers, written once below: a loop of global adds per pair (one per
                    # level reached) made the 1000-box bin's step 1.4 ms longer (half a million pairs)
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
                    if not model.geom_contact_point[k]:
                        continue
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
