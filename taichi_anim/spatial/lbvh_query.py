"""Queries of the linear BVH (lbvh.py) from Taichi scope, a mixin of BVH: depth-first walks of its node
records (Karras 2012 trees), pruned by a score per box.

Queries from Taichi scope (`visit(i, prim, ret)` gets the original primitive index; `i` is the caller's
own index passed through, `ret` its accumulator, passed by reference): `for_each_overlap(i, lo, hi, ...)`
visits every primitive whose box meets the closed box [lo, hi]; `for_each_in_sphere(i, c, r, ...)` every
primitive whose box lies within distance r of c; `for_each_ray(i, o, d, t_max, ...)` every primitive
whose box the segment o + t d, t in [0, t_max], touches; `traverse(i, q, score, visit, ret)` is the
general walk the others use, and `traverse_nearest(i, q, score, bound, visit, ret)` the nearest-first walk
of closest-point and nearest-hit searches, which tightens its bound as it goes.

Depth bound: see lbvh.py; a depth-first traversal that pushes at most one pending sibling per level never
needs more than STACK_SIZE = 64 stack entries.
"""

import taichi as ti

from .bounds import INV_DIR_PARALLEL, aabb_overlap, aabb_point_distance_sq, aabb_ray

STACK_SIZE = 64


@ti.func
def ray_inv_dir(d):
    """1 / d per component for `bounds.aabb_ray`, with a zero component mapped past INV_DIR_PARALLEL
    (so no division by zero, whatever fast-math does with infinities)."""
    inv = ti.Vector([0.0, 0.0, 0.0], float)
    for a in ti.static(range(3)):
        inv[a] = 4.0 * INV_DIR_PARALLEL
        if ti.abs(d[a]) * (4.0 * INV_DIR_PARALLEL) > 1.0:
            inv[a] = 1.0 / d[a]
    return inv


class BVHQueries:
    """Mixin of BVH: walks its node records (node_box, node_child, root, leaf_base, prim_id)."""

    @ti.func
    def traverse(self, i, q, score: ti.template(), visit: ti.template(), ret: ti.template()):
        """Depth-first walk: `score(q, lo, hi, ret)` rates a node's box for query data q (any Taichi
        value): < 0 skips the subtree, otherwise the child with the lower score is walked first.
        `visit(i, prim, ret)` is called for each leaf whose box scored >= 0. For filters whose score
        does not change as the walk goes (overlap, in-sphere, rays up to a fixed t)."""
        root = self.root[None]
        s_root = -1.0
        if root >= 0:
            s_root = score(q, self.root_box[0], self.root_box[1], ret)
        if s_root >= 0.0 and root >= self.leaf_base:
            visit(i, self.prim_id[root - self.leaf_base], ret)
        elif s_root >= 0.0:
            stack = ti.Vector([0] * STACK_SIZE, ti.i32)
            stack[0] = root
            top = 1
            while top > 0:
                top -= 1
                node = stack[top]
                near, far, s_near, s_far = self._children(node, q, score, ret)
                # leaves are visited at once, the nearer first; internal nodes are pushed, the nearer
                # last (so it is walked next)
                if s_near >= 0.0 and near >= self.leaf_base:
                    visit(i, self.prim_id[near - self.leaf_base], ret)
                if s_far >= 0.0:
                    if far >= self.leaf_base:
                        visit(i, self.prim_id[far - self.leaf_base], ret)
                    else:
                        stack[top] = far
                        top += 1
                if s_near >= 0.0 and near < self.leaf_base:
                    stack[top] = near
                    top += 1

    @ti.func
    def _children(self, node, q, score: ti.template(), ret: ti.template()):
        """Internal node `node`'s children scored, the nearer first: (near, far, s_near, s_far)."""
        ab = self.node_child[node]
        lo_a, hi_a = self._child_box(node, 0)
        lo_b, hi_b = self._child_box(node, 1)
        sa = score(q, lo_a, hi_a, ret)
        sb = score(q, lo_b, hi_b, ret)
        near, far = ab[0], ab[1]
        s_near, s_far = sa, sb
        if sb >= 0.0 and (sa < 0.0 or sb < sa):
            near, far = ab[1], ab[0]
            s_near, s_far = sb, sa
        return near, far, s_near, s_far

    # `traverse_nearest` calls `visit` at one place in the compiled walk, where `traverse` calls it at
    # three: a closest-point visit is a point-triangle distance, and every kernel with a mesh collider
    # compiled three (pour's liquid step 1.04 -> 0.80 s of its cold start). Each turn of the loop first
    # handles the pair of children the last node expanded into (the root alone at the start), as a
    # run-time loop over one visit: the nearer child, visited if a leaf, then the farther (its score
    # checked against the bound the nearer visit left), visited or pushed, then the nearer pushed if
    # internal; then it pops and expands the next node. The same visits and pushes in the same order as
    # three visits make. `traverse` keeps its three: the self-contact queries' frame was 8 % slower
    # with one (the tablecloth, 58-59 against 54-55 ms).
    @ti.func
    def traverse_nearest(
        self, i, q, score: ti.template(), bound: ti.template(), visit: ti.template(), ret: ti.template()
    ):
        """`traverse` for searches that tighten a bound in ret as they go (closest point, nearest hit):
        `bound(ret)` is the largest score still of interest; a subtree pushed earlier is skipped when
        its score has come to exceed it, and of two children the farther is dropped if visiting the
        nearer one has excluded it."""
        root = self.root[None]
        stack = ti.Vector([0] * STACK_SIZE, ti.i32)
        stack_score = ti.Vector([0.0] * STACK_SIZE, float)
        top = 0
        node = -1  # the node expanded last (-1: none, the root is the pair's nearer child)
        near, far = root, -1
        s_near, s_far = ti.cast(-1.0, float), ti.cast(-1.0, float)
        if root >= 0:
            s_near = score(q, self.root_box[0], self.root_box[1], ret)
        while True:
            for k in range(2):
                c, sc = near, s_near
                if k == 1:
                    c, sc = far, s_far
                    if sc > bound(ret):
                        sc = -1.0
                if sc >= 0.0:
                    if c >= self.leaf_base:
                        visit(i, self.prim_id[c - self.leaf_base], ret)
                    elif k == 1:
                        stack[top] = c
                        stack_score[top] = sc
                        top += 1
            if s_near >= 0.0 and near < self.leaf_base:
                stack[top] = near
                stack_score[top] = s_near if node >= 0 else 0.0  # the root is walked whatever the bound
                top += 1
            if top == 0:
                break
            top -= 1
            node = stack[top]
            near, far = -1, -1
            s_near, s_far = -1.0, -1.0
            if stack_score[top] <= bound(ret):
                near, far, s_near, s_far = self._children(node, q, score, ret)

    @ti.func
    def _score_box(self, q, lo, hi, ret: ti.template()):
        out = -1.0
        q_lo = ti.Vector([q[0, 0], q[0, 1], q[0, 2]])
        q_hi = ti.Vector([q[1, 0], q[1, 1], q[1, 2]])
        if aabb_overlap(lo, hi, q_lo, q_hi):
            out = 0.0
        return out

    @ti.func
    def _score_sphere(self, q, lo, hi, ret: ti.template()):
        d2 = aabb_point_distance_sq(lo, hi, ti.Vector([q[0], q[1], q[2]]))
        out = -1.0
        if d2 <= q[3]:
            out = d2
        return out

    @ti.func
    def _score_ray(self, q, lo, hi, ret: ti.template()):
        o = ti.Vector([q[0, 0], q[0, 1], q[0, 2]])
        inv_d = ti.Vector([q[1, 0], q[1, 1], q[1, 2]])
        hit, t = aabb_ray(lo, hi, o, inv_d, q[2, 0])
        out = -1.0
        if hit:
            out = t
        return out

    @ti.func
    def for_each_overlap(self, i, lo, hi, visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for every primitive whose box meets the closed box [lo, hi] [m]."""
        q = ti.Matrix.rows([ti.cast(lo, float), ti.cast(hi, float)])
        self.traverse(i, q, self._score_box, visit, ret)

    @ti.func
    def for_each_in_sphere(self, i, c, r, visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for every primitive whose box lies within distance r [m] of c (closed)."""
        q = ti.Vector([c[0], c[1], c[2], r * r], float)
        self.traverse(i, q, self._score_sphere, visit, ret)

    @ti.func
    def for_each_ray(self, i, o, d, t_max, visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for every primitive whose box the segment o + t d, t in [0, t_max],
        touches (slab test, `bounds.aabb_ray`); nearer boxes first."""
        q = ti.Matrix.rows([ti.cast(o, float), ray_inv_dir(d), ti.Vector([t_max, 0.0, 0.0], float)])
        self.traverse(i, q, self._score_ray, visit, ret)
