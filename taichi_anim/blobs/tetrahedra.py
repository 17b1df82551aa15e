"""Isosurface by marching tetrahedra in Taichi, visiting only the flagged blocks of a BlobField.

Marching cubes (Lorensen & Cline 1987, "Marching Cubes: A High Resolution 3D Surface Construction
Algorithm") applied to a split of each grid cell into six tetrahedra around its main diagonal (corner 0
to corner 7), as in Doi & Koide 1991 ("An Efficient Method of Triangulating Equi-Valued Surfaces by Using
Tetrahedral Cells"). Every cell uses the same split, so the diagonals of a shared face agree and the
surface has no cracks; a tetrahedron has no ambiguous case, so the table below is generated (16 sign
patterns per tetrahedron, at most two triangles each) instead of the 256-entry cube table.

All 19 edges of the split join a corner to one whose coordinates are each >= its own (direction
d in {0,1}^3 \\ 0, 7 directions), so a vertex is named by (lower grid node, d) and shared by every
tetrahedron around that edge: the mesh is welded by construction. A node is inside when psi > iso; the
triangles are wound counter-clockwise seen from outside (normal towards decreasing psi).

Two passes over the flagged blocks (in parallel over blocks, serially inside one): count the vertices and
triangles of each block, scan the counts, then write them at their block's offset. Output order depends
only on the block order, so the mesh is the same on any thread count.
"""

import numpy as np
import taichi as ti

from ..runtime import data_oriented
from .blocks import BLOCK3

CORNER = [
    (c & 1, (c >> 1) & 1, (c >> 2) & 1) for c in range(8)
]  # cube corner -> (x, y, z) offset, bit k = axis k
TETRAHEDRA = [(0, 1, 3, 7), (0, 3, 2, 7), (0, 2, 6, 7), (0, 6, 4, 7), (0, 4, 5, 7), (0, 5, 1, 7)]


def _edge(a: int, b: int) -> int:
    """Code of the cube edge between corners a and b: lower corner * 8 + direction bits."""
    lo, hi = (a, b) if (a & b) == a else (b, a)
    assert (lo & hi) == lo, "every edge of the split is monotone"
    return lo * 8 + (lo ^ hi)


def triangle_table() -> tuple[np.ndarray, np.ndarray]:
    """(count (6, 16), edges (6, 16, 2, 3)): for tetrahedron t and inside-mask m (bit j = corner
    TETRAHEDRA[t][j] inside), the triangles as three edge codes each, wound so that their normal points
    from the inside corners to the outside ones."""
    count = np.zeros((6, 16), dtype=np.int32)
    edges = np.zeros((6, 16, 2, 3), dtype=np.int32)
    pos = np.asarray(CORNER, dtype=np.float64)
    for t, tet in enumerate(TETRAHEDRA):
        for m in range(1, 15):
            ins = [tet[j] for j in range(4) if m >> j & 1]
            out = [tet[j] for j in range(4) if not m >> j & 1]
            if len(ins) == 1:
                polys = [[(ins[0], o) for o in out]]
            elif len(ins) == 3:
                polys = [[(i, out[0]) for i in ins]]
            else:  # a quad through the four edges joining the two inside and the two outside corners
                a, b = ins
                c, d = out
                quad = [(a, c), (a, d), (b, d), (b, c)]
                polys = [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
            for k, tri in enumerate(polys):
                # Wind by geometry at midpoints: the sign is the same for any crossing points strictly
                # inside the edges (the triangle cannot degenerate there), so one evaluation decides.
                p = np.array([(pos[u] + pos[v]) / 2 for u, v in tri])
                normal = np.cross(p[1] - p[0], p[2] - p[0])
                if normal @ (pos[out].mean(0) - pos[ins].mean(0)) < 0:
                    tri = tri[::-1]
                edges[t, m, k] = [_edge(u, v) for u, v in tri]
            count[t, m] = len(polys)
    return count, edges


@data_oriented
class MarchingTetrahedra:
    """Isosurface extractor over the flagged blocks of `field` (a BlobField, read through its grid and
    block attributes); scratch: one i32 per grid node."""

    def __init__(self, field):
        self.f = field
        # Per node: index of its first vertex within its block (low 12 bits, < 7 * BLOCK^3 = 3584) and
        # which of its 7 edges cross the level (7 bits above).
        self.node_edges = ti.field(ti.i32, field.dims)
        self.block_vertices = ti.field(ti.i32, field.block_count + 1)
        self.block_triangles = ti.field(ti.i32, field.block_count + 1)
        self.totals = ti.field(ti.i32, 2)
        count, edges = triangle_table()
        self.tri_count = ti.field(ti.i32, (6, 16))
        self.tri_edges = ti.field(ti.i32, (6, 16, 6))
        self.tri_count.from_numpy(count)
        self.tri_edges.from_numpy(edges.reshape(6, 16, 6))

    def extract(self, iso: float) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (V,3) [m] float64, triangles (F,3) int32) of psi = iso from the last evaluation."""
        self._count(iso)
        nv, nt = (int(c) for c in self.totals.to_numpy())
        verts = np.zeros((nv, 3), dtype=np.float64)
        tris = np.zeros((nt, 3), dtype=np.int32)
        if nv and nt:
            self._fill(iso, verts, tris)
        return verts, tris

    @ti.func
    def _crossing_mask(self, node, iso):
        """Bit d-1 set when the edge from `node` in direction d crosses the level."""
        dims = ti.Vector(self.f.dims)
        inside = self.f.value(node) > iso
        mask = 0
        for d in ti.static(range(1, 8)):
            q = node + ti.Vector(CORNER[d])
            if (q < dims).all():
                if (self.f.value(q) > iso) != inside:
                    mask |= 1 << (d - 1)
        return mask

    @ti.func
    def _cell_masks(self, node, iso):
        """Inside-mask (bit c = corner c) of the cell whose lowest corner is `node`; -1 if no such cell."""
        dims = ti.Vector(self.f.dims)
        m = -1
        if (node < dims - 1).all():
            m = 0
            for c in ti.static(range(8)):
                if self.f.value(node + ti.Vector(CORNER[c])) > iso:
                    m |= 1 << c
        return m

    @ti.func
    def _tet_mask(self, cell_mask, t: ti.template()):
        m = 0
        for j in ti.static(range(4)):
            m |= ((cell_mask >> TETRAHEDRA[t][j]) & 1) << j
        return m

    @ti.kernel
    def _count(self, iso: float):
        f = self.f
        for s in range(f.active_count[None]):
            b = f.active_block[s]
            nv = 0
            nt = 0
            for local in range(BLOCK3):
                node = f.block_node(b, local)
                if f.inside_grid(node):
                    mask = self._crossing_mask(node, iso)
                    self.node_edges[node] = nv | (mask << 12)
                    nv += ti.math.popcnt(mask)
                    cm = self._cell_masks(node, iso)
                    if cm > 0 and cm != 255:
                        for t in ti.static(range(6)):
                            nt += self.tri_count[t, self._tet_mask(cm, t)]
            self.block_vertices[s] = nv
            self.block_triangles[s] = nt
        ti.loop_config(serialize=True)
        for _ in range(1):
            av = 0
            at = 0
            for s in range(f.active_count[None]):
                v = self.block_vertices[s]
                self.block_vertices[s] = av
                av += v
                t = self.block_triangles[s]
                self.block_triangles[s] = at
                at += t
            self.totals[0] = av
            self.totals[1] = at

    @ti.func
    def _vertex_id(self, cell, code):
        lo = code >> 3
        node = cell + ti.Vector([lo & 1, (lo >> 1) & 1, (lo >> 2) & 1])
        d = code & 7
        e = self.node_edges[node]
        rank = ti.math.popcnt((e >> 12) & ((1 << (d - 1)) - 1))
        return self.block_vertices[self.f.block_slot[self.f.block_of(node)]] + (e & 0xFFF) + rank

    @ti.kernel
    def _fill(self, iso: float, verts: ti.types.ndarray(), tris: ti.types.ndarray()):
        f = self.f
        for s in range(f.active_count[None]):
            b = f.active_block[s]
            v = self.block_vertices[s]
            tri = self.block_triangles[s]
            for local in range(BLOCK3):
                node = f.block_node(b, local)
                if f.inside_grid(node):
                    mask = self.node_edges[node] >> 12
                    a = f.value(node)
                    for d in ti.static(range(1, 8)):
                        if mask & (1 << (d - 1)):
                            off = ti.Vector(CORNER[d])
                            w = (iso - a) / (f.value(node + off) - a)  # crossing: the values differ
                            p = f.node_position(node[0], node[1], node[2]) + f.spacing * w * off
                            for c in ti.static(range(3)):
                                verts[v, c] = p[c]
                            v += 1
                    cm = self._cell_masks(node, iso)
                    if cm > 0 and cm != 255:
                        for t in ti.static(range(6)):
                            m = self._tet_mask(cm, t)
                            for k in range(self.tri_count[t, m]):
                                for c in ti.static(range(3)):
                                    tris[tri, c] = self._vertex_id(node, self.tri_edges[t, m, 3 * k + c])
                                tri += 1
