"""Linear BVH (Karras 2012): every query visits exactly the primitives a brute-force scan over all boxes
finds, on random box sets with degenerate (zero-extent) boxes, duplicated centres (equal Morton codes),
very large boxes, negative coordinates, n = 1 and 2, after refits, and on the deepest trees Morton codes
give; the tree is a valid binary tree over every primitive; update() rebuilds exactly when the
surface-area cost ratio passes its threshold."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim import ParameterError
from taichi_anim.runtime import CPU_SERIAL_BELOW
from taichi_anim.spatial import BVH, aabb_ray
from taichi_anim.spatial.lbvh_query import ray_inv_dir

MAX_HITS = 2048
# The f64 tests share one tree capacity and one collector size: the same field layout gives the same
# compiled kernels, which Taichi's offline cache then shares between the tests (compiling the build and
# the queries costs more than running them).
CAP, NQ = 4000, 300


@ti.data_oriented
class Collector:
    """Runs a batch of box / sphere / ray queries; lists the primitives visited per query."""

    def __init__(self, tree, nq, max_hits=MAX_HITS):
        self.tree = tree
        self.max_hits = max_hits
        self.hits = ti.field(ti.i32, (nq, max_hits))
        self.count = ti.field(ti.i32, nq)

    @ti.func
    def visit(self, i, prim, ret: ti.template()):
        if ret < self.max_hits:
            self.hits[i, ret] = prim
        ret += 1

    @ti.kernel
    def boxes(self, a: ti.types.ndarray(), b: ti.types.ndarray(), nq: ti.i32):
        for i in range(nq):
            acc = 0
            lo = ti.Vector([a[i, 0], a[i, 1], a[i, 2]], float)
            hi = ti.Vector([b[i, 0], b[i, 1], b[i, 2]], float)
            self.tree.for_each_overlap(i, lo, hi, self.visit, acc)
            self.count[i] = acc

    @ti.kernel
    def spheres(self, a: ti.types.ndarray(), r: ti.types.ndarray(), nq: ti.i32):
        for i in range(nq):
            acc = 0
            c = ti.Vector([a[i, 0], a[i, 1], a[i, 2]], float)
            self.tree.for_each_in_sphere(i, c, r[i], self.visit, acc)
            self.count[i] = acc

    @ti.kernel
    def rays(self, a: ti.types.ndarray(), b: ti.types.ndarray(), t: ti.types.ndarray(), nq: ti.i32):
        for i in range(nq):
            acc = 0
            o = ti.Vector([a[i, 0], a[i, 1], a[i, 2]], float)
            d = ti.Vector([b[i, 0], b[i, 1], b[i, 2]], float)
            self.tree.for_each_ray(i, o, d, t[i], self.visit, acc)
            self.count[i] = acc

    @ti.kernel
    def rays_brute(
        self, a: ti.types.ndarray(), b: ti.types.ndarray(), t: ti.types.ndarray(), nq: ti.i32, n: ti.i32
    ):
        """The same slab predicate on every box: the reference for the ray walk."""
        for i in range(nq):
            acc = 0
            o = ti.Vector([a[i, 0], a[i, 1], a[i, 2]], float)
            d = ti.Vector([b[i, 0], b[i, 1], b[i, 2]], float)
            for k in range(n):
                hit, _ = aabb_ray(self.tree.prim_lo[k], self.tree.prim_hi[k], o, ray_inv_dir(d), t[i])
                if hit:
                    self.visit(i, k, acc)
            self.count[i] = acc

    def lists(self, nq):
        c = self.count.to_numpy()[:nq]
        assert c.max(initial=0) <= self.max_hits
        h = self.hits.to_numpy()
        out = []
        for i in range(nq):
            got = h[i, : c[i]].tolist()
            assert len(got) == len(set(got)), f"query {i} visited a primitive twice"
            out.append(set(got))
        return out


def tree_and_collector(**options):
    """A BVH of capacity CAP and a collector of NQ queries that can list every primitive."""
    tree = BVH(CAP, **options)
    return tree, Collector(tree, NQ, max_hits=CAP)


def fill(tree, lo, hi):
    """Write boxes into the tree's primitive fields (padding the rest of the capacity with junk)."""
    cap = tree.capacity
    pad = np.full((cap - len(lo), 3), 7.0, dtype=lo.dtype)
    tree.prim_lo.from_numpy(np.vstack([lo, pad]))
    tree.prim_hi.from_numpy(np.vstack([hi, pad + 1.0]))


def random_boxes(n, rng, *, scale=1.0, shared=0.25, huge=True):
    """Boxes with negative coordinates, 1/5 degenerate, a share of them with one centre, a few huge."""
    c = rng.uniform(-scale, 0.5 * scale, (n, 3))
    e = rng.uniform(0.0, 0.05 * scale, (n, 3))
    e[::5] = 0.0
    c[: int(n * shared)] = c[0]
    if n > 10 and huge:
        e[3] = 50.0 * scale
        e[7, 0] = 30.0 * scale
    return c - e, c + e


def brute_boxes(lo, hi, qlo, qhi):
    return [
        set(np.nonzero(np.all(lo <= b, 1) & np.all(a <= hi, 1))[0].tolist())
        for a, b in zip(qlo, qhi, strict=True)
    ]


def brute_spheres(lo, hi, c, r):
    out = []
    for p, rr in zip(c, r, strict=True):
        e = np.maximum(lo - p, 0.0) + np.maximum(p - hi, 0.0)
        out.append(set(np.nonzero((e * e).sum(1) <= rr * rr)[0].tolist()))
    return out


def queries(lo, hi, nq, rng):
    """Random query boxes plus ones that touch primitives exactly (a corner, a whole box, a point)."""
    n = len(lo)
    c = rng.uniform(-1.2, 0.7, (nq, 3))
    e = rng.uniform(0.0, 0.2, (nq, 3))
    qlo, qhi = c - e, c + e
    k = rng.integers(0, n, nq)
    qlo[:10], qhi[:10] = hi[k[:10]], hi[k[:10]] + 0.1  # touches box k at its hi corner
    qlo[10:20], qhi[10:20] = lo[k[10:20]], hi[k[10:20]]
    qlo[20:30] = qhi[20:30] = lo[k[20:30]]  # a point query on a corner
    return qlo, qhi


def tree_check(tree, n):
    """Walk the tree in NumPy: a binary tree whose leaves are each primitive once; each child box
    stored in a node is the primitive's box (leaf) or the union of that child's own children's boxes.
    Returns the depth (leaf levels)."""
    root = int(tree.root[None])
    if n == 0:
        assert root == -1
        return 0
    child = tree.node_child.to_numpy()
    box = tree.node_box.to_numpy()  # (inner, 4, 3): lo_a, hi_a, lo_b, hi_b
    plo, phi = tree.prim_lo.to_numpy(), tree.prim_hi.to_numpy()
    pid = tree.prim_id.to_numpy()[:n]
    assert sorted(pid.tolist()) == list(range(n))

    m = n - 1  # internal nodes 0 .. n-2
    inner_lo = np.minimum(box[:m, 0], box[:m, 2])
    inner_hi = np.maximum(box[:m, 1], box[:m, 3])

    def own(c):
        """Boxes of nodes c (array): the primitive's for leaves, the union of children for the rest."""
        leaf = c >= tree.leaf_base
        k = pid[np.where(leaf, c - tree.leaf_base, 0)]
        ci = np.where(leaf, 0, c)
        lo = np.where(leaf[:, None], plo[k], inner_lo[ci] if m else plo[k])
        hi = np.where(leaf[:, None], phi[k], inner_hi[ci] if m else phi[k])
        return lo, hi

    rlo, rhi = own(np.array([root]))
    np.testing.assert_array_equal(tree.root_box.to_numpy(), [rlo[0], rhi[0]])
    for side in range(2):
        lo, hi = own(child[:m, side])
        np.testing.assert_array_equal(box[:m, 2 * side], lo)
        np.testing.assert_array_equal(box[:m, 2 * side + 1], hi)
    seen, depth, stack = [], 0, [(root, 1)]
    while stack:
        node, d = stack.pop()
        depth = max(depth, d)
        if node >= tree.leaf_base:
            seen.append(node - tree.leaf_base)
        else:
            stack += [(int(child[node, 0]), d + 1), (int(child[node, 1]), d + 1)]
    assert sorted(seen) == list(range(n))
    return depth


def test_overlap_and_sphere_equal_brute_force():
    rng = np.random.default_rng(1)
    tree, col = tree_and_collector()
    nq = NQ
    for n in (1, 2, 3, 17, CAP):
        lo, hi = random_boxes(n, rng)
        fill(tree, lo, hi)
        tree.build(n)
        tree_check(tree, n)
        qlo, qhi = queries(lo, hi, nq, rng)
        col.boxes(qlo, qhi, nq)
        assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi), n
        c = 0.5 * (qlo + qhi)
        r = rng.uniform(0.0, 0.3, nq)
        r[:5] = 0.0
        col.spheres(c, r, nq)
        assert col.lists(nq) == brute_spheres(lo, hi, c, r), n


def test_rays_equal_brute_force():
    rng = np.random.default_rng(2)
    n, nq = 1500, NQ
    tree, col = tree_and_collector()
    lo, hi = random_boxes(n, rng)
    fill(tree, lo, hi)
    tree.build(n)
    o = rng.uniform(-1.5, 1.0, (nq, 3))
    d = rng.normal(size=(nq, 3))
    d[:20, 1:] = 0.0  # axis-parallel rays (zero direction components)
    d[20:25] = 0.0  # a point
    o[25:35] = lo[rng.integers(0, n, 10)]  # starting on a box corner
    t = rng.uniform(0.0, 3.0, nq)
    t[35:45] = np.inf
    col.rays(o, d, t, nq)
    got = col.lists(nq)
    col.rays_brute(o, d, t, nq, n)
    assert got == col.lists(nq)
    # the slab predicate itself against a dense sampling of the segments (a hit sampled is a hit found)
    for i in range(45, 60):
        s = np.linspace(0.0, t[i], 2001)[:, None] * d[i] + o[i]
        near = np.nonzero(np.all(lo <= s.max(0), 1) & np.all(s.min(0) <= hi, 1))[0]  # meet the samples' box
        inside = near[np.any(np.all((s[:, None] >= lo[near]) & (s[:, None] <= hi[near]), -1), 0)]
        assert set(inside.tolist()) <= got[i]


def test_refit_after_moving_boxes_equals_brute_force():
    rng = np.random.default_rng(3)
    n, nq = 1000, 200
    tree, col = tree_and_collector()
    lo, hi = random_boxes(n, rng)
    fill(tree, lo, hi)
    tree.build(n)
    for step in range(3):
        move = rng.normal(scale=0.3, size=(n, 3))  # large, incoherent motion: the topology gets bad
        grow = rng.uniform(0.0, 0.02, (n, 3))
        lo, hi = lo + move - grow, hi + move + grow
        fill(tree, lo, hi)
        tree.refit()
        tree_check(tree, n)
        qlo, qhi = queries(lo, hi, nq, rng)
        col.boxes(qlo, qhi, nq)
        assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi), step
    assert tree.build_count == 1


def test_deep_trees_from_equal_and_nested_codes():
    """All centres equal (the tree comes from the index tie-break alone), and 100 copies each of centres
    whose Morton codes are 2^m, m = 0..29 (a chain of prefixes, 30 levels, then 7 more levels of equal
    codes): queries stay exact however deep the tree."""
    rng = np.random.default_rng(4)
    m = np.arange(30)
    c = np.zeros((32, 3))
    c[m, 2 - m % 3] = 2.0 ** (m // 3)  # quantised coordinate 2^(m//3) on axis 2 - m%3: code bit m
    c[31] = 1024.0  # with c[30] = 0 the centres span [0, 1024]^3: one unit per quantisation cell
    c = np.repeat(c + 0.5 * (c < 1024.0), 100, axis=0)
    n = len(c)
    tree, col = tree_and_collector()
    nq = 100
    e = np.where(np.arange(n)[:, None] % 3 == 0, 0.0, 0.25)
    cases = (((-np.ones((n, 3)), np.ones((n, 3))), 13), ((c - e, c + e), 37))
    for (lo, hi), min_depth in cases:
        fill(tree, lo, hi)
        tree.build(n)
        assert tree_check(tree, n) >= min_depth
        qlo, qhi = queries(lo, hi, nq, rng)
        qlo[30:60] = c[rng.integers(0, n, 30)] - 0.3
        qhi[30:60] = qlo[30:60] + 0.6
        col.boxes(qlo, qhi, nq)
        assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi)


def test_update_rebuilds_only_when_cost_ratio_passes():
    rng = np.random.default_rng(5)
    n = CAP
    tree, _ = tree_and_collector(rebuild_ratio=1.5)  # the collector unused: the shared field layout
    lo, hi = random_boxes(n, rng, shared=0.0, huge=False)
    fill(tree, lo, hi)
    tree.build(n)
    assert tree.cost_ratio() == pytest.approx(1.0)
    # a rigid translation and a uniform scaling keep the cost (it is normalised by the root's area)
    fill(tree, 2.0 * lo + 5.0, 2.0 * hi + 5.0)
    assert not tree.update()
    assert tree.cost_ratio() == pytest.approx(1.0, rel=1e-9)
    # shuffling which box sits where destroys the Morton order: refit cost soars, update rebuilds
    perm = rng.permutation(n)
    fill(tree, lo[perm], hi[perm])
    tree.refit()
    ratio = tree.cost_ratio()
    assert ratio > 1.5
    # ... and the rule compares exactly that ratio with the threshold
    loose = BVH(n, rebuild_ratio=ratio * 1.01)
    fill(loose, lo, hi)
    loose.build(n)
    fill(loose, lo[perm], hi[perm])
    assert not loose.update() and loose.build_count == 1
    assert tree.update() and tree.build_count == 2
    assert tree.cost_ratio() == pytest.approx(1.0)


@pytest.mark.parametrize("climb", [False, True])
def test_f32_and_parallel_loops(climb):
    """Single precision, and a capacity at the serial-loop threshold (the parallel build and refit);
    also with the GPU's refit (atomic visit counters), forced on the CPU."""
    ta.init("cpu", precision="f32")
    rng = np.random.default_rng(6)
    n, nq = CPU_SERIAL_BELOW, 200
    tree = BVH(n)
    tree._climb = climb
    col = Collector(tree, nq)
    lo, hi = (a.astype(np.float32) for a in random_boxes(n, rng, scale=100.0, shared=0.0))
    lo[5:10], hi[5:10] = lo[4], hi[4]
    fill(tree, lo, hi)
    tree.build(n)
    tree_check(tree, n)
    qlo, qhi = (a.astype(np.float32) * 100.0 for a in queries(lo / 100.0, hi / 100.0, nq, rng))
    same = [4, 5, 6, 8, 9, 10, 11, 12, 13, 14]  # query = a primitive's box (not a huge one)
    qlo[:10], qhi[:10] = lo[same], hi[same]
    col.boxes(qlo, qhi, nq)
    assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi)
    lo, hi = lo - 1.0, hi + np.float32(0.5)
    fill(tree, lo, hi)
    tree.refit()
    col.boxes(qlo, qhi, nq)
    assert col.lists(nq) == brute_boxes(lo, hi, qlo, qhi)


def test_empty_tree_and_parameter_errors():
    tree, col = tree_and_collector()
    tree.build(0)
    q = np.array([[-1e9] * 3, [0.0] * 3])
    col.boxes(q, -q, 2)
    assert col.lists(2) == [set(), set()]
    with pytest.raises(ParameterError, match="capacity"):
        BVH(0)
    with pytest.raises(ParameterError, match="rebuild_ratio"):
        BVH(4, rebuild_ratio=1.0)
    with pytest.raises(ParameterError, match="n must"):
        tree.build(CAP + 1)
    with pytest.raises(ParameterError, match="n must"):
        tree.build(-1)
