"""The proximity constraints of cloth self-contact (self_contact.py, item 1): Gauss-Seidel sweeps that
push every vertex-triangle and edge-edge pair closer than the thickness apart along its closest-feature
direction (Bridson, Fedkiw & Anderson, "Robust Treatment of Collisions, Contact and Friction for Cloth
Animation", SIGGRAPH 2002, sec. 7.1; the position-based constraint of Mueller et al., "Position Based
Dynamics", 2007, eq. 9, with the inverse masses weighted by the barycentric coordinates), with Coulomb
friction on the pair's tangential displacement (Macklin et al., "Unified Particle Physics for Real-Time
Applications", 2014, eq. 24). This mixin holds its kernels, on SelfContact's arrays.
"""

import taichi as ti

from ..runtime import data_oriented
from ..spatial.distance import point_triangle_closest, segment_segment_closest
from .response import project_spheres

# A pair found closer than this to zero distance has no direction of its own: it takes the direction it
# had at the step's start, or the triangle's normal.
TINY = 1e-12


@data_oriented
class ProximitySweeps:
    """Mixin of SelfContact: `_proximity` runs the sweeps over the pairs marked near."""

    @ti.func
    def _w(self, model: ti.template(), v):
        return model.inv_mass(self.vertex[v])

    @ti.func
    def _pair_correction(self, model: ti.template(), state: ti.template(), idx, coef, side):
        """Push the pair's two sides apart to the thickness: idx holds four local vertices, coef their
        weights (positive on the first side, negative on the second, summing to zero), so the gap is
        sum coef_k x_k; side is the unit direction from side two to side one at the step's start, the
        fallback for a gap of zero length."""
        gap = ti.Vector.zero(float, 3)
        gap0 = ti.Vector.zero(float, 3)
        for k in ti.static(range(4)):
            gap += coef[k] * state.particle_x[self.vertex[idx[k]]]
            gap0 += coef[k] * self.x0[idx[k]]
        d = gap.norm()
        n = side
        if d > TINY:
            n = gap / d
            if n.dot(gap0) < 0.0:
                n = -n  # crossed since the step's start: push back to the start's side
                d = -d
        c = self.thickness - d
        if c > 0.0:
            wsum = 0.0
            for k in ti.static(range(4)):
                wsum += self._w(model, idx[k]) * coef[k] * coef[k]
            if wsum > 0.0:
                s = self.relaxation * c / wsum
                # Friction: the pair's relative tangential motion over the step shrinks by at most mu c.
                rel = gap - gap0
                rel_t = rel - rel.dot(n) * n
                slip = rel_t.norm()
                cut = ti.min(self.relaxation * self.friction * c, slip) / ti.max(slip, TINY) / wsum
                for k in ti.static(range(4)):
                    w = self._w(model, idx[k]) * coef[k]
                    if w != 0.0:
                        state.particle_x[self.vertex[idx[k]]] += w * (s * n - cut * rel_t)

    @ti.func
    def _vertex_triangle(self, model: ti.template(), state: ti.template(), v, f):
        t = self.tri[f]
        a = state.particle_x[self.vertex[t[0]]]
        b = state.particle_x[self.vertex[t[1]]]
        c = state.particle_x[self.vertex[t[2]]]
        w = point_triangle_closest(state.particle_x[self.vertex[v]], a, b, c)
        a0, b0, c0 = self._tri_x0(f)
        side = (b0 - a0).cross(c0 - a0)
        if side.dot(self.x0[v] - a0) < 0.0:
            side = -side
        side = side / ti.max(side.norm(), TINY)
        idx = ti.Vector([v, t[0], t[1], t[2]])
        coef = ti.Vector([1.0, -w[0], -w[1], -w[2]])
        self._pair_correction(model, state, idx, coef, side)

    @ti.func
    def _edge_edge(self, model: ti.template(), state: ti.template(), e, g):
        i0, i1, j0, j1 = self.edge[e][0], self.edge[e][1], self.edge[g][0], self.edge[g][1]
        st = segment_segment_closest(
            state.particle_x[self.vertex[i0]],
            state.particle_x[self.vertex[i1]],
            state.particle_x[self.vertex[j0]],
            state.particle_x[self.vertex[j1]],
        )
        idx = ti.Vector([i0, i1, j0, j1])
        coef = ti.Vector([1.0 - st[0], st[0], -(1.0 - st[1]), -st[1]])
        gap0 = coef[0] * self.x0[i0] + coef[1] * self.x0[i1] + coef[2] * self.x0[j0] + coef[3] * self.x0[j1]
        side = (self.x0[i1] - self.x0[i0]).cross(self.x0[j1] - self.x0[j0])
        if side.norm_sqr() < TINY * TINY:
            side = gap0  # parallel edges: the direction between them at the step's start
        if side.dot(gap0) < 0.0:
            side = -side
        side = side / ti.max(side.norm(), TINY)
        self._pair_correction(model, state, idx, coef, side)

    @ti.kernel
    def _proximity(self, model: ti.template(), state: ti.template(), t_end: float):
        # Gauss-Seidel sweeps in one serial task: each pair's correction is applied at once (it sums to
        # zero momentum), the fixed order makes runs reproducible, and one launch replaces several.
        ti.loop_config(serialize=True)
        for _ in range(1):
            for _sweep in range(self.iterations):
                for v in range(self.verts()):
                    for j in range(self.vt_n[v]):
                        k = v * self.slots + j
                        if self.vt_near[k]:
                            self._vertex_triangle(model, state, v, self.vt_tri[k])
                for e in range(self.edges()):
                    for j in range(self.ee_n[e]):
                        k = e * self.slots + j
                        if self.ee_near[k]:
                            self._edge_edge(model, state, e, self.ee_other[k])
                if ti.static(model.collider_count > 0):
                    # A contact must not push a vertex into a collider (the lower of two sheets on a ball).
                    for v in range(self.verts()):
                        i = self.vertex[v]
                        if model.inv_mass(i) == 0.0:
                            continue  # pinned: kinematic, colliders do not move it
                        x, _v = project_spheres(
                            model.colliders,
                            state.particle_x[i],
                            state.particle_v[i],
                            model.radius(i),
                            -1.0,
                            t_end,
                        )
                        state.particle_x[i] = x
