"""Loose octree over axis-aligned boxes with implicit nodes, built by counting sort.

Ulrich, "Loose Octrees", Game Programming Gems 1, 2000, sec. 4.11: an octree over a root cube of side S
whose cells at level l (side h_l = S / 2^l) are loosened to twice their size, so an object whose largest
extent e is <= h_l fits in the loose cell of the level-l cell containing its centre. Each object goes to
the deepest level where it fits (level = floor(log2(S / e)), capped at MAX_LEVEL), but no deeper than
the median object's level (smaller objects share those cells: cells far smaller than most objects would
make every query enumerate many empty cells), so cells match the objects' sizes whatever the mix. Nodes
are implicit: a node (l, cell) is one key of level l's hash table (Teschner et al. 2003 hashing,
2^k >= 2 * objects buckets per level, the tables laid out level after level), filled by a counting sort
of the objects by bucket (Green 2010, as in `collision/neighbors.py`), each bucket sorted by object index
so queries are reproducible.

Query (`for_each_overlap(i, lo, hi, visit, ret)`, `for_each_in_sphere(i, c, r, visit, ret)`): for every
occupied level, the cells whose loose boxes meet the query are those with centre cell c in
[floor(a - 1/2), floor(b + 1/2)] per axis, a and b the query's bounds in level-l cell units (an object of
extent <= h_l reaches half a cell beyond its centre; a slack of SLACK cells absorbs round-off); each
candidate is checked exactly against the object's box. When that range holds more cells than the level
has objects, the level's objects are scanned instead, so a large query costs at most a brute-force pass.
There is no refit: moving objects change cells, and `refit()` / `update()` rebuild (a counting sort, as
cheap as a refit)."""

import taichi as ti

from .. import validate
from ..errors import ParameterError
from ..runtime import data_oriented, serial_loops
from .bounds import aabb_overlap, aabb_point_distance_sq
from .lbvh import float_bytes
from .prefix_sum import PrefixSum

MAX_LEVEL = 16  # 2^16 cells per axis at the finest level; the cell coordinates stay well inside i32
LEVELS = MAX_LEVEL + 1
BLOCK = 1024  # objects per block of the reductions
SLACK = 1e-3  # in cells: covers round-off in the cell coordinates of centres and query bounds


@ti.func
def _hash(c):
    u = ti.cast(c, ti.u32)
    return (u[0] * ti.u32(73856093)) ^ (u[1] * ti.u32(19349663)) ^ (u[2] * ti.u32(83492791))


@data_oriented
class Octree:
    """Loose octree over up to `capacity` boxes: fill `prim_lo`/`prim_hi` (Vector fields (capacity, 3)
    [m], lo <= hi, finite) for k < n, then `build(n)`. `slot_prim[s]` is the object stored in slot s."""

    single_level = False  # TriGrid: every object at one level, the deepest where all fit

    def __init__(self, capacity: int):
        self.capacity = validate.count("capacity", capacity, 1)
        # Per box: 12 floats and 72 bytes of int32 cells, ids and 4 hash buckets (4 capacity + 3 starts).
        validate.capacity(
            "capacity",
            self.capacity,
            bytes_each=12 * float_bytes() + 72,
            limit=(validate.INT32_MAX - 3) // 4,
            unit="boxes",
            why=f"whose 4 capacity + 3 hash buckets keep int32 indices (at most {validate.INT32_MAX})",
        )
        c = self.capacity
        self.prim_lo = ti.Vector.field(3, float, c)
        self.prim_hi = ti.Vector.field(3, float, c)
        self.prim_level = ti.field(ti.i32, c)
        self.prim_cell = ti.Vector.field(3, ti.i32, c)
        self.prim_bucket = ti.field(ti.i32, c)
        self.prim_rank = ti.field(ti.i32, c)
        self.slot_prim = ti.field(ti.i32, c)
        self.slot_cell = ti.Vector.field(3, ti.i32, c)
        self.slot_lo = ti.Vector.field(3, float, c)
        self.slot_hi = ti.Vector.field(3, float, c)
        self.bucket_cap = 4 * c + 2  # each level's table is a power of two < 4 x its objects
        self.bucket_count = ti.field(ti.i32, self.bucket_cap)
        self.bucket_start = ti.field(ti.i32, self.bucket_cap + 1)
        self.level_count = ti.field(ti.i32, LEVELS)
        self.level_table = ti.field(ti.i32, LEVELS + 1)  # first bucket of each level's table
        self.level_size = ti.field(ti.i32, LEVELS)  # buckets in each level's table (a power of two)
        self.level_inv_h = ti.field(float, LEVELS)
        self.root_box = ti.Vector.field(3, float, 2)  # union of all boxes
        self.origin = ti.Vector.field(3, float, ())
        self.count = ti.field(ti.i32, ())
        self.grid_level = ti.field(ti.i32, ())  # deepest level used (grid: the one level)
        self.n = 0
        self.build_count = 0
        self._serial = serial_loops(c)
        self._scan = PrefixSum(self.bucket_cap, self._serial)

    def build(self, n: int) -> None:
        """Index boxes 0 .. n-1 (0 <= n <= capacity)."""
        if isinstance(n, bool) or int(n) != n or not 0 <= n <= self.capacity:
            raise ParameterError(f"n must be an integer in [0, capacity {self.capacity}], got {n!r}")
        self.n = int(n)
        self._build(self.n)
        self.build_count += 1

    def refit(self) -> None:
        """Rebuild (objects change cells as they move)."""
        self.build(self.n)

    def update(self) -> bool:
        """Rebuild; returns True (the same protocol as `BVH.update`)."""
        self.refit()
        return True

    def describe(self) -> str:
        """One line for summaries: the method and the boxes held."""
        return f"octree ({self.n} of {self.capacity} boxes)"

    @ti.kernel
    def _build(self, n: ti.i32):
        blocks = (n + BLOCK - 1) // BLOCK
        for _ in range(1):
            self.count[None] = n
            self.root_box[0] = ti.Vector([ti.math.inf] * 3, float)
            self.root_box[1] = ti.Vector([-ti.math.inf] * 3, float)
            for level in range(LEVELS):
                self.level_count[level] = 0
        # Per-block reductions, then one atomic per block (atomics on one address from every object
        # serialise the threads).
        ti.loop_config(serialize=self._serial)
        for b in range(blocks):
            lo = ti.Vector([ti.math.inf] * 3, float)
            hi = ti.Vector([-ti.math.inf] * 3, float)
            for k in range(b * BLOCK, ti.min(n, (b + 1) * BLOCK)):
                lo = ti.min(lo, self.prim_lo[k])
                hi = ti.max(hi, self.prim_hi[k])
            for a in ti.static(range(3)):
                ti.atomic_min(self.root_box[0][a], lo[a])
                ti.atomic_max(self.root_box[1][a], hi[a])
        for _ in range(1):
            lo = self.root_box[0]
            side = (self.root_box[1] - lo).max()
            side = side * (1.0 + 1e-5) + 1e-30  # a zero-size root still gets cells
            self.origin[None] = lo
            for level in range(LEVELS):
                self.level_inv_h[level] = ti.cast(1 << level, float) / side
        # Each object's own level: the deepest whose cells are as large as its largest extent.
        ti.loop_config(serialize=self._serial)
        for b in range(blocks):
            hist = ti.Vector([0] * LEVELS, ti.i32)
            for k in range(b * BLOCK, ti.min(n, (b + 1) * BLOCK)):
                e = (self.prim_hi[k] - self.prim_lo[k]).max()
                level = 0
                while level < MAX_LEVEL and e * self.level_inv_h[level + 1] <= 1.0:
                    level += 1
                self.prim_level[k] = level
                hist[level] += 1
            for level in ti.static(range(LEVELS)):
                if hist[level] > 0:
                    ti.atomic_add(self.level_count[level], hist[level])
        # The level objects are stored at: octree, their own but no deeper than the median object's
        # (cells far smaller than most objects would make every query enumerate many empty cells);
        # grid, the coarsest level any object needs, for all.
        for _ in range(1):
            total = 0
            cap = MAX_LEVEL
            found = False
            for level in range(LEVELS):
                total += self.level_count[level]
                if not found:
                    if ti.static(self.single_level):
                        found = total > 0
                    else:
                        found = 2 * total >= n
                    if found:
                        cap = level
            self.grid_level[None] = cap
            moved = 0
            for level in range(LEVELS):
                if ti.static(self.single_level):
                    moved += self.level_count[level]
                    self.level_count[level] = 0
                elif level > cap:
                    moved += self.level_count[level]
                    self.level_count[level] = 0
            self.level_count[cap] += moved
        ti.loop_config(serialize=self._serial)
        for k in range(n):
            level = self.prim_level[k]
            if ti.static(self.single_level):
                level = self.grid_level[None]
            else:
                level = ti.min(level, self.grid_level[None])
            self.prim_level[k] = level
            c = 0.5 * (self.prim_lo[k] + self.prim_hi[k])
            self.prim_cell[k] = self._cell_of(c, level)
        for _ in range(1):
            start = 0
            for level in range(LEVELS):
                size = 0
                if self.level_count[level] > 0:
                    size = 1
                    while size < 2 * self.level_count[level]:
                        size *= 2
                self.level_table[level] = start
                self.level_size[level] = size
                start += size
            self.level_table[LEVELS] = start
        buckets = self.level_table[LEVELS]
        ti.loop_config(serialize=self._serial)
        for b in range(buckets):
            self.bucket_count[b] = 0
        ti.loop_config(serialize=self._serial)
        for k in range(n):
            level = self.prim_level[k]
            b = self._bucket(self.prim_cell[k], level)
            self.prim_bucket[k] = b
            self.prim_rank[k] = ti.atomic_add(self.bucket_count[b], 1)
        self._scan.exclusive(self.bucket_count, self.bucket_start, buckets)
        ti.loop_config(serialize=self._serial)
        for k in range(n):
            self.slot_prim[self.bucket_start[self.prim_bucket[k]] + self.prim_rank[k]] = k
        # Atomic ranks depend on thread timing: sort each bucket by object index (buckets are small).
        ti.loop_config(serialize=self._serial)
        for b in range(buckets):
            a = self.bucket_start[b]
            for s in range(a + 1, self.bucket_start[b + 1]):
                v = self.slot_prim[s]
                m = s
                while m > a and self.slot_prim[m - 1] > v:
                    self.slot_prim[m] = self.slot_prim[m - 1]
                    m -= 1
                self.slot_prim[m] = v
        ti.loop_config(serialize=self._serial)
        for s in range(n):
            k = self.slot_prim[s]
            self.slot_cell[s] = self.prim_cell[k]
            self.slot_lo[s] = self.prim_lo[k]
            self.slot_hi[s] = self.prim_hi[k]

    @ti.func
    def _cell_of(self, p, level):
        m = (1 << level) - 1
        u = ti.floor((p - self.origin[None]) * self.level_inv_h[level])
        return ti.cast(ti.max(ti.min(u, ti.cast(m, float)), 0.0), ti.i32)

    @ti.func
    def _bucket(self, cell, level):
        mask = ti.u32(self.level_size[level] - 1)
        return self.level_table[level] + ti.cast(_hash(cell) & mask, ti.i32)

    # ---------------------------------------------------------------------------------------------
    # queries (Taichi scope)

    @ti.func
    def _walk(self, i, lo, hi, q, test: ti.template(), visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for each object whose stored box passes test(q, box_lo, box_hi), among
        the objects whose loose cells meet the box [lo, hi]."""
        if self.count[None] > 0 and aabb_overlap(lo, hi, self.root_box[0], self.root_box[1]):
            for level in range(LEVELS):
                if self.level_count[level] > 0:
                    m = ti.cast((1 << level) - 1, float)
                    o = self.origin[None]
                    inv_h = self.level_inv_h[level]
                    a = ti.max(ti.min(ti.floor((lo - o) * inv_h - 0.5 - SLACK), m), 0.0)
                    b = ti.max(ti.min(ti.floor((hi - o) * inv_h + 0.5 + SLACK), m), 0.0)
                    cells = (b[0] - a[0] + 1.0) * (b[1] - a[1] + 1.0) * (b[2] - a[2] + 1.0)
                    if cells >= self.level_count[level]:
                        s0 = self.bucket_start[self.level_table[level]]
                        s1 = self.bucket_start[self.level_table[level + 1]]
                        for s in range(s0, s1):
                            if test(q, self.slot_lo[s], self.slot_hi[s]):
                                visit(i, self.slot_prim[s], ret)
                    else:
                        c0 = ti.cast(a, ti.i32)
                        c1 = ti.cast(b, ti.i32)
                        for cx in range(c0[0], c1[0] + 1):
                            for cy in range(c0[1], c1[1] + 1):
                                for cz in range(c0[2], c1[2] + 1):
                                    cell = ti.Vector([cx, cy, cz])
                                    bk = self._bucket(cell, level)
                                    for s in range(self.bucket_start[bk], self.bucket_start[bk + 1]):
                                        # other cells hashed here are visited through their own
                                        if (self.slot_cell[s] == cell).all():
                                            if test(q, self.slot_lo[s], self.slot_hi[s]):
                                                visit(i, self.slot_prim[s], ret)

    @ti.func
    def _test_box(self, q, lo, hi):
        q_lo = ti.Vector([q[0, 0], q[0, 1], q[0, 2]])
        q_hi = ti.Vector([q[1, 0], q[1, 1], q[1, 2]])
        return aabb_overlap(lo, hi, q_lo, q_hi)

    @ti.func
    def _test_sphere(self, q, lo, hi):
        return aabb_point_distance_sq(lo, hi, ti.Vector([q[0], q[1], q[2]])) <= q[3]

    @ti.func
    def for_each_overlap(self, i, lo, hi, visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for every object whose box meets the closed box [lo, hi] [m]."""
        lo_ = ti.cast(lo, float)
        hi_ = ti.cast(hi, float)
        self._walk(i, lo_, hi_, ti.Matrix.rows([lo_, hi_]), self._test_box, visit, ret)

    @ti.func
    def for_each_in_sphere(self, i, c, r, visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for every object whose box lies within distance r [m] of c (closed)."""
        c_ = ti.cast(c, float)
        q = ti.Vector([c_[0], c_[1], c_[2], r * r], float)
        self._walk(i, c_ - r, c_ + r, q, self._test_sphere, visit, ret)
