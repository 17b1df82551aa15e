"""Neighbour search: a uniform grid built by counting sort, its hashed variant for unbounded domains, and
the brute-force O(N^2) reference. One query for all of them: visit the particles near a point.

Counting sort as in Green, "Particle Simulation using CUDA" (NVIDIA, 2010), sec. 3: cell index per
particle, counts per cell, a prefix sum, then the particles' indices (and their positions) stored cell by
cell, so a neighbour query reads contiguous memory. There is no per-cell capacity, so no neighbour is ever
dropped. Spatial hash of the cell coordinates: Teschner et al., "Optimized Spatial Hashing for Collision
Detection of Deformable Objects", VMV 2003, sec. 4.

Query from Taichi scope: `for_each_neighbor(i, p, radius, visit, ret)` calls `visit(i, k, ret)` for every
slot k whose build-time position sorted_x[k] lies within `radius` of p (radius <= the structure's
`radius`); `for_each_candidate` visits every particle of the 3^3 cells around p, a superset of those
within `radius` at build time, for callers that test distances themselves (the sphere sweeps, whose
positions move a little between the build and their last sweep: pairs that only come within reach
during those moves are found at the next build). `i` is passed through to `visit` (the
caller's own index); `ret` is the caller's accumulator, passed by reference. On a bounded grid of cells of
half the radius, `for_each_near` scans 5 x 5 columns of 5 cells (fewer candidates), and
`for_each_in_columns` is that scan without its distance test, for a caller whose test is branch-free.
"""

from enum import Enum

import numpy as np
import taichi as ti

from .. import capacity as capacity_module
from .. import validate
from ..errors import ParameterError
from ..runtime import data_oriented, serial_loops
from ..spatial.prefix_sum import PrefixSum

# Below these many particles brute force (build + one query pass) beats the bounded grid / the hashed
# grid on this project's 2-core CPU (benchmarks/neighbors.py; the study: results/neighbors_study.md).
CROSSOVER_N = 120
CROSSOVER_N_HASHED = 1100
# A bounded grid keeps at most this many cells per particle (bigger cells beyond it): the counting
# sort's scan and clear passes are O(cells).
MAX_CELLS_PER_PARTICLE = 32


class NeighborMethod(Enum):
    """BRUTE: every pair (O(N^2)); GRID: bounded uniform grid; HASH_GRID: hashed grid, unbounded."""

    BRUTE = "brute"
    GRID = "grid"
    HASH_GRID = "hash_grid"


@data_oriented
class _NeighborSearch:
    """Common part: sorted_id[k] (slot -> particle), sorted_x[k] (build-time positions), size[None]."""

    method = NeighborMethod.BRUTE

    def __init__(self, capacity: int, radius: float, make=None):
        self.capacity = validate.count("capacity", capacity, 1)
        self.radius = validate.positive("radius", radius)
        # make(owner, role, dtype, shape, dims): a model's pool under capacity buckets, else new fields.
        self._make = make or capacity_module.plain
        self.sorted_id = self._make(self, "neighbor_sorted_id", ti.i32, self.capacity)
        self.sorted_x = self._make(self, "neighbor_sorted_x", float, self.capacity, (3,))
        self.size = self._make(self, "neighbor_size", ti.i32, ())
        self._no_death = self._make(self, "neighbor_no_death", float, 1)

    def describe(self) -> str:
        """One line for summaries: the method and its capacity."""
        return f"{self.method.value} (capacity {self.capacity})"

    def settings(self) -> dict:
        """The structure's settings for run.json: method, radius [m], capacity."""
        return {"method": self.method.value, "radius": self.radius, "capacity": self.capacity}

    def build(self, x, count: int | None = None, death=None, t: float = 0.0) -> None:
        """Index particles [0, count) of the Vector field x [m]; with a `death` field [s], only those with
        death > t (alive)."""
        n = self.checked_count(x, count)
        self._build(x, n, death if death is not None else self._no_death, float(t), death is not None)

    def checked_count(self, x, count: int | None) -> int:
        """The count `build` indexes (x's length when None), refused outside [0, capacity] and x."""
        n = x.shape[0] if count is None else count
        if not 0 <= n <= min(self.capacity, x.shape[0]):
            raise ParameterError(
                f"count must be in [0, min(capacity {self.capacity}, positions {x.shape[0]})], got {n}"
            )
        return n

    @ti.func
    def for_each_neighbor(self, i, p, radius, visit: ti.template(), ret: ti.template()):
        """From Taichi scope: call visit(i, k, ret) for every slot k whose build-time position sorted_x[k]
        lies strictly within `radius` [m] of p (|d| < radius <= self.radius); the particle is sorted_id[k],
        `i` is passed through and `ret` is the caller's accumulator (by reference)."""
        self._cells(i, p, radius * radius, True, visit, ret)

    @ti.func
    def for_each_candidate(self, i, p, visit: ti.template(), ret: ti.template()):
        """From Taichi scope: call visit(i, k, ret) for every slot k of the 3x3x3 cells around p (all slots
        for brute force), a superset of those within self.radius; the caller tests distances."""
        self._cells(i, p, 0.0, False, visit, ret)

    @ti.func
    def _offer(self, i, k, p, r2, check: ti.template(), visit: ti.template(), ret: ti.template()):
        if ti.static(check):
            if (self.sorted_x[k] - p).norm_sqr() < r2:
                visit(i, k, ret)
        else:
            visit(i, k, ret)


@data_oriented
class NeighborBrute(_NeighborSearch):
    """Every particle is a candidate of every query: the O(N^2) reference, and the fastest for small N."""

    method = NeighborMethod.BRUTE

    @ti.kernel
    def _build(self, x: ti.template(), n: ti.i32, death: ti.template(), t: float, use_death: ti.template()):
        self.build_pass(x, n, death, t, use_death)

    @ti.func
    def build_pass(self, x: ti.template(), n, death: ti.template(), t, use_death: ti.template()):
        """_build's work, for a kernel that builds the structure among other passes."""
        ti.loop_config(serialize=True)  # order-preserving compaction; brute force is only for small N
        for _ in range(1):
            size = 0
            for i in range(n):
                ok = True
                if ti.static(use_death):
                    ok = death[i] > t
                if ok:
                    self.sorted_id[size] = i
                    self.sorted_x[size] = x[i]
                    size += 1
            self.size[None] = size

    @ti.func
    def _cells(self, i, p, r2, check: ti.template(), visit: ti.template(), ret: ti.template()):
        for k in range(self.size[None]):
            self._offer(i, k, p, r2, check, visit, ret)


@data_oriented
class NeighborGrid(_NeighborSearch):
    """Uniform grid of cubic cells of side >= radius, counting-sorted.

    domain=(lo, hi) [m]: a bounded grid over that box (particles outside are clamped into the border
    cells, which stays correct, only slower). domain=None: cells are hashed into a table of 2^k >= 2N
    buckets (Teschner et al. 2003), for unbounded scenes; a query then checks each candidate's own cell,
    so two neighbour cells sharing a bucket never visit a particle twice."""

    def __init__(self, capacity: int, radius: float, domain=None, make=None):
        super().__init__(capacity, radius, make)
        self.hashed = domain is None
        self.method = NeighborMethod.HASH_GRID if self.hashed else NeighborMethod.GRID
        h = self.radius
        if self.hashed:
            self.lo = (0.0, 0.0, 0.0)
            self.dims = (0, 0, 0)
            self.cell_count = 1 << max(6, int(np.ceil(np.log2(2 * self.capacity))))
        else:
            if len(domain) != 2:
                raise ParameterError(f"domain must be (lo, hi), got {domain!r}")
            lo, hi = validate.box("domain", *domain)
            limit = max(MAX_CELLS_PER_PARTICLE * self.capacity, 64)
            while np.prod(np.ceil((hi - lo) / h)) > limit:
                h *= 1.25  # bigger cells: fewer to clear and scan, more candidates per query
            self.lo = tuple(float(c) for c in lo)
            self.dims = tuple(int(max(1, np.ceil((b - a) / h))) for a, b in zip(lo, hi, strict=True))
            self.cell_count = int(np.prod(self.dims))
        self.cell_size = float(h)
        self._inv_h = 1.0 / self.cell_size
        c = self.cell_count
        make = self._make
        self.cell_particles = make(self, "neighbor_cell_particles", ti.i32, c)
        self.cell_start = make(self, "neighbor_cell_start", ti.i32, c + 1)
        self.particle_cell = make(self, "neighbor_particle_cell", ti.i32, self.capacity)
        self.particle_rank = make(self, "neighbor_particle_rank", ti.i32, self.capacity)
        # Hashed grid: each slot's cell, so a query skips other cells sharing a bucket with one compare.
        self.slot_cell = (
            make(self, "neighbor_slot_cell", ti.i32, self.capacity, (3,)) if self.hashed else None
        )
        # Small structures are launch-bound on the CPU: their build loops run on one thread.
        self._serial = serial_loops(self.capacity)
        self._scan = PrefixSum(c, self._serial, make)

    def describe(self) -> str:
        """One line for summaries: cells (or hash buckets) and the cell size [m]."""
        if self.hashed:
            return f"hash_grid ({self.cell_count} buckets, cell {self.cell_size:.4g} m)"
        d = "x".join(str(n) for n in self.dims)
        return f"grid ({d} cells of {self.cell_size:.4g} m)"

    def settings(self) -> dict:
        """The grid's settings for run.json: method, radius, capacity, cell size [m], cells, dims, lo [m]."""
        out = super().settings()
        out.update(cell_size=self.cell_size, cells=self.cell_count, dims=self.dims, lo=self.lo)
        return out

    @ti.func
    def coords(self, p):
        """Integer cell coordinates of point p (floor, so negative coordinates are right)."""
        q = ti.floor((p - ti.Vector(self.lo, dt=float)) * self._inv_h)
        q = ti.max(ti.min(q, 1.0e9), -1.0e9)  # keep the cast to i32 defined for far-away points
        c = ti.cast(q, ti.i32)
        if ti.static(not self.hashed):
            c = ti.max(ti.min(c, ti.Vector(self.dims) - 1), 0)
        return c

    @ti.func
    def key(self, c):
        """Cell (or bucket) index of cell coordinates c."""
        k = 0
        if ti.static(self.hashed):
            u = ti.cast(c, ti.u32)
            h = (u[0] * ti.u32(73856093)) ^ (u[1] * ti.u32(19349663)) ^ (u[2] * ti.u32(83492791))
            k = ti.cast(h & ti.u32(self.cell_count - 1), ti.i32)
        else:
            k = (c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]
        return k

    @ti.kernel
    def _build(self, x: ti.template(), n: ti.i32, death: ti.template(), t: float, use_death: ti.template()):
        self.build_pass(x, n, death, t, use_death)

    @ti.func
    def build_pass(self, x: ti.template(), n, death: ti.template(), t, use_death: ti.template()):
        """_build's work, for a kernel that builds the grid among other passes (a small liquid's
        substep, bodies/fluid/serial_substep.py)."""
        ti.loop_config(serialize=self._serial)
        for c in range(self.cell_count):
            self.cell_particles[c] = 0
        ti.loop_config(serialize=self._serial)
        for i in range(n):
            ok = True
            if ti.static(use_death):
                ok = death[i] > t
            cell = -1
            if ok:
                cell = self.key(self.coords(x[i]))
                self.particle_rank[i] = ti.atomic_add(self.cell_particles[cell], 1)
            self.particle_cell[i] = cell
        self._scan.exclusive(self.cell_particles, self.cell_start, self.cell_count)
        ti.loop_config(serialize=self._serial)
        for i in range(n):
            cell = self.particle_cell[i]
            if cell >= 0:
                self.sorted_id[self.cell_start[cell] + self.particle_rank[i]] = i
        # The atomic ranks depend on thread timing: sort each cell by particle index so every query
        # visits neighbours in one order and float sums over them are reproducible. Serial loops rank in
        # index order already: no sort, and no pass over every cell (a liquid's tank has ~20 cells a
        # particle).
        if ti.static(not self._serial):
            for c in range(self.cell_count):
                a = self.cell_start[c]
                for k in range(a + 1, self.cell_start[c + 1]):
                    v = self.sorted_id[k]
                    m = k
                    while m > a and self.sorted_id[m - 1] > v:
                        self.sorted_id[m] = self.sorted_id[m - 1]
                        m -= 1
                    self.sorted_id[m] = v
        self.size[None] = self.cell_start[self.cell_count]
        ti.loop_config(serialize=self._serial)
        for k in range(self.cell_start[self.cell_count]):
            p = x[self.sorted_id[k]]
            self.sorted_x[k] = p
            if ti.static(self.hashed):
                self.slot_cell[k] = self.coords(p)

    @ti.func
    def _cells(self, i, p, r2, check: ti.template(), visit: ti.template(), ret: ti.template()):
        base = self.coords(p)
        if ti.static(self.hashed):
            for q in range(27):
                c = base + ti.Vector([q // 9 - 1, (q // 3) % 3 - 1, q % 3 - 1])
                key = self.key(c)
                for k in range(self.cell_start[key], self.cell_start[key + 1]):
                    # Other cells hashed to this bucket: skip (they are visited through their own).
                    if (self.slot_cell[k] == c).all():
                        self._offer(i, k, p, r2, check, visit, ret)
        else:
            # Cells adjacent in z are adjacent in memory: one contiguous slot range per (x, y) column.
            z0 = ti.max(base[2] - 1, 0)
            z1 = ti.min(base[2] + 1, self.dims[2] - 1)
            for q in range(9):
                cx = base[0] + q // 3 - 1
                cy = base[1] + q % 3 - 1
                if 0 <= cx < self.dims[0] and 0 <= cy < self.dims[1]:
                    row = (cx * self.dims[1] + cy) * self.dims[2]
                    for k in range(self.cell_start[row + z0], self.cell_start[row + z1 + 1]):
                        self._offer(i, k, p, r2, check, visit, ret)

    @ti.func
    def for_each_near(self, i, p, radius: ti.template(), visit: ti.template(), ret: ti.template()):
        """From Taichi scope, for a grid built with cells of at least radius / 2: call
        visit(i, k, p - sorted_x[k], ret) for every slot k within `radius` [m] of p, scanning the 5 x 5
        columns of 5 cells around p's cell (a box of 5/2 radius on a side: about 40 % fewer candidates
        than the 27 cells of radius a for_each_neighbor scans on a grid of cells of radius). `radius`: a
        Python number (its square is taken in double precision, as the liquid's solver always has).
        A bounded grid only (the hashed one's buckets are not laid out by column)."""
        self._columns(i, p, radius * radius, True, visit, ret)

    @ti.func
    def for_each_in_columns(self, i, p, visit: ti.template(), ret: ti.template()):
        """for_each_near's scan without its distance test: visit(i, k, p - sorted_x[k], ret) for every
        slot k of the 5 x 5 columns of 5 cells around p's cell, in the same order, for a caller whose
        own test is branch-free (a test that mostly fails, taken as a branch, mispredicts often)."""
        self._columns(i, p, 0.0, False, visit, ret)

    @ti.func
    def _columns(
        self, i, p, r2: ti.template(), check: ti.template(), visit: ti.template(), ret: ti.template()
    ):
        ti.static_assert(not self.hashed, "the column scan needs a bounded grid")
        base = self.coords(p)
        z0 = ti.max(base[2] - 2, 0)
        z1 = ti.min(base[2] + 2, self.dims[2] - 1)
        for q in range(25):
            cx = base[0] + q // 5 - 2
            cy = base[1] + q % 5 - 2
            if 0 <= cx < self.dims[0] and 0 <= cy < self.dims[1]:
                row = (cx * self.dims[1] + cy) * self.dims[2]  # cells adjacent in z are adjacent in memory
                for k in range(self.cell_start[row + z0], self.cell_start[row + z1 + 1]):
                    d = p - self.sorted_x[k]
                    if ti.static(check):
                        if d.norm_sqr() < r2:
                            visit(i, k, d, ret)
                    else:
                        visit(i, k, d, ret)


def make_neighbor_search(capacity: int, radius: float, *, domain=None, method: str = "auto", make=None):
    """A neighbour structure for up to `capacity` particles and queries up to `radius` [m]; make: the
    allocator of its fields (a model's pool under capacity buckets; default new fields).

    method: "brute", "grid" (needs domain=(lo, hi)), "hash_grid", or "auto": the bounded grid when a
    domain is given, else the hashed grid, or brute force below their measured crossover (CROSSOVER_N,
    CROSSOVER_N_HASHED particles)."""
    names = [m.value for m in NeighborMethod] + ["auto"]
    validate.choice("method", method, names)
    if method == "auto":
        method = "grid" if domain is not None else "hash_grid"
        if capacity < (CROSSOVER_N if domain is not None else CROSSOVER_N_HASHED):
            method = "brute"
    if method == "brute":
        return NeighborBrute(capacity, radius, make)
    if method == "grid" and domain is None:
        raise ParameterError("method='grid' needs domain=(lo, hi); use 'hash_grid' without one")
    return NeighborGrid(capacity, radius, domain if method == "grid" else None, make)
