"""Rigid contact detection: the course's cascade of bounding volumes, then contact points.

Every pair of bodies goes through cheaper tests first and the exact one last (the collision chapter's
"spheres within AABB within OBB"): bounding spheres about the centres of mass, world AABBs (each body's OBB
projected on the world axes), the OBB-OBB separating-axis test on the 15 axes of Gottschalk, Lin & Manocha
("OBBTree", SIGGRAPH 1996, sec. 4), and only then the exact test and its contact points: two polytopes'
separating axis (sat.py), then each body's points (vertices; a round shape's core points with its radius)
against the other's signed distance (geometry.py), both ways; where a round shape meets something with none
of its points, the closest points of the two cores (gjk.py). A body's points are also tested against every
collider's signed distance (`Collider.contact`). How many pairs each level passes is counted
(`RigidContacts.cascade`): the cost model T = N_v C_v + N_p C_p of the course, measured.

Contacts within the margin are kept (speculative contacts: the solver lets such a gap close, no more), keyed
by (body a, body b or collider, side, point) so that the next step can find its impulse again (warm
starting). A body made of several convex parts (a compound) meets others part by part (geoms)."""

import taichi as ti

from .quaternion import quat_matrix

NO_BODY = -1  # the b side of a contact with a collider


@ti.func
def geom_sdf(model: ti.template(), b, xb, rb, p):
    """(signed distance [m], outward unit normal (world)) of geom b (a body's convex part, its frame at
    xb, rotation rb) at world p."""
    local = rb.transpose() @ (p - xb)
    dist = ti.cast(0.0, float)
    normal = ti.Vector([0.0, 1.0, 0.0], float)
    if model.geom_round[b]:
        s0, s1 = model.geom_seg0[b], model.geom_seg1[b]
        axis = s1 - s0
        u = ti.cast(0.0, float)
        if axis.norm_sqr() > 0.0:
            u = ti.min(ti.max((local - s0).dot(axis) / axis.norm_sqr(), 0.0), 1.0)
        off = local - (s0 + u * axis)
        length = off.norm()
        if length > 1e-12:
            normal = off / length
        dist = length - model.geom_radius[b]
    elif model.geom_box[b]:
        # its six planes in closed form (the largest of |local| - half): a pyramid's detection spends
        # most of its time on box corners against boxes
        q = ti.abs(local) - model.geom_half[b]
        dist = ti.max(q[0], q[1], q[2])
        axis = ti.Vector([q[0] == dist, q[0] < dist and q[1] == dist, q[0] < dist and q[1] < dist], float)
        normal = axis * ti.select(local >= 0.0, 1.0, -1.0)
    else:
        dist = -1e30
        for k in range(model.geom_plane_start[b], model.geom_plane_start[b + 1]):
            plane = model.geom_planes[k]
            n = ti.Vector([plane[0], plane[1], plane[2]])
            d = n.dot(local) - plane[3]
            if d > dist:
                dist = d
                normal = n
    return dist, rb @ normal


@ti.func
def obb_overlap(ha, hb, ra, rb, d, margin):
    """Whether two OBBs (half extents ha, hb along the columns of ra, rb; centres d apart) come within
    `margin`: no separating axis among the 15 of Gottschalk et al. (a margin on an unnormalised cross
    axis keeps the test conservative)."""
    r = ra.transpose() @ rb
    t = ra.transpose() @ d
    absr = ti.abs(r) + 1e-9  # parallel edges give a null cross axis: keep it from separating by round-off
    overlap = True
    for i in ti.static(range(3)):
        if ti.abs(t[i]) > ha[i] + hb.dot(ti.Vector([absr[i, 0], absr[i, 1], absr[i, 2]])) + margin:
            overlap = False
    for j in ti.static(range(3)):
        proj = t[0] * r[0, j] + t[1] * r[1, j] + t[2] * r[2, j]
        if ti.abs(proj) > ha.dot(ti.Vector([absr[0, j], absr[1, j], absr[2, j]])) + hb[j] + margin:
            overlap = False
    for i in ti.static(range(3)):
        i1, i2 = ti.static((i + 1) % 3, (i + 2) % 3)
        for j in ti.static(range(3)):
            j1, j2 = ti.static((j + 1) % 3, (j + 2) % 3)
            ext_a = ha[i1] * absr[i2, j] + ha[i2] * absr[i1, j]
            ext_b = hb[j1] * absr[i, j2] + hb[j2] * absr[i, j1]
            if ti.abs(t[i2] * r[i1, j] - t[i1] * r[i2, j]) > ext_a + ext_b + margin:
                overlap = False
    return overlap


@ti.func
def body_sdf(model: ti.template(), b, xb, rb, p):
    """(signed distance [m], outward unit normal (world)) of body b (com xb, rotation rb) at world p:
    its nearest part's."""
    dist = ti.cast(1e30, float)
    normal = ti.Vector([0.0, 1.0, 0.0], float)
    for g in range(model.rigid_geom_start[b], model.rigid_geom_start[b + 1]):
        xg, rg = model.geom_pose(g, xb, rb)
        d, n = geom_sdf(model, g, xg, rg, p)
        if d < dist:
            dist, normal = d, n
    return dist, normal


@ti.func
def pose(state: ti.template(), i):
    """(com [m], rotation matrix) of body i now."""
    return state.rigid_x[i], quat_matrix(state.rigid_q[i])


@ti.func
def support(model: ti.template(), i, x, r, u):
    """max over geom i's points (its frame at x, rotation r) of u . p: its extent along u [m]; for a
    box, in closed form from its half extents."""
    best = -1e30
    if model.geom_box[i]:
        best = u.dot(x) + (ti.abs(r.transpose() @ u)).dot(model.geom_half[i])
    else:
        for k in range(model.geom_point_start[i], model.geom_point_start[i + 1]):
            best = ti.max(best, u.dot(x + r @ model.geom_points[k]))
    return best


@ti.func
def separation(model: ti.template(), a, xa, ra, b, xb, rb, u):
    """How far geom a lies beyond geom b along u (negative: their overlap along u)."""
    return -support(model, a, xa, ra, -u) - support(model, b, xb, rb, u)
