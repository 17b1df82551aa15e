"""Choice of the structure that answers box and ball queries over N boxes: brute force, the uniform loose
grid (`tri_grid.py`), the loose octree (`octree.py`) or the linear BVH (`lbvh.py`), from the crossovers
measured in benchmarks/results/bvh_study.md (as `collision/neighbors.py` chooses its grid from CROSSOVER_N).

All four share one protocol: `prim_lo` / `prim_hi` (Vector fields (capacity, 3) [m]) that the caller
fills, `build(n)`, `refit()`, `update() -> bool`, and from Taichi scope
`for_each_overlap(i, lo, hi, visit, ret)` and `for_each_in_sphere(i, c, r, visit, ret)`, which call
`visit(i, prim, ret)` for every box meeting the query. So a caller can swap them without other changes.
"""

from enum import Enum

import taichi as ti

from .. import validate
from ..capacity import plain
from ..errors import ParameterError
from ..runtime import data_oriented
from .bounds import aabb_overlap, aabb_point_distance_sq
from .lbvh import BVH, float_bytes
from .octree import Octree
from .tri_grid import TriGrid

# Cost model fitted to benchmarks/results/bvh_study.md on this project's 2-core CPU ("cost model"):
# brute force costs queries x boxes x BRUTE_TEST_S; the BVH a build, BVH_BUILD_FIXED_S +
# boxes x BVH_BUILD_PER_BOX_S, plus queries x BVH_QUERY_S (for queries that meet ~10 boxes).
BRUTE_TEST_S = 9.6e-10
BVH_BUILD_FIXED_S = 4.8e-5
BVH_BUILD_PER_BOX_S = 6.2e-8
BVH_QUERY_S = 2.7e-7
# Where the two meet with one query per box (self-contact): brute force below it. Measured crossovers,
# brute force against BVH build (or refit) + N queries: 586 (425) boxes on a cloth-like sheet, 397 (254)
# on a triangle soup; an earlier run under a different load fitted 640.
CROSSOVER_N = 460


class BoxQueryMethod(Enum):
    """BRUTE: every box per query; GRID: uniform loose grid; OCTREE: loose octree; BVH: linear BVH."""

    BRUTE = "brute"
    GRID = "grid"
    OCTREE = "octree"
    BVH = "bvh"


@data_oriented
class BruteBoxes:
    """Every box is a candidate of every query: the reference, and the fastest for few boxes."""

    def __init__(self, capacity: int, *, make=plain):
        self.capacity = validate.count("capacity", capacity, 1)
        validate.capacity("capacity", self.capacity, bytes_each=6 * float_bytes(), unit="boxes")
        self.prim_lo = make(self, "brute_prim_lo", float, self.capacity, (3,))
        self.prim_hi = make(self, "brute_prim_hi", float, self.capacity, (3,))
        self.count = make(self, "brute_count", ti.i32, ())
        self.n = 0
        self.build_count = 0

    def build(self, n: int) -> None:
        """Use boxes 0 .. n-1 (0 <= n <= capacity)."""
        if isinstance(n, bool) or int(n) != n or not 0 <= n <= self.capacity:
            raise ParameterError(f"n must be an integer in [0, capacity {self.capacity}], got {n!r}")
        self.n = int(n)
        self.count[None] = self.n
        self.build_count += 1

    def refit(self) -> None:
        """Nothing to do: queries read prim_lo/prim_hi directly."""

    def update(self) -> bool:
        """Nothing to refit for brute force: returns False (no rebuild)."""
        return False

    def describe(self) -> str:
        """One line for summaries: the method and the boxes held."""
        return f"brute ({self.n} of {self.capacity} boxes)"

    @ti.func
    def for_each_overlap(self, i, lo, hi, visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for every box meeting the closed box [lo, hi] [m]."""
        for k in range(self.count[None]):
            if aabb_overlap(self.prim_lo[k], self.prim_hi[k], lo, hi):
                visit(i, k, ret)

    @ti.func
    def for_each_in_sphere(self, i, c, r, visit: ti.template(), ret: ti.template()):
        """visit(i, prim, ret) for every box within distance r [m] of c."""
        for k in range(self.count[None]):
            if aabb_point_distance_sq(self.prim_lo[k], self.prim_hi[k], c) <= r * r:
                visit(i, k, ret)


def choose_box_query(count: int, queries: int | None = None) -> BoxQueryMethod:
    """The method the cost model measures fastest for `count` boxes and `queries` queries per build
    (default: one per box, as in self-contact): brute force when queries x count x BRUTE_TEST_S is
    below the BVH's build plus queries, else the BVH. The grid and the octree are not chosen: they beat
    the BVH only narrowly, on meshes of uniform triangles between ~10^3 and 3 x 10^3 boxes, and lose by
    up to 15x on mixed sizes (benchmarks/results/bvh.md)."""
    n = validate.count("count", count, 0)
    q = n if queries is None else validate.count("queries", queries, 0)
    brute = q * n * BRUTE_TEST_S
    bvh = BVH_BUILD_FIXED_S + n * BVH_BUILD_PER_BOX_S + q * BVH_QUERY_S
    return BoxQueryMethod.BRUTE if brute < bvh else BoxQueryMethod.BVH


def make_box_query(capacity: int, *, method: str = "auto", queries: int | None = None, make=plain):
    """A structure for box / ball queries over up to `capacity` boxes (the protocol in the module
    docstring). method: "brute", "grid", "octree", "bvh", or "auto" (`choose_box_query(capacity,
    queries)`). make(owner, role, dtype, shape, dims): the allocator of its fields (a model's pool under
    capacity buckets); the grid and the octree always make their own."""
    validate.choice("method", method, [m.value for m in BoxQueryMethod] + ["auto"])
    kind = choose_box_query(capacity, queries) if method == "auto" else BoxQueryMethod(method)
    cls = {
        BoxQueryMethod.BRUTE: BruteBoxes,
        BoxQueryMethod.GRID: TriGrid,
        BoxQueryMethod.OCTREE: Octree,
        BoxQueryMethod.BVH: BVH,
    }[kind]
    if kind in (BoxQueryMethod.BRUTE, BoxQueryMethod.BVH):
        return cls(capacity, make=make)
    return cls(capacity)
