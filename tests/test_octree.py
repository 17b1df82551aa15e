"""Loose octree (Ulrich 2000), its single-level case (the uniform loose grid) and the brute-force box
set: box and sphere queries visit exactly the boxes a NumPy scan finds, with degenerate, duplicated,
huge and tiny boxes (many levels), negative coordinates, queries outside the root cube or covering it
(the level-scan path), n = 1 and 2, after moving boxes, in f32 with parallel loops; the slot order is
reproducible. The automatic choice follows select.py's cost model."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim import ParameterError
from taichi_anim.runtime import CPU_SERIAL_BELOW
from taichi_anim.spatial import BVH, Octree, TriGrid
from taichi_anim.spatial.select import (
    CROSSOVER_N,
    BoxQueryMethod,
    BruteBoxes,
    choose_box_query,
    make_box_query,
)

from .test_bvh import Collector, brute_boxes, brute_spheres, fill, queries, random_boxes

CLASSES = [Octree, TriGrid, BruteBoxes]
# The f64 query tests of a class share one capacity and collector size: the same field layout gives the
# same compiled kernels, which Taichi's offline cache then shares between the tests.
CAP, NQ = 2000, 200


def check(tree, col, lo, hi, rng, nq):
    qlo, qhi = queries(lo, hi, nq, rng)
    qlo[30:35], qhi[30:35] = lo.min(0) - 1.0, hi.max(0) + 1.0  # covers everything: level scans
    qlo[35:40] = qhi[35:40] = hi.max(0) + 1e-6  # just outside the root cube
    col.boxes(qlo, qhi, nq)
    assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi)
    c = 0.5 * (qlo + qhi)
    r = rng.uniform(0.0, 0.3, nq)
    r[:5] = 0.0
    col.spheres(c, r, nq)
    assert col.lists(nq) == brute_spheres(lo, hi, c, r)


@pytest.mark.parametrize("cls", CLASSES)
def test_queries_equal_brute_force(cls):
    rng = np.random.default_rng(11)
    tree = cls(CAP)
    nq = NQ
    col = Collector(tree, nq)
    for n in (1, 2, 3, 17, CAP):
        lo, hi = random_boxes(n, rng)
        fill(tree, lo, hi)
        tree.build(n)
        check(tree, col, lo, hi, rng, nq)


@pytest.mark.parametrize("cls", CLASSES)
def test_sizes_over_many_levels_and_moves(cls):
    """Extents from 1e-6 to 10 (every octree level occupied, the grid forced coarse), boxes on cell
    borders of the finest levels; then the boxes move and refit() (a rebuild) is exact again."""
    rng = np.random.default_rng(12)
    n, nq = 1500, NQ
    tree = cls(CAP)
    col = Collector(tree, nq)  # its MAX_HITS > n: every box fits in a query's list
    c = rng.uniform(-4.0, 1.0, (n, 3))
    c[::7] = np.round(c[::7] * 64.0) / 64.0  # on grid planes
    e = 10.0 ** rng.uniform(-6.0, 1.0, (n, 1)) * rng.uniform(0.0, 1.0, (n, 3))
    lo, hi = c - e, c + e
    fill(tree, lo, hi)
    tree.build(n)
    if cls is Octree:
        assert (tree.level_count.to_numpy() > 0).sum() >= 8
    check(tree, col, lo, hi, rng, nq)
    lo, hi = lo + rng.normal(scale=0.5, size=(n, 3)), hi + 0.6
    fill(tree, lo, hi)
    tree.refit()
    check(tree, col, lo, hi, rng, nq)


@pytest.mark.parametrize("cls", CLASSES)
def test_f32_parallel_and_reproducible(cls):
    ta.init("cpu", precision="f32")
    rng = np.random.default_rng(13)
    n, nq = CPU_SERIAL_BELOW, 150  # the smallest capacity whose loops run in parallel
    tree = cls(n)
    col = Collector(tree, nq)
    lo, hi = (a.astype(np.float32) for a in random_boxes(n, rng, scale=100.0, shared=0.0, huge=False))
    fill(tree, lo, hi)
    tree.build(n)
    if cls is not BruteBoxes:
        slots = tree.slot_prim.to_numpy()
        assert sorted(slots.tolist()) == list(range(n))
        tree.build(n)
        np.testing.assert_array_equal(tree.slot_prim.to_numpy(), slots)
    qlo, qhi = (a.astype(np.float32) * 100.0 for a in queries(lo / 100.0, hi / 100.0, nq, rng))
    col.boxes(qlo, qhi, nq)
    assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi)


def test_empty_and_parameter_errors():
    tree = Octree(CAP)
    col = Collector(tree, NQ)
    tree.build(0)
    col.boxes(np.full((1, 3), -1e9), np.full((1, 3), 1e9), 1)
    assert col.lists(1) == [set()]
    with pytest.raises(ParameterError, match="capacity"):
        Octree(0)
    with pytest.raises(ParameterError, match="n must"):
        tree.build(CAP + 1)


def test_automatic_choice_follows_the_cost_model():
    assert choose_box_query(1) is BoxQueryMethod.BRUTE
    assert choose_box_query(CROSSOVER_N - 20) is BoxQueryMethod.BRUTE
    assert choose_box_query(CROSSOVER_N + 20) is BoxQueryMethod.BVH
    assert choose_box_query(10**6) is BoxQueryMethod.BVH
    assert choose_box_query(10**5, queries=3) is BoxQueryMethod.BRUTE  # a few queries: no build pays
    assert isinstance(make_box_query(100), BruteBoxes)
    assert isinstance(make_box_query(5000), BVH)
    kinds = {"brute": BruteBoxes, "grid": TriGrid, "octree": Octree, "bvh": BVH}
    for name, cls in kinds.items():
        assert type(make_box_query(10, method=name)) is cls
    with pytest.raises(ParameterError, match="method"):
        make_box_query(10, method="kd")
    with pytest.raises(ParameterError, match="count"):
        choose_box_query(-1)
