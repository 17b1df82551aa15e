"""Loose octree (Ulrich 2000) and its single-level case, the uniform loose grid: box and sphere queries
visit exactly the boxes a brute-force scan finds, with degenerate, duplicated, huge and tiny boxes
(many levels), negative coordinates, queries outside the root cube or covering it (the level-scan
path), n = 1 and 2, after moving boxes, in f32 with parallel loops; the slot order is reproducible."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim import ParameterError
from taichi_anim.spatial import Octree, TriGrid

from .test_bvh import Collector, brute_boxes, brute_spheres, fill, queries, random_boxes

CLASSES = [Octree, TriGrid]


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
    tree = cls(2000)
    nq = 200
    col = Collector(tree, nq)
    for n in (1, 2, 3, 17, 2000):
        lo, hi = random_boxes(n, rng)
        fill(tree, lo, hi)
        tree.build(n)
        check(tree, col, lo, hi, rng, nq)


@pytest.mark.parametrize("cls", CLASSES)
def test_sizes_over_many_levels_and_moves(cls):
    """Extents from 1e-6 to 10 (every octree level occupied, the grid forced coarse), boxes on cell
    borders of the finest levels; then the boxes move and refit() (a rebuild) is exact again."""
    rng = np.random.default_rng(12)
    n, nq = 1500, 200
    tree = cls(n)
    col = Collector(tree, nq, max_hits=n)
    c = rng.uniform(-4.0, 1.0, (n, 3))
    c[::7] = np.round(c[::7] * 64.0) / 64.0  # on grid planes
    e = 10.0 ** rng.uniform(-6.0, 1.0, (n, 1)) * rng.uniform(0.0, 1.0, (n, 3))
    lo, hi = c - e, c + e
    fill(tree, lo, hi)
    tree.build(n)
    if cls is Octree:
        assert (tree.level_count.to_numpy() > 0).sum() >= 10
    check(tree, col, lo, hi, rng, nq)
    lo, hi = lo + rng.normal(scale=0.5, size=(n, 3)), hi + 0.6
    fill(tree, lo, hi)
    tree.refit()
    check(tree, col, lo, hi, rng, nq)


@pytest.mark.parametrize("cls", CLASSES)
def test_f32_parallel_and_reproducible(cls):
    ta.init("cpu", precision="f32")
    rng = np.random.default_rng(13)
    n, nq = 30_000, 150
    tree = cls(n)
    col = Collector(tree, nq)
    lo, hi = (a.astype(np.float32) for a in random_boxes(n, rng, scale=100.0, shared=0.0, huge=False))
    fill(tree, lo, hi)
    tree.build(n)
    slots = tree.slot_prim.to_numpy()
    assert sorted(slots.tolist()) == list(range(n))
    tree.build(n)
    np.testing.assert_array_equal(tree.slot_prim.to_numpy(), slots)
    qlo, qhi = (a.astype(np.float32) * 100.0 for a in queries(lo / 100.0, hi / 100.0, nq, rng))
    col.boxes(qlo, qhi, nq)
    assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi)


def test_empty_and_parameter_errors():
    tree = Octree(3)
    col = Collector(tree, 1)
    tree.build(0)
    col.boxes(np.full((1, 3), -1e9), np.full((1, 3), 1e9), 1)
    assert col.lists(1) == [set()]
    with pytest.raises(ParameterError, match="capacity"):
        Octree(0)
    with pytest.raises(ParameterError, match="n must"):
        tree.build(4)
