"""Neighbour search: grid, hashed grid and brute force find exactly the pairs of a NumPy O(N^2) scan
(Green 2010 counting sort; Teschner et al. 2003 hashing), on clouds with negative coordinates, points on
cell borders, points outside a bounded grid, and dead particles."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim import NeighborMethod, ParameterError, make_neighbor_search

MAX_NEIGHBORS = 96


@ti.data_oriented
class PairCollector:
    """Lists, per particle, the slots the query visits (as particle indices) and counts visits."""

    def __init__(self, ns, n):
        self.ns = ns
        self.found = ti.field(ti.i32, (n, MAX_NEIGHBORS))
        self.found_count = ti.field(ti.i32, n)

    @ti.func
    def visit(self, i, k, ret: ti.template()):
        j = self.ns.sorted_id[k]
        if j != i:
            if ret < MAX_NEIGHBORS:
                self.found[i, ret] = j
            ret += 1

    @ti.kernel
    def collect(self, x: ti.template(), n: ti.i32, radius: float):
        for i in range(n):
            acc = 0
            self.ns.for_each_neighbor(i, x[i], radius, self.visit, acc)
            self.found_count[i] = acc


def query_pairs(ns, x_np, radius, alive=None):
    n = len(x_np)
    x = ti.Vector.field(3, float, n)
    x.from_numpy(x_np)
    death = None
    if alive is not None:
        death = ti.field(float, n)
        death.from_numpy(np.where(alive, 1.0, -1.0))
    ns.build(x, death=death, t=0.0)
    c = PairCollector(ns, n)
    c.collect(x, n, radius)
    counts = c.found_count.to_numpy()
    assert counts.max() <= MAX_NEIGHBORS
    found = c.found.to_numpy()
    keep = np.ones(n, bool) if alive is None else alive
    pairs = {(i, j) for i in np.nonzero(keep)[0] for j in found[i, : counts[i]]}
    return pairs, counts


def numpy_pairs(x, radius, alive=None):
    d2 = ((x[:, None, :] - x[None, :, :]) ** 2).sum(-1)
    ok = d2 < radius * radius
    np.fill_diagonal(ok, False)
    if alive is not None:
        ok &= alive[:, None] & alive[None, :]
    return {(int(i), int(j)) for i, j in zip(*np.nonzero(ok), strict=True)}


def cloud(n, seed, h):
    """Random points in [-1, 0.6]^3 plus points exactly on cell borders (multiples of h)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 0.6, (n, 3))
    x[: n // 4] = np.round(x[: n // 4] / h) * h
    return x


METHODS = ["brute", "grid", "hash_grid"]


@pytest.mark.parametrize("method", METHODS)
def test_same_pairs_as_numpy(method):
    h = 0.1
    radius = 0.0937  # no lattice distance 0.1*sqrt(k) is near it, so no pair is a rounding tie
    x = cloud(3000, 1, h)
    domain = ((-0.7, -0.7, -0.7), (0.4, 0.4, 0.4)) if method == "grid" else None  # some points outside
    ns = make_neighbor_search(len(x), h, domain=domain, method=method)
    assert ns.method == NeighborMethod(method)
    pairs, _ = query_pairs(ns, x, radius)
    expected = numpy_pairs(x, radius)
    assert len(expected) > 3000  # the test has pairs to find
    assert pairs == expected


@pytest.mark.parametrize("method", ["grid", "hash_grid"])
def test_dead_particles_are_not_indexed(method):
    h = 0.1
    x = cloud(2000, 2, h)
    alive = np.random.default_rng(3).random(len(x)) < 0.6
    ns = make_neighbor_search(len(x), h, domain=((-1, -1, -1), (0.6, 0.6, 0.6)), method=method)
    pairs, _ = query_pairs(ns, x, 0.0937, alive)
    assert ns.size[None] == alive.sum()
    assert pairs == numpy_pairs(x, 0.0937, alive)


def test_hash_collisions_do_not_duplicate_pairs():
    """A tiny table (64 buckets) makes many of the 27 cells around a point share buckets."""
    h = 0.05
    x = cloud(30, 4, h) * 3.0  # spread over many cells -> collisions in the 64-bucket table
    ns = make_neighbor_search(len(x), h, method="hash_grid")
    assert ns.cell_count == 64
    pairs, counts = query_pairs(ns, x, 0.049)
    expected = numpy_pairs(x, 0.049)
    assert pairs == expected
    assert counts.sum() == len(expected)  # each pair visited once, not once per shared bucket


def test_slots_are_sorted_by_cell_then_index():
    """Counting sort output: cells in order, particle indices ascending within a cell (reproducible)."""
    h = 0.1
    x = cloud(4000, 5, h)
    ns = make_neighbor_search(len(x), h, domain=((-1, -1, -1), (0.6, 0.6, 0.6)), method="grid")
    xf = ti.Vector.field(3, float, len(x))
    xf.from_numpy(x)
    ns.build(xf)
    ids = ns.sorted_id.to_numpy()
    assert sorted(ids) == list(range(len(x)))
    # The kernel's own cell keys (a border point's cell depends on fused multiply-adds under fast math,
    # so NumPy's floor may put it in the next cell; the pair tests cover border points).
    key = ns.particle_cell.to_numpy()[ids]
    counts = np.bincount(key, minlength=ns.cell_count)
    assert np.array_equal(ns.cell_start.to_numpy()[:-1], np.concatenate([[0], np.cumsum(counts)[:-1]]))
    order = np.lexsort((ids, key))
    assert np.array_equal(order, np.arange(len(x)))
    assert np.allclose(ns.sorted_x.to_numpy(), x[ids])


def test_auto_choice_and_errors():
    from taichi_anim.collision.neighbors import CROSSOVER_N, CROSSOVER_N_HASHED

    box = ((0, 0, 0), (1, 1, 1))
    assert make_neighbor_search(CROSSOVER_N - 1, 0.1, domain=box).method == NeighborMethod.BRUTE
    big = make_neighbor_search(CROSSOVER_N, 0.1, domain=box)
    assert big.method == NeighborMethod.GRID and "grid" in big.describe()
    assert make_neighbor_search(CROSSOVER_N_HASHED - 1, 0.1).method == NeighborMethod.BRUTE
    assert make_neighbor_search(CROSSOVER_N_HASHED, 0.1).method == NeighborMethod.HASH_GRID
    with pytest.raises(ParameterError, match="method"):
        make_neighbor_search(10, 0.1, method="octree")
    with pytest.raises(ParameterError, match="radius"):
        make_neighbor_search(10, 0.0)
    with pytest.raises(ParameterError, match="domain"):
        make_neighbor_search(10, 0.1, method="grid")
    with pytest.raises(ParameterError, match="domain"):
        make_neighbor_search(10, 0.1, domain=((0, 0, 0), (1, -1, 1)), method="grid")


def test_parallel_build_finds_the_same_pairs_as_a_kd_tree():
    """Above CPU_SERIAL_BELOW the build runs in parallel (atomic ranks, per-cell sort, parallel scan
    passes): the pairs still equal SciPy's k-d tree, and the slot order is the same on 1 and 2 threads."""
    from scipy.spatial import cKDTree

    from taichi_anim.runtime import CPU_SERIAL_BELOW

    h, radius = 0.05, 0.0468
    x = cloud(CPU_SERIAL_BELOW + 5000, 11, h)
    expected = cKDTree(x).query_pairs(radius, output_type="set")
    expected = {(i, j) for i, j in expected} | {(j, i) for i, j in expected}
    orders = {}
    for method in ("grid", "hash_grid"):
        for threads in (2, 1):
            ta.init("cpu", precision="f64", cpu_threads=threads)
            domain = ((-1, -1, -1), (0.6, 0.6, 0.6)) if method == "grid" else None
            ns = make_neighbor_search(len(x), h, domain=domain, method=method)
            pairs, _ = query_pairs(ns, x, radius)
            assert pairs == expected
            orders[method, threads] = ns.sorted_id.to_numpy()
        assert np.array_equal(orders[method, 1], orders[method, 2])


def test_build_rejects_a_count_beyond_the_positions():
    ns = make_neighbor_search(100, 0.1, method="grid", domain=((0, 0, 0), (1, 1, 1)))
    x = ti.Vector.field(3, float, 10)
    with pytest.raises(ParameterError, match="count must be in"):
        ns.build(x, count=100)
    with pytest.raises(ParameterError, match="count must be in"):
        ns.build(x, count=-5)


@ti.data_oriented
class ScanRecorder:
    """Per particle, the slots for_each_near visits and, separately, the candidates for_each_in_columns
    visits with the same distance test applied afterwards, each in visit order."""

    def __init__(self, ns, n, radius):
        self.ns, self.radius = ns, radius
        self.near = ti.field(ti.i32, (n, MAX_NEIGHBORS))
        self.near_count = ti.field(ti.i32, n)
        self.kept = ti.field(ti.i32, (n, MAX_NEIGHBORS))
        self.kept_count = ti.field(ti.i32, n)
        self.candidates = ti.field(ti.i32, n)

    @ti.func
    def visit_near(self, i, k, d, ret: ti.template()):
        if ret < MAX_NEIGHBORS:
            self.near[i, ret] = k
        ret += 1

    @ti.func
    def visit_candidate(self, i, k, d, ret: ti.template()):
        ret[1] += 1
        if d.norm_sqr() < self.radius * self.radius:
            if ret[0] < MAX_NEIGHBORS:
                self.kept[i, ret[0]] = k
            ret[0] += 1

    @ti.kernel
    def scan(self, x: ti.template(), n: ti.i32):
        for i in range(n):
            acc = 0
            self.ns.for_each_near(i, x[i], self.radius, self.visit_near, acc)
            self.near_count[i] = acc
            both = ti.Vector([0, 0])
            self.ns.for_each_in_columns(i, x[i], self.visit_candidate, both)
            self.kept_count[i] = both[0]
            self.candidates[i] = both[1]


def test_column_scan_is_the_near_scan_without_its_test():
    """for_each_in_columns visits the 5 x 5 x 5 cells around a point in for_each_near's order: the
    candidates within the radius are exactly for_each_near's slots, in the same order, and those are
    NumPy's pairs; the candidates are the particles of the 125 cells (clipped at the grid's edges)."""
    h = 0.1
    radius = 0.1873  # cells of h = radius / 2 (about); no lattice distance is near it
    x = cloud(2000, 3, h)
    lo, hi = np.full(3, -1.0), np.full(3, 0.6)
    ns = make_neighbor_search(len(x), radius / 2, domain=(tuple(lo), tuple(hi)), method="grid")
    xf = ti.Vector.field(3, float, len(x))
    xf.from_numpy(x)
    ns.build(xf)
    rec = ScanRecorder(ns, len(x), radius)
    rec.scan(xf, len(x))
    near_n, kept_n = rec.near_count.to_numpy(), rec.kept_count.to_numpy()
    assert near_n.max() <= MAX_NEIGHBORS and (near_n == kept_n).all()
    near, kept = rec.near.to_numpy(), rec.kept.to_numpy()
    for i in range(len(x)):
        assert (near[i, : near_n[i]] == kept[i, : kept_n[i]]).all()
    ids = ns.sorted_id.to_numpy()
    pairs = {(i, int(ids[k])) for i in range(len(x)) for k in near[i, : near_n[i]] if ids[k] != i}
    assert pairs == numpy_pairs(x, radius)
    cell = np.clip(np.floor((x - lo) / ns.cell_size).astype(int), 0, np.array(ns.dims) - 1)
    box = (np.abs(cell[:, None, :] - cell[None, :, :]) <= 2).all(axis=2)
    np.testing.assert_array_equal(rec.candidates.to_numpy(), box.sum(axis=1))
