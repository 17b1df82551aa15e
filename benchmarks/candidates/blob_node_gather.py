"""Candidate measured by benchmarks/blobs.py: the blob field gathered node by node.

Same field, cutoff, flagged blocks and zero outer layer as `taichi_anim.BlobField` (Blinn 1982,
psi(p) = sum_i exp(-|p - p_i|^2 / sigma^2) truncated at r_c), but each interior node of a flagged block
queries the neighbour structure itself (radius r_c, cells of r_c) and evaluates one exponential per
particle within r_c. The engine instead queries once per block and uses the Gaussian's factorisation
over the axes (3 x 8 exponentials per particle and block of 8^3 nodes).
"""

import numpy as np
import taichi as ti

from taichi_anim import BlobField
from taichi_anim.blobs.field import BLOCK3
from taichi_anim.collision.neighbors import make_neighbor_search


@ti.data_oriented
class BlobFieldNodeGather(BlobField):
    """BlobField with a per-node gather; same constructor."""

    def __init__(self, **options):
        super().__init__(**options)
        r = self.cutoff_radius  # a node needs only r_c: smaller cells, fewer candidates than the block query
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        self.neighbors = make_neighbor_search(
            self.capacity,
            r,
            domain=(tuple(lo - r), tuple(hi + r)),
            method=options.get("neighbor_method", "grid"),
        )
        self._Sum = ti.types.struct(p=ti.types.vector(3, float), s=float)

    @ti.func
    def _add_blob(self, i, k, ret: ti.template()):
        ret.s += ti.exp(-(self.neighbors.sorted_x[k] - ret.p).norm_sqr() * self._inv_s2)

    @ti.kernel
    def _evaluate(self):
        self._activate_blocks()
        dims = ti.Vector(self.dims)
        for j in range(self.active_count[None] * BLOCK3):
            node = self.block_node(self.active_block[j // BLOCK3], j % BLOCK3)
            if (node > 0).all() and (node < dims - 1).all():  # the outer layer stays 0
                acc = self._Sum(p=self.node_position(node[0], node[1], node[2]), s=0.0)
                self.neighbors.for_each_neighbor(j, acc.p, self.cutoff_radius, self._add_blob, acc)
                self.psi[node] = acc.s
