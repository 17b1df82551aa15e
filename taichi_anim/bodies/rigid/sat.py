"""The separating-axis test between two polytopes (boxes, convex hulls, a mesh body's hull), exact: the
axis of least overlap among both bodies' face normals and the cross products of their edges. Two boxes
take Gottschalk, Lin & Manocha's 15 axes ("OBBTree", SIGGRAPH 1996, sec. 4) with their edges in closed
form; other polytopes prune their edge pairs on the Gauss map (Gregorius, "The Separating Axis Test
between Convex Polyhedra", GDC 2013): a pair of edges can give the axis only where it builds a face of
the Minkowski difference, that is where the arcs of the two edges' face normals cross.

Where an edge-edge axis wins, the contact is the closest points of the two edges (as ODE's dBoxBox
and Jolt's edge case give one contact there); where a face wins, rigid contacts make the manifold from
both bodies' vertices along its normal (detection.py). segment_axis gives a round core's depth in a
polytope it has gone through."""

import taichi as ti

from .narrow_phase import separation, support

# A face of a, or an edge-edge axis, replaces the best axis so far only when clearly better: resting
# contacts then keep one normal from step to step instead of flickering between near-ties (Jolt and Box2D
# bias their separating-axis choices the same way).
FACE_BIAS = 1e-5  # [m]
EDGE_BIAS = 1e-3  # [m]


@ti.func
def _unit(i):
    """The unit vector along axis i (0, 1, 2) chosen at run time."""
    return ti.Vector([1.0 if i == 0 else 0.0, 1.0 if i == 1 else 0.0, 1.0 if i == 2 else 0.0])


@ti.func
def segment_closest(p1, q1, p2, q2):
    """The closest points of segments p1 q1 and p2 q2 (Ericson, "Real-Time Collision Detection", 2005,
    sec. 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1.norm_sqr(), d2.norm_sqr(), d2.dot(r)
    s = ti.cast(0.0, float)
    t = ti.cast(0.0, float)
    tiny = 1e-20
    if a <= tiny and e <= tiny:
        s, t = 0.0, 0.0
    elif a <= tiny:
        t = ti.min(ti.max(f / e, 0.0), 1.0)
    else:
        c = d1.dot(r)
        if e <= tiny:
            s = ti.min(ti.max(-c / a, 0.0), 1.0)
        else:
            b = d1.dot(d2)
            denom = a * e - b * b
            if denom > 0.0:
                s = ti.min(ti.max((b * f - c * e) / denom, 0.0), 1.0)
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = ti.min(ti.max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = ti.min(ti.max((b - c) / a, 0.0), 1.0)
    return p1 + s * d1, p2 + t * d2


@ti.func
def face_axes(model: ti.template(), a, xa, ra, b, xb, rb):
    """(largest separation of a beyond b along a face normal (negative: overlap), that normal (from b
    towards a)): b's faces, then a's."""
    best = -1e30
    normal = ti.Vector([0.0, 1.0, 0.0], float)
    b0, a0 = model.geom_plane_start[b], model.geom_plane_start[a]
    nb, na = model.geom_plane_start[b + 1] - b0, model.geom_plane_start[a + 1] - a0
    for m in range(nb + na):
        # one read at a selected index: Taichi evaluates both sides of a conditional expression, and the
        # unselected read would fall past the plane array for the last body
        plane = model.geom_planes[b0 + m if m < nb else a0 + m - nb]
        u = ti.Vector([plane[0], plane[1], plane[2]])
        u = rb @ u if m < nb else -(ra @ u)
        s = separation(model, a, xa, ra, b, xb, rb, u)
        if s > best + (0.0 if m < nb else FACE_BIAS):
            best, normal = s, u
    return best, normal


@ti.func
def box_edges(model: ti.template(), a, xa, ra, b, xb, rb):
    """(separation, axis from b towards a, contact point) of the best of two boxes' 9 edge-edge axes,
    the contact at the closest points of the two edges that support it."""
    best = -1e30
    normal = ti.Vector([0.0, 1.0, 0.0], float)
    best_i, best_j = 0, 0
    for e in range(9):
        i, j = e // 3, e % 3
        u = (ra @ _unit(i)).cross(rb @ _unit(j))
        length = u.norm()
        if length > 1e-6:  # parallel edges: the face axes hold that case
            u /= length
            if u.dot(xa - xb) < 0.0:
                u = -u
            s = separation(model, a, xa, ra, b, xb, rb, u)
            if s > best:
                best, normal, best_i, best_j = s, u, i, j
    # b's edge along its axis j farthest along the normal, a's along its axis i farthest against it
    side_b = ti.math.sign(rb.transpose() @ normal) * model.geom_half[b]
    side_a = -ti.math.sign(ra.transpose() @ normal) * model.geom_half[a]
    side_b[best_j], side_a[best_i] = 0.0, 0.0
    half_b = rb @ (_unit(best_j) * model.geom_half[b][best_j])
    half_a = ra @ (_unit(best_i) * model.geom_half[a][best_i])
    cb, ca = xb + rb @ side_b, xa + ra @ side_a
    pb, pa = segment_closest(cb - half_b, cb + half_b, ca - half_a, ca + half_a)
    return best, normal, 0.5 * (pa + pb)


@ti.func
def _minkowski_face(n0, n1, m0, m1):
    """Whether the great arcs n0 n1 and m0 m1 cross (Gregorius 2013): the arcs of two edges' face
    normals, one of them negated, build a face of the Minkowski difference."""
    nn = n1.cross(n0)
    mm = m1.cross(m0)
    cba, dba = m0.dot(nn), m1.dot(nn)
    adc, bdc = n0.dot(mm), n1.dot(mm)
    return cba * dba < 0.0 and adc * bdc < 0.0 and cba * bdc > 0.0


@ti.func
def hull_edges(model: ti.template(), a, xa, ra, b, xb, rb):
    """(separation, axis from b towards a, contact point) of the best edge-edge axis of two polytopes,
    over the pairs of edges that pass the Gauss-map test."""
    best = -1e30
    normal = ti.Vector([0.0, 1.0, 0.0], float)
    point = xa
    for eb in range(model.geom_edge_start[b], model.geom_edge_start[b + 1]):
        edge_b = model.geom_edges[eb]
        pb0 = xb + rb @ ti.Vector([edge_b[0, 0], edge_b[0, 1], edge_b[0, 2]])
        pb1 = xb + rb @ ti.Vector([edge_b[1, 0], edge_b[1, 1], edge_b[1, 2]])
        nb0 = rb @ ti.Vector([edge_b[2, 0], edge_b[2, 1], edge_b[2, 2]])
        nb1 = rb @ ti.Vector([edge_b[3, 0], edge_b[3, 1], edge_b[3, 2]])
        for ea in range(model.geom_edge_start[a], model.geom_edge_start[a + 1]):
            edge_a = model.geom_edges[ea]
            na0 = ra @ ti.Vector([edge_a[2, 0], edge_a[2, 1], edge_a[2, 2]])
            na1 = ra @ ti.Vector([edge_a[3, 0], edge_a[3, 1], edge_a[3, 2]])
            if _minkowski_face(nb0, nb1, -na0, -na1):
                pa0 = xa + ra @ ti.Vector([edge_a[0, 0], edge_a[0, 1], edge_a[0, 2]])
                pa1 = xa + ra @ ti.Vector([edge_a[1, 0], edge_a[1, 1], edge_a[1, 2]])
                u = (pb1 - pb0).cross(pa1 - pa0)
                length = u.norm()
                if length > 1e-6 * (pb1 - pb0).norm() * (pa1 - pa0).norm():
                    u /= length
                    if u.dot(pb0 - xb) < 0.0:  # outward from b (its centre of mass is inside it)
                        u = -u
                    s = u.dot(pa0 - pb0)
                    if s > best:
                        best, normal = s, u
                        closest_b, closest_a = segment_closest(pb0, pb1, pa0, pa1)
                        point = 0.5 * (closest_a + closest_b)
    return best, normal, point


@ti.func
def polytope_axis(model: ti.template(), a, xa, ra, b, xb, rb):
    """(normal from b towards a, separation along it [m] (negative: overlap), whether an edge-edge axis
    won, the edge contact point) of two polytopes a and b."""
    s, normal = face_axes(model, a, xa, ra, b, xb, rb)
    edge_s = ti.cast(-1e30, float)
    edge_n = normal
    point = xa
    if model.geom_box[a] and model.geom_box[b]:
        edge_s, edge_n, point = box_edges(model, a, xa, ra, b, xb, rb)
    else:
        edge_s, edge_n, point = hull_edges(model, a, xa, ra, b, xb, rb)
    edge = edge_s > s + EDGE_BIAS
    if edge:
        s, normal = edge_s, edge_n
    return normal, s, edge, point


@ti.func
def segment_axis(model: ti.template(), s0, s1, g, xg, rg):
    """(depth [m], unit axis from g outwards) of the shortest translation that takes the segment s0 s1
    (world) out of polytope geom g: the least h_g(u) - min(u . s0, u . s1) over g's face normals and, both
    ways, the cross products of g's edges with the segment. These are the face normals of the Minkowski
    difference of g and the segment, so the least is exact (the separating-axis theorem: the depth EPA
    would find for this pair, without its polytope expansion). Positive: they overlap."""
    d = s1 - s0
    best = ti.cast(1e30, float)
    axis = ti.Vector([0.0, 1.0, 0.0], float)
    for k in range(model.geom_plane_start[g], model.geom_plane_start[g + 1]):
        plane = model.geom_planes[k]
        u = rg @ ti.Vector([plane[0], plane[1], plane[2]])
        depth = plane[3] + u.dot(xg) - ti.min(u.dot(s0), u.dot(s1))
        if depth < best:
            best, axis = depth, u
    for e in range(model.geom_edge_start[g], model.geom_edge_start[g + 1]):
        edge = model.geom_edges[e]
        along = rg @ ti.Vector([edge[1, 0] - edge[0, 0], edge[1, 1] - edge[0, 1], edge[1, 2] - edge[0, 2]])
        u = along.cross(d)
        length = u.norm()
        if length > 1e-6 * along.norm() * d.norm():  # parallel: the face normals hold that case
            u /= length
            for sign in ti.static((1.0, -1.0)):
                depth = support(model, g, xg, rg, sign * u) - ti.min(sign * u.dot(s0), sign * u.dot(s1))
                if depth < best:
                    best, axis = depth, sign * u
    return best, axis
