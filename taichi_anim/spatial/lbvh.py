"""Linear bounding volume hierarchy over axis-aligned boxes, built on the device from sorted Morton codes.

Construction: Karras, "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d Trees",
HPG 2012. Each box centre gets a 30-bit Morton code (10 bits per axis, centres normalised by the
largest extent of their box, so cells stay cubes); codes are sorted (a stable least-significant-digit
radix sort, 4 passes of 8 bits, blocks of keys histogrammed and scattered in parallel); internal node i
of the n - 1 is then built on its own (sec. 4, Fig. 4): its direction d = sign(delta(i, i+1) -
delta(i, i-1)), the far end of its key range by an exponential then binary search on delta >
delta(i, i-d), and its split by a binary search for the longest common prefix, where delta(i, j) is the
length of the common prefix of keys i and j. Equal keys are told apart by their positions, delta = 32 +
clz(i xor j) (the "index tie-break" of sec. 4), so duplicated centres still give a valid binary tree.
Boxes are computed bottom up. On a GPU each leaf climbs towards the root with atomic visit counters
(Karras sec. 5, Apetrei 2014): the second child to arrive computes its parent. On the CPU one atomic per
node cost more than the whole refit, so the build lists the internal nodes in depth-first pre-order once
and a refit sweeps that list backwards (children before parents) on one thread, after the leaves' boxes
are copied in parallel. Each internal node stores both children's boxes, so a traversal step reads
one record.

Depth bound: the prefix length delta strictly grows from a node to its internal children and lies in
[2, 63] (keys use 30 of 32 bits; positions differ within 31 bits), so no root-to-leaf path has more than
62 internal nodes and a depth-first traversal that pushes at most one pending sibling per level never
needs more than STACK_SIZE = 64 stack entries.

Refit keeps the topology and recomputes boxes from `prim_lo`/`prim_hi`, for deforming meshes. Tree
quality: the surface-area cost C = sum over internal nodes of A(node) / A(root) (MacDonald & Booth,
"Heuristics for ray tracing using space subdivision", 1990: the expected number of internal nodes a
random ray through the root box visits). Refit lets it grow as primitives move apart from their Morton
neighbours. `update()` refits, and rebuilds when C exceeds `rebuild_ratio` times its value right after
the last build (benchmarks/results/bvh_study.md records the cost of refit against rebuild and query
speed as a mesh deforms, which set the default).

Queries from Taichi scope: lbvh_query.py.
"""

import taichi as ti
from taichi.lang import impl

from .. import validate
from ..capacity import plain
from ..errors import ParameterError
from ..runtime import backend_name, compile_with, data_oriented, float_dtype, serial_loops
from .bounds import aabb_surface_area
from .lbvh_query import STACK_SIZE, BVHQueries
from .prefix_sum import PrefixSum

MORTON_BITS_PER_AXIS = 10
RADIX_BITS = 8
RADIX = 1 << RADIX_BITS
RADIX_PASSES = 4  # 4 x 8 bits >= the 30-bit codes; an even count leaves the result in the first buffer
SORT_BLOCK = 1024  # keys histogrammed/scattered serially per block; blocks run in parallel
# Default of update(): rebuild once the refit tree's surface-area cost exceeds this times its cost
# right after the last build. With one box query per primitive and step (self-contact), a rebuild paid
# for itself from a cost ratio of ~1.5 on triangles moving apart at random (query slowdown ~ the ratio)
# and of ~1.8 on a crumpling sheet (slowdown 1.1 there, 1.3 at ratio 3)
# (benchmarks/results/bvh_study.md, "refit or rebuild", 10^5 triangles). Fewer queries per step favour a
# higher ratio.
REBUILD_RATIO = 1.5


@ti.func
def _expand_bits(v):
    """Spread the low 10 bits of v (u32) so that two zero bits follow each one."""
    v = (v * ti.u32(0x00010001)) & ti.u32(0xFF0000FF)
    v = (v * ti.u32(0x00000101)) & ti.u32(0x0F00F00F)
    v = (v * ti.u32(0x00000011)) & ti.u32(0xC30C30C3)
    v = (v * ti.u32(0x00000005)) & ti.u32(0x49249249)
    return v


@ti.func
def morton3(u):
    """30-bit Morton code (i32) of a point u in [0, 1]^3 (clamped): x bits highest."""
    scale = float(1 << MORTON_BITS_PER_AXIS)
    q = ti.cast(ti.min(ti.max(u * scale, 0.0), scale - 1.0), ti.u32)
    code = (_expand_bits(q[0]) << 2) | (_expand_bits(q[1]) << 1) | _expand_bits(q[2])
    return ti.cast(code, ti.i32)


def float_bytes() -> int:
    """Bytes of one float in the fields (4 for f32, 8 for f64), for capacity checks."""
    return 8 if float_dtype() == ti.f64 else 4


@data_oriented
class BVH(BVHQueries):
    """Linear BVH over up to `capacity` boxes (Karras 2012).

    The caller writes primitive boxes into `prim_lo[k]`, `prim_hi[k]` (Vector fields (capacity, 3) [m],
    lo <= hi, finite) for k < n in its own kernel, then calls `build(n)`; after moving them, `refit()`
    or `update()`. Node layout: internal nodes 0 .. n-2 (root 0), leaves at `leaf_base` + k for sorted
    position k, whose primitive is `prim_id[k]`; `node_box[t]` holds internal node t's two child boxes.

    rebuild_ratio: `update()` rebuilds when the refit tree's surface-area cost exceeds this many times
    its cost after the last build (> 1).
    """

    def __init__(self, capacity: int, *, rebuild_ratio: float = REBUILD_RATIO, make=plain):
        """make(owner, role, dtype, shape, dims): the allocator (a model's pool under capacity buckets,
        capacity.py; default: new fields)."""
        self.capacity = validate.count("capacity", capacity, 1)
        # Per box: 19 floats (boxes, node records, costs) and 46 bytes of int32 ids, codes and links.
        validate.capacity(
            "capacity",
            self.capacity,
            bytes_each=19 * float_bytes() + 46,
            limit=(validate.INT32_MAX + 1) // 2,
            unit="boxes",
            why=f"for which the BVH's 2 capacity - 1 nodes keep int32 indices (at most {validate.INT32_MAX})",
        )
        self.rebuild_ratio = validate.positive("rebuild_ratio", rebuild_ratio)
        if self.rebuild_ratio <= 1.0:
            raise ParameterError(f"rebuild_ratio must be > 1, got {rebuild_ratio!r}")
        c = self.capacity
        self.leaf_base = c - 1
        inner = max(c - 1, 1)  # Taichi refuses zero-sized fields (capacity 1 has no internal node)
        self.prim_lo = make(self, "bvh_prim_lo", float, c, (3,))
        self.prim_hi = make(self, "bvh_prim_hi", float, c, (3,))
        # Internal node t holds its two children's boxes (rows lo_a, hi_a, lo_b, hi_b): expanding a node
        # reads one record. node_parent[x] = 2 * parent + side (side 0: child a, 1: child b), -1 root.
        self.node_box = make(self, "bvh_node_box", float, inner, (4, 3))
        self.node_child = make(self, "bvh_node_child", ti.i32, inner, (2,))
        self.node_parent = make(self, "bvh_node_parent", ti.i32, 2 * c - 1)
        self.root_box = make(self, "bvh_root_box", float, 2, (3,))
        self.node_cost = make(self, "bvh_node_cost", float, inner)  # sum of internal areas in the subtree
        self.node_visits = make(self, "bvh_node_visits", ti.i32, inner)
        self.prim_id = make(self, "bvh_prim_id", ti.i32, c)
        self.code = make(self, "bvh_code", ti.i32, c)
        self._code_tmp = make(self, "bvh_code_tmp", ti.i32, c)
        self._id_tmp = make(self, "bvh_id_tmp", ti.i32, c)
        self._centre_box = make(self, "bvh_centre_box", float, 2, (3,))
        self._blocks_max = (c + SORT_BLOCK - 1) // SORT_BLOCK
        self._hist = make(self, "bvh_hist", ti.i32, RADIX * self._blocks_max)
        self._hist_start = make(self, "bvh_hist_start", ti.i32, RADIX * self._blocks_max + 1)
        self._serial = serial_loops(c)
        self._scan = PrefixSum(RADIX * self._blocks_max, self._serial, make)
        self.count = make(self, "bvh_count", ti.i32, ())
        self.root = make(self, "bvh_root", ti.i32, ())
        self.quality = make(self, "bvh_quality", float, ())  # surface-area cost of the current boxes
        self.built_quality = make(self, "bvh_built_quality", float, ())  # ... right after the last build
        self.n = 0
        self.build_count = 0
        self._cuda = impl.current_cfg().arch == ti.cuda
        # Refit: a serial sweep in reverse pre-order on the CPU, the parallel climb on GPUs.
        self._climb = backend_name() != "cpu"
        self._one_task = self._serial and not self._climb  # the build as one serial task (`_build`)
        self.refit_order = make(self, "bvh_refit_order", ti.i32, inner)

    # ---------------------------------------------------------------------------------------------
    # Python scope

    def build(self, n: int) -> None:
        """Build the tree over boxes 0 .. n-1 (0 <= n <= capacity; n = 0 gives an empty tree)."""
        if isinstance(n, bool) or int(n) != n or not 0 <= n <= self.capacity:
            raise ParameterError(f"n must be an integer in [0, capacity {self.capacity}], got {n!r}")
        self.n = int(n)
        self._build(self.n)
        self.build_count += 1

    def refit(self) -> None:
        """Recompute every node's box (and the tree's cost) from prim_lo/prim_hi; topology unchanged."""
        self._refit_kernel(self.n)

    def update(self) -> bool:
        """Refit; rebuild if the surface-area cost grew past rebuild_ratio times its value at the last
        build. Returns whether it rebuilt (one device read)."""
        self.refit()
        if self.quality[None] > self.rebuild_ratio * self.built_quality[None]:
            self.build(self.n)
            return True
        return False

    def cost_ratio(self) -> float:
        """Current surface-area cost over its value right after the last build (1 after a build)."""
        b = self.built_quality[None]
        q = self.quality[None]
        return q / b if b > 0.0 else (1.0 if q <= 0.0 else float("inf"))

    def describe(self) -> str:
        """One line for summaries: the method and the boxes held."""
        return f"lbvh ({self.n} of {self.capacity} boxes)"

    # ---------------------------------------------------------------------------------------------
    # build

    # A large serial build: Taichi's CFG passes cost compile time only (see SelfContact._query). A small
    # tree on the CPU (every loop serial anyway) is built in one serial task, its radix passes a loop over
    # one copy of the pass instead of RADIX_PASSES unrolled ones (the same sort: each pass's output is
    # copied back), which halved the front end's and the compiler's work on it.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _build(self, n: ti.i32):
        if ti.static(self._one_task):
            ti.loop_config(serialize=True)
            for _ in range(1):
                self._build_all(n)
        else:
            self._build_all(n)

    @ti.func
    def _build_all(self, n):
        self._morton(n)
        if ti.static(self._one_task):
            for s in range(RADIX_PASSES):
                self._radix_pass(self.code, self.prim_id, self._code_tmp, self._id_tmp, s * RADIX_BITS, n)
                for k in range(n):
                    self.code[k] = self._code_tmp[k]
                    self.prim_id[k] = self._id_tmp[k]
        else:
            for s in ti.static(range(RADIX_PASSES)):
                if ti.static(s % 2 == 0):
                    self._radix_pass(self.code, self.prim_id, self._code_tmp, self._id_tmp, s * RADIX_BITS, n)
                else:
                    self._radix_pass(self._code_tmp, self._id_tmp, self.code, self.prim_id, s * RADIX_BITS, n)
        self._hierarchy(n)
        if ti.static(not self._climb):
            self._post_order(n)
        self._refit(n)
        for _ in range(1):
            self.built_quality[None] = self.quality[None]

    @ti.func
    def _post_order(self, n):
        """Internal nodes in depth-first pre-order (serial, O(n)): read backwards, every node comes
        after all of its descendants, the order of the CPU refit."""
        for _ in range(1):
            if n > 1:
                stack = ti.Vector([0] * STACK_SIZE, ti.i32)
                stack[0] = 0
                top = 1
                count = 0
                while top > 0:
                    top -= 1
                    node = stack[top]
                    self.refit_order[count] = node
                    count += 1
                    ab = self.node_child[node]
                    for side in ti.static(range(2)):
                        if ab[side] < self.leaf_base:
                            stack[top] = ab[side]
                            top += 1

    @ti.func
    def _morton(self, n):
        for _ in range(1):
            self.count[None] = n
            self._centre_box[0] = ti.Vector([ti.math.inf] * 3, float)
            self._centre_box[1] = ti.Vector([-ti.math.inf] * 3, float)
        # Box of the centres: min/max per block of SORT_BLOCK, then one atomic per block (atomics on
        # one address from every element serialise the threads; min/max are order-independent).
        ti.loop_config(serialize=self._serial)
        for b in range((n + SORT_BLOCK - 1) // SORT_BLOCK):
            lo = ti.Vector([ti.math.inf] * 3, float)
            hi = ti.Vector([-ti.math.inf] * 3, float)
            for k in range(b * SORT_BLOCK, ti.min(n, (b + 1) * SORT_BLOCK)):
                c = 0.5 * (self.prim_lo[k] + self.prim_hi[k])
                lo = ti.min(lo, c)
                hi = ti.max(hi, c)
            for a in ti.static(range(3)):
                ti.atomic_min(self._centre_box[0][a], lo[a])
                ti.atomic_max(self._centre_box[1][a], hi[a])
        ti.loop_config(serialize=self._serial)
        for k in range(n):
            # One scale for all axes (the largest extent): Morton cells stay cubes, so a flat or thin
            # mesh does not spend a third of the code's bits on its thin axis.
            lo = self._centre_box[0]
            ext = (self._centre_box[1] - lo).max()
            inv = 0.0
            if ext > 0.0:
                inv = 1.0 / ext
            c = 0.5 * (self.prim_lo[k] + self.prim_hi[k])
            self.code[k] = morton3((c - lo) * inv)
            self.prim_id[k] = k

    @ti.func
    def _radix_pass(
        self, key: ti.template(), val: ti.template(), key_out: ti.template(), val_out: ti.template(), shift, n
    ):
        """One stable counting-sort pass on digit (key >> shift) & 255: per block histograms laid out
        digit-major (digit * blocks + block), an exclusive scan of them gives each block's first slot
        per digit, and each block scatters its keys in order (stable)."""
        blocks = (n + SORT_BLOCK - 1) // SORT_BLOCK
        ti.loop_config(serialize=self._serial)
        for t in range(RADIX * blocks):
            self._hist[t] = 0
        ti.loop_config(serialize=self._serial)
        for b in range(blocks):
            for k in range(b * SORT_BLOCK, ti.min(n, (b + 1) * SORT_BLOCK)):
                self._hist[((key[k] >> shift) & (RADIX - 1)) * blocks + b] += 1
        self._scan.exclusive(self._hist, self._hist_start, RADIX * blocks)
        ti.loop_config(serialize=self._serial)
        for b in range(blocks):
            for k in range(b * SORT_BLOCK, ti.min(n, (b + 1) * SORT_BLOCK)):
                slot = ((key[k] >> shift) & (RADIX - 1)) * blocks + b
                pos = self._hist_start[slot]
                self._hist_start[slot] = pos + 1
                key_out[pos] = key[k]
                val_out[pos] = val[k]

    @ti.func
    def _delta(self, i, j, n):
        """Common-prefix length of sorted keys i and j (positions break ties), -1 outside [0, n)."""
        out = -1
        if 0 <= j < n:
            ki = self.code[i]
            kj = self.code[j]
            if ki == kj:
                out = 32 + ti.math.clz(i ^ j)
            else:
                out = ti.math.clz(ki ^ kj)
        return out

    @ti.func
    def _hierarchy(self, n):
        """Karras 2012, Fig. 4: children of each internal node, independently."""
        for _ in range(1):
            self.root[None] = -1
            if n == 1:
                self.root[None] = self.leaf_base
                self.node_parent[self.leaf_base] = -1
            elif n > 1:
                self.root[None] = 0
                self.node_parent[0] = -1
        ti.loop_config(serialize=self._serial)
        for i in range(n - 1):
            d = 1
            if self._delta(i, i + 1, n) < self._delta(i, i - 1, n):
                d = -1
            d_min = self._delta(i, i - d, n)
            l_max = 2
            while self._delta(i, i + l_max * d, n) > d_min:
                l_max *= 2
            ell = 0
            t = l_max // 2
            while t >= 1:
                if self._delta(i, i + (ell + t) * d, n) > d_min:
                    ell += t
                t //= 2
            j = i + ell * d
            d_node = self._delta(i, j, n)
            s = 0
            div = 2
            t = (ell + div - 1) // div
            while t >= 1:
                if self._delta(i, i + (s + t) * d, n) > d_node:
                    s += t
                if t == 1:
                    t = 0
                else:
                    div *= 2
                    t = (ell + div - 1) // div
            gamma = i + s * d + ti.min(d, 0)
            left = gamma
            if ti.min(i, j) == gamma:
                left = self.leaf_base + gamma
            right = gamma + 1
            if ti.max(i, j) == gamma + 1:
                right = self.leaf_base + gamma + 1
            self.node_child[i] = ti.Vector([left, right])
            self.node_parent[left] = 2 * i
            self.node_parent[right] = 2 * i + 1

    # ---------------------------------------------------------------------------------------------
    # refit

    @ti.kernel
    def _refit_kernel(self, n: ti.i32):
        self._refit(n)

    @ti.func
    def _child_cost(self, c):
        out = 0.0
        if c < self.leaf_base:
            out = self.node_cost[c]
        return out

    @ti.func
    def _store_box(self, node, lo, hi):
        """Write a node's box into its parent's record (or the root box)."""
        code = self.node_parent[node]
        if code < 0:
            self.root_box[0] = lo
            self.root_box[1] = hi
        else:
            row = 2 * (code & 1)
            for a in ti.static(range(3)):
                self.node_box[code >> 1][row, a] = lo[a]
                self.node_box[code >> 1][row + 1, a] = hi[a]

    @ti.func
    def _child_box(self, node, side):
        m = self.node_box[node]
        r = 2 * side
        return ti.Vector([m[r, 0], m[r, 1], m[r, 2]]), ti.Vector([m[r + 1, 0], m[r + 1, 1], m[r + 1, 2]])

    @ti.func
    def _refit(self, n):
        """Bottom-up boxes: leaves in parallel, then internal nodes in reverse pre-order (CPU), or with
        visit counters (GPU)."""
        if ti.static(self._climb):
            self._refit_climb(n)
        else:
            self._refit_sweep(n)
        for _ in range(1):
            q = 0.0
            if n > 1:
                area = aabb_surface_area(self.root_box[0], self.root_box[1])
                if area > 0.0:
                    q = self.node_cost[0] / area
            self.quality[None] = q

    @ti.func
    def _union(self, node):
        """Box of internal node `node` from its children's boxes, written into its parent's record,
        and its subtree cost."""
        lo_a, hi_a = self._child_box(node, 0)
        lo_b, hi_b = self._child_box(node, 1)
        lo = ti.min(lo_a, lo_b)
        hi = ti.max(hi_a, hi_b)
        self._store_box(node, lo, hi)
        ab = self.node_child[node]
        self.node_cost[node] = aabb_surface_area(lo, hi) + self._child_cost(ab[0]) + self._child_cost(ab[1])

    @ti.func
    def _refit_sweep(self, n):
        """CPU: no atomics (they dominated the climb: one per node); a serial sweep over the internal
        nodes reads records that the previous steps just wrote, so it stays in cache."""
        ti.loop_config(serialize=self._serial)
        for k in range(n):
            p = self.prim_id[k]
            self._store_box(self.leaf_base + k, self.prim_lo[p], self.prim_hi[p])
        ti.loop_config(serialize=True)
        for t in range(n - 1):
            self._union(self.refit_order[n - 2 - t])

    @ti.func
    def _refit_climb(self, n):
        """GPU: each leaf climbs; the second child to reach a parent computes it (Apetrei 2014)."""
        ti.loop_config(serialize=self._serial)
        for t in range(n - 1):
            self.node_visits[t] = 0
        ti.loop_config(serialize=self._serial)
        for k in range(n):
            node = self.leaf_base + k
            p = self.prim_id[k]
            self._store_box(node, self.prim_lo[p], self.prim_hi[p])
            climbing = True
            while climbing:
                code = self.node_parent[node]
                if code < 0:
                    climbing = False
                else:
                    parent = code >> 1
                    if ti.static(self._cuda):
                        ti.simt.grid.memfence()  # publish this child's box before the counter
                    if ti.atomic_add(self.node_visits[parent], 1) == 0:
                        climbing = False  # the sibling is not done yet: it will compute the parent
                    else:
                        self._union(parent)
                        node = parent
