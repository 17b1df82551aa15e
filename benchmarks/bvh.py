"""Hierarchies over triangles: build, refit and queries of the linear BVH (`spatial/lbvh.py`, through
`spatial.mesh_query.TriangleMesh` for mesh queries), the loose octree, the uniform loose grid and brute
force, N = 10^3 ... 10^6 triangles, against NVIDIA Warp's `wp.Mesh` and `wp.Bvh` on the CPU in the same
process; the crossovers `spatial/select.py` uses; and refit against rebuild as meshes deform (the rule
of `BVH.update`).

Scenes (f32): "sheet", a cloth-like m x m grid of the unit square (N = 2 m^2 triangles) with a wavy
height z = 0.05 sin(6x) cos(5y); "soup", N random triangles with centres uniform in the unit cube and
edges ~ 1.5 / sqrt(N) (1 % of them 10 x larger). Queries: Q points uniform in the box of the mesh grown
by 10 % (closest point, unbounded distance); Q rays from points in that box with uniform random
directions, unbounded (nearest hit); Q boxes of random triangles of the mesh grown by 1 % of the unit
square side (box overlap, the self-contact pattern: every primitive box whose box meets the query box
is counted). Q = min(N, 10^4). The BVH, octree, grid and brute force answer box queries with
`for_each_overlap`; `TriangleMesh.closest_points` and `.ray_casts` answer the mesh queries. Warp: the
same arrays as `wp.array`s; `wp.Mesh(points, indices)` (its default CPU constructor, SAH) with
`mesh_query_point_no_sign` and `mesh_query_ray` kernels, `mesh.refit()`; `wp.Bvh(lowers, uppers)` over
the same primitive boxes with `bvh_query_aabb` (counting, as Warp's benchmark_bvh.py does) and
`bvh.refit()`, plus its "median" constructor's build time. Warp runs each CPU kernel on one core; Taichi
on both (the machine's 2); results name both.

Timing: each operation runs once first (its JIT compile, reported apart as first call minus a steady
call), then repeatedly with `ti.sync()` / `wp.synchronize()` before each clock read until ~`window` s
(at least 3 calls; once if a call takes > 5 s); the median is reported. Brute force runs while Q x N
stays under BRUTE_WORK (beyond, on the first Q' queries with Q' N = BRUTE_WORK; per-query times scale).
Checks in the same run: overlap counts of every method equal; closest distances and ray t equal Warp's
to f32 tolerance.

Refit or rebuild (the rule of `BVH.update`): a sheet crumpled progressively (a sum of random smooth
displacement waves whose amplitude grows frame by frame) and a soup whose triangles random-walk: at each
frame the refit time, the surface-area cost ratio, the box-query time on the refit tree, then a rebuild's
time and the same queries on the fresh tree.

    .venv/bin/python benchmarks/bvh.py           # full run (~10 min), writes benchmarks/results/bvh.*
    .venv/bin/python benchmarks/bvh.py --quick   # smoke run (~2 min), writes benchmarks/out/
"""

import json
import math
import statistics
import time

import numpy as np
import taichi as ti
from common import (
    OtherLoad,
    clock,
    command_line,
    engine_fingerprint,
    fmt_s,
    init,
    load_average,
    log,
    machine_info,
    machine_table,
    md_table,
    output_paths,
    parse_args,
)

from taichi_anim.spatial import BVH, Octree, TriGrid
from taichi_anim.spatial import lbvh as lbvh_module
from taichi_anim.spatial import select as select_module
from taichi_anim.spatial.distance import point_triangle_closest
from taichi_anim.spatial.intersect import ray_triangle
from taichi_anim.spatial.mesh_query import TriangleMesh
from taichi_anim.spatial.select import BruteBoxes

SEED = 0
MAX_QUERIES = 10_000
BRUTE_WORK = 3e8  # largest Q x N brute-force pass that is run in full
LONG_CALL = 5.0
GROW = 0.01  # [m] query boxes: triangle boxes grown by this
BOX_METHODS = ("brute", "grid", "octree", "bvh")
DEFORM_FRAMES = 10


# ---------------------------------------------------------------------------------------------------------
# scenes and queries


def sheet(n: int, amplitude: float = 0.0, rng=None):
    """Wavy m x m grid of the unit square, 2 m^2 ~ n triangles; `amplitude` adds random smooth waves."""
    m = max(1, round(math.sqrt(n / 2)))
    i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
    x, y = i.ravel() / m, j.ravel() / m
    v = np.stack([x, y, 0.05 * np.sin(6 * x) * np.cos(5 * y)], 1)
    if amplitude:
        for _ in range(6):
            k = rng.normal(scale=4.0, size=3)
            v += amplitude * rng.normal(size=3) * np.sin(v @ k + rng.uniform(0, 6.3))[:, None]
    k = (i[:-1, :-1] * (m + 1) + j[:-1, :-1]).ravel()
    f = np.concatenate([np.stack([k, k + m + 1, k + 1], 1), np.stack([k + 1, k + m + 1, k + m + 2], 1)])
    return v.astype(np.float32), f.astype(np.int32)


def soup(n: int, rng):
    """n random triangles in the unit cube, edges ~ 1.5 / sqrt(n), 1 % ten times larger."""
    c = rng.random((n, 1, 3))
    size = np.where(rng.random((n, 1, 1)) < 0.01, 10.0, 1.0) * 1.5 / math.sqrt(n)
    v = (c + size * (rng.random((n, 3, 3)) - 0.5)).reshape(-1, 3)
    return v.astype(np.float32), np.arange(3 * n, dtype=np.int32).reshape(n, 3)


def queries(v, f, q, rng):
    """Closest-point points, ray origins and directions, and query boxes (Q of each)."""
    lo, hi = v.min(0), v.max(0)
    pad = 0.1 * (hi - lo).max()
    p = rng.uniform(lo - pad, hi + pad, (q, 3)).astype(np.float32)
    o = rng.uniform(lo - pad, hi + pad, (q, 3)).astype(np.float32)
    d = rng.normal(size=(q, 3)).astype(np.float32)
    t = v[f[rng.integers(0, len(f), q)]]
    return p, o, d, (t.min(1) - GROW).astype(np.float32), (t.max(1) + GROW).astype(np.float32)


def boxes(v, f):
    t = v[f]
    return t.min(1), t.max(1)


# ---------------------------------------------------------------------------------------------------------
# timing


def timed(fn, window: float, sync=clock) -> float:
    """Minimum seconds per call of fn(), synchronised, repeated ~window s (at least 3 calls): the
    machine is shared, and the minimum is the figure other processes disturb least."""
    times: list[float] = []
    while True:
        a = sync()
        fn()
        times.append(sync() - a)
        if times[0] > LONG_CALL or (len(times) >= 3 and sum(times) >= window) or len(times) >= 500:
            return min(times)


def first_then_timed(fn, window: float, sync=clock) -> tuple[float, float]:
    """(compile = first call - steady call, steady median)."""
    a = sync()
    fn()
    first = sync() - a
    steady = timed(fn, window, sync)
    return max(first - steady, 0.0), steady


@ti.data_oriented
class BoxCount:
    """Counts, per query box, the primitive boxes a structure's for_each_overlap visits."""

    def __init__(self, q: int):
        self.count = ti.field(ti.i32, q)
        self.lo = ti.Vector.field(3, ti.f32, q)
        self.hi = ti.Vector.field(3, ti.f32, q)

    @ti.func
    def visit(self, i, prim, ret: ti.template()):
        ret += 1

    @ti.kernel
    def run(self, tree: ti.template(), q: ti.i32, serial: ti.template()):
        ti.loop_config(serialize=serial)
        for i in range(q):
            acc = 0
            tree.for_each_overlap(i, self.lo[i], self.hi[i], self.visit, acc)
            self.count[i] = acc


@ti.data_oriented
class MeshPass:
    """Closest points and ray casts of Q queries through `TriangleMesh.closest_point` / `.ray_cast`,
    with the loop on both threads or on one (serial=True: the per-core figure, as Warp's CPU kernels)."""

    def __init__(self, mesh, p, o, d):
        q = len(p)
        self.mesh = mesh
        self.p, self.o, self.d = (ti.Vector.field(3, ti.f32, q) for _ in range(3))
        self.p.from_numpy(p)
        self.o.from_numpy(o)
        self.d.from_numpy(d)
        self.dist = ti.field(ti.f32, q)
        self.t = ti.field(ti.f32, q)

    @ti.kernel
    def closest(self, q: ti.i32, serial: ti.template()):
        ti.loop_config(serialize=serial)
        for i in range(q):
            self.dist[i], _f, _w = self.mesh.closest_point(self.p[i], 1.0e30)

    @ti.kernel
    def rays(self, q: ti.i32, serial: ti.template()):
        ti.loop_config(serialize=serial)
        for i in range(q):
            self.t[i], _f, _u, _v = self.mesh.ray_cast(self.o[i], self.d[i], 1.0e30)


@ti.data_oriented
class BruteMesh:
    """Closest point and nearest ray hit by scanning every face (the reference and the brute peer)."""

    def __init__(self, mesh):
        self.mesh = mesh

    @ti.kernel
    def closest(self, p: ti.types.ndarray(), out: ti.types.ndarray()):
        for k in range(p.shape[0]):
            x = ti.Vector([p[k, 0], p[k, 1], p[k, 2]])
            best = ti.math.inf
            for f in range(self.mesh.face_count_field[None]):
                a, b, c = self.mesh.corners(f)
                w = point_triangle_closest(x, a, b, c)
                best = ti.min(best, (x - (w[0] * a + w[1] * b + w[2] * c)).norm_sqr())
            out[k] = ti.sqrt(best)

    @ti.kernel
    def rays(self, o: ti.types.ndarray(), d: ti.types.ndarray(), out: ti.types.ndarray()):
        for k in range(o.shape[0]):
            oo = ti.Vector([o[k, 0], o[k, 1], o[k, 2]])
            dd = ti.Vector([d[k, 0], d[k, 1], d[k, 2]])
            best = ti.math.inf
            for f in range(self.mesh.face_count_field[None]):
                a, b, c = self.mesh.corners(f)
                hit, t, _u, _v = ray_triangle(oo, dd, a, b, c, ti.math.inf)
                if hit:
                    best = ti.min(best, t)
            out[k] = best


# ---------------------------------------------------------------------------------------------------------
# Warp


def warp_kernels():
    """Warp kernels (module level in spirit; defined on first use so Warp is imported only here)."""
    import warp as wp

    @wp.kernel
    def closest(mesh: wp.uint64, p: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
        i = wp.tid()
        q = wp.mesh_query_point_no_sign(mesh, p[i], 1.0e30)
        out[i] = 1.0e30
        if q.result:
            out[i] = wp.length(p[i] - wp.mesh_eval_position(mesh, q.face, q.u, q.v))

    @wp.kernel
    def rays(
        mesh: wp.uint64, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)
    ):
        i = wp.tid()
        q = wp.mesh_query_ray(mesh, o[i], d[i], 1.0e30)
        out[i] = 1.0e30
        if q.result:
            out[i] = q.t

    @wp.kernel
    def aabb(
        bvh: wp.uint64, lo: wp.array(dtype=wp.vec3), hi: wp.array(dtype=wp.vec3), out: wp.array(dtype=int)
    ):
        i = wp.tid()
        q = wp.bvh_query_aabb(bvh, lo[i], hi[i])
        k = wp.int32(0)
        c = wp.int32(0)
        while wp.bvh_query_next(q, k):
            c += 1
        out[i] = c

    return wp, closest, rays, aabb


def measure_warp(v, f, p, o, d, qlo, qhi, window: float) -> dict:
    wp, k_closest, k_rays, k_aabb = warp_kernels()
    sync = lambda: (wp.synchronize(), time.perf_counter())[1]  # noqa: E731
    dev = "cpu"
    pts = wp.array(v, dtype=wp.vec3, device=dev)
    idx = wp.array(f.ravel(), dtype=int, device=dev)
    lo, hi = boxes(v, f)
    lows, ups = wp.array(lo, dtype=wp.vec3, device=dev), wp.array(hi, dtype=wp.vec3, device=dev)
    arr = {
        n: wp.array(a, dtype=wp.vec3, device=dev)
        for n, a in (("p", p), ("o", o), ("d", d), ("lo", qlo), ("hi", qhi))
    }
    q = len(p)
    dist = wp.zeros(q, dtype=float, device=dev)
    hit_t = wp.zeros(q, dtype=float, device=dev)
    counts = wp.zeros(q, dtype=int, device=dev)
    r: dict = {}
    holder: dict = {}

    def build_mesh():
        holder["mesh"] = wp.Mesh(points=pts, indices=idx)

    def build_bvh(kind=None):
        holder["bvh"] = wp.Bvh(lows, ups, constructor=kind)

    _, r["mesh_build"] = first_then_timed(build_mesh, window, sync)
    _, r["bvh_build_median"] = first_then_timed(lambda: build_bvh("median"), window, sync)
    _, r["bvh_build"] = first_then_timed(build_bvh, window, sync)
    mesh, bvh = holder["mesh"], holder["bvh"]
    _, r["mesh_refit"] = first_then_timed(mesh.refit, window, sync)
    _, r["bvh_refit"] = first_then_timed(bvh.refit, window, sync)
    launch = lambda k, inputs: wp.launch(k, dim=q, inputs=inputs, device=dev)  # noqa: E731
    r["compile_closest"], r["closest"] = first_then_timed(
        lambda: launch(k_closest, [mesh.id, arr["p"], dist]), window, sync
    )
    r["compile_ray"], r["ray"] = first_then_timed(
        lambda: launch(k_rays, [mesh.id, arr["o"], arr["d"], hit_t]), window, sync
    )
    r["compile_box"], r["box"] = first_then_timed(
        lambda: launch(k_aabb, [bvh.id, arr["lo"], arr["hi"], counts]), window, sync
    )
    for k in ("closest", "ray", "box"):
        r[k] /= q  # seconds per query
    r["dist"], r["t"], r["counts"] = dist.numpy(), hit_t.numpy(), counts.numpy()
    return r


# ---------------------------------------------------------------------------------------------------------
# one size and scene


def measure_ours(v, f, p, o, d, qlo, qhi, window: float, brute_ok: bool) -> dict:
    n, q = len(f), len(p)
    lo, hi = boxes(v, f)
    r: dict = {"box": {}, "build": {}, "refit": {}, "compile": {}}
    counter = BoxCount(q)
    counter.lo.from_numpy(qlo)
    counter.hi.from_numpy(qhi)
    counts = {}
    for method in BOX_METHODS:
        if method == "brute" and not brute_ok:
            continue
        tree = {"brute": BruteBoxes, "grid": TriGrid, "octree": Octree, "bvh": BVH}[method](n)
        tree.prim_lo.from_numpy(lo)
        tree.prim_hi.from_numpy(hi)
        r["compile"][f"{method} build"], r["build"][method] = first_then_timed(
            lambda t=tree: t.build(n), window
        )
        r["compile"][f"{method} refit"], r["refit"][method] = first_then_timed(tree.refit, window)
        qq = q if method != "brute" else min(q, max(1, int(BRUTE_WORK // n)))
        r["compile"][f"{method} box query"], t = first_then_timed(
            lambda t=tree, qq=qq: counter.run(t, qq, False), window
        )
        r["box"][method] = t / qq
        counts[method] = counter.count.to_numpy()[:qq]
        if method == "bvh":
            r["bvh_cost_ratio_after_build"] = tree.cost_ratio()
            bvh = tree
    ref = counts["bvh"]
    r["box_counts_agree"] = all(np.array_equal(c, ref[: len(c)]) for c in counts.values())
    r["box_counts"] = ref
    mesh = TriangleMesh(v, f)
    r["compile"]["mesh refit"], r["refit"]["mesh (face boxes + bvh)"] = first_then_timed(mesh.refit, window)
    mp = MeshPass(mesh, p, o, d)
    for serial in (False, True):
        tag = " (1 thread)" if serial else ""
        r["compile"]["closest" + tag], t = first_then_timed(lambda s=serial: mp.closest(q, s), window)
        r["closest" + tag] = t / q
        r["compile"]["ray" + tag], t = first_then_timed(lambda s=serial: mp.rays(q, s), window)
        r["ray" + tag] = t / q
    r["compile"]["bvh box query (1 thread)"], t = first_then_timed(lambda: counter.run(bvh, q, True), window)
    r["box (1 thread)"] = t / q
    r["dist"] = mp.dist.to_numpy()
    r["t"] = mp.t.to_numpy()
    if brute_ok or n * q <= 100 * BRUTE_WORK:
        bm = BruteMesh(mesh)
        qq = min(q, max(1, int(BRUTE_WORK // n)))
        out = np.zeros(qq, np.float32)
        r["compile"]["brute closest"], t = first_then_timed(lambda: bm.closest(p[:qq], out), window)
        r["brute_closest"] = t / qq
        r["brute_dist_agree"] = bool(np.allclose(out, r["dist"][:qq], rtol=1e-5, atol=1e-6))
        r["compile"]["brute ray"], t = first_then_timed(lambda: bm.rays(o[:qq], d[:qq], out), window)
        r["brute_ray"] = t / qq
    return r


def measure(n: int, scene: str, window: float) -> dict:
    init("f32", offline_cache=False)
    rng = np.random.default_rng(SEED)
    v, f = sheet(n) if scene == "sheet" else soup(n, rng)
    n = len(f)
    q = min(n, MAX_QUERIES)
    p, o, d, qlo, qhi = queries(v, f, q, rng)
    log(f"{scene} N={n}: ours")
    ours = measure_ours(v, f, p, o, d, qlo, qhi, window, brute_ok=n * q <= 30 * BRUTE_WORK)
    log(f"{scene} N={n}: warp")
    warp = measure_warp(v, f, p, o, d, qlo, qhi, window)
    fin = np.isfinite(ours["t"]) & (ours["t"] < 1e29) & (warp["t"] < 1e29)
    check = {
        "box counts: all methods equal": ours["box_counts_agree"],
        "box counts equal Warp's bvh_query_aabb": bool(np.array_equal(ours["box_counts"], warp["counts"])),
        "closest distance = Warp's (rtol 1e-5)": bool(
            np.allclose(ours["dist"], warp["dist"], rtol=1e-5, atol=1e-6)
        ),
        "ray hits: same rays hit as Warp": bool(np.array_equal(ours["t"] < 1e29, warp["t"] < 1e29)),
        "ray t = Warp's (rtol 1e-4)": bool(np.allclose(ours["t"][fin], warp["t"][fin], rtol=1e-4, atol=1e-6)),
    }
    if "brute_dist_agree" in ours:
        check["closest distance = brute force"] = ours["brute_dist_agree"]
    for k in ("dist", "t", "box_counts"):
        ours.pop(k)
    for k in ("dist", "t", "counts"):
        warp.pop(k)
    res = {
        "n": n,
        "scene": scene,
        "queries": q,
        "vertices": len(v),
        "ours": ours,
        "warp": warp,
        "check": check,
    }
    log(f"{scene} N={n}: " + ", ".join(f"{k} {'ok' if ok else 'DIFFERS'}" for k, ok in check.items()))
    return res


# ---------------------------------------------------------------------------------------------------------
# refit against rebuild


def deform_run(n: int, scene: str, window: float) -> list[dict]:
    """Frames of a deforming mesh: one tree built on the rest shape and refit each frame, one rebuilt
    each frame; their box queries are timed alternately (so load changes hit both alike)."""
    init("f32", offline_cache=False)
    rng = np.random.default_rng(SEED + 1)
    v, f = sheet(n) if scene == "sheet" else soup(n, rng)
    n = len(f)
    q = min(n, MAX_QUERIES)
    sel = rng.integers(0, n, q)
    refit_tree, fresh, counter = BVH(n), BVH(n), BoxCount(q)
    lo, hi = boxes(v, f)
    refit_tree.prim_lo.from_numpy(lo)
    refit_tree.prim_hi.from_numpy(hi)
    refit_tree.build(n)
    walk = np.zeros((n, 1, 3), np.float32)
    rows = []
    for frame in range(DEFORM_FRAMES + 1):
        if scene == "sheet":
            vf = sheet(n, amplitude=0.04 * frame, rng=np.random.default_rng(SEED + 2))[0]
        else:
            vf = (v.reshape(n, 3, 3) + walk).reshape(-1, 3)
            walk += (0.01 * rng.normal(size=walk.shape)).astype(np.float32)
        lo, hi = boxes(vf, f)
        counter.lo.from_numpy(lo[sel] - GROW)
        counter.hi.from_numpy(hi[sel] + GROW)
        for tree in (refit_tree, fresh):
            tree.prim_lo.from_numpy(lo)
            tree.prim_hi.from_numpy(hi)
        t_refit = timed(refit_tree.refit, window)
        t_build = timed(lambda: fresh.build(n), window)
        counter.run(refit_tree, q, False)
        c_refit = counter.count.to_numpy().copy()
        counter.run(fresh, q, False)
        same = bool(np.array_equal(c_refit, counter.count.to_numpy()))
        ta_, tb_ = [], []
        while len(ta_) < 3 or sum(ta_) + sum(tb_) < window:
            for tree, acc in ((refit_tree, ta_), (fresh, tb_)):
                a = clock()
                counter.run(tree, q, False)
                acc.append(clock() - a)
        rows.append(
            {
                "frame": frame,
                "ratio": refit_tree.cost_ratio(),
                "refit": t_refit,
                "build": t_build,
                "q_refit": statistics.median(ta_) / q,
                "q_fresh": statistics.median(tb_) / q,
                "counts_equal": same,
                "n": n,
                "scene": scene,
            }
        )
        d = rows[-1]
        log(
            f"deform {scene} frame {frame}: ratio {d['ratio']:.2f}, "
            f"query refit/fresh {d['q_refit'] / d['q_fresh']:.2f}"
        )
    return rows


# ---------------------------------------------------------------------------------------------------------
# analysis


def fit(xs, ys) -> float:
    """Least-squares slope of log t against log N."""
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0]) if len(xs) >= 2 else float("nan")


def crossover(ns, ta_, tb) -> float | None:
    """N where ta_ == tb (ta_ faster below), log-log interpolation between the bracketing sizes."""
    f = [math.log(a / b) for a, b in zip(ta_, tb, strict=True)]
    for i in range(len(f) - 1):
        if f[i] <= 0.0 < f[i + 1]:
            l0, l1 = math.log(ns[i]), math.log(ns[i + 1])
            return math.exp(l0 + (l1 - l0) * (-f[i]) / (f[i + 1] - f[i]))
    return None


def step_cost(r: dict, method: str, rebuild: bool) -> float | None:
    """Seconds of one self-contact step over N boxes: a build (or refit) plus N box queries."""
    o = r["ours"]
    if method not in o["box"]:
        return None
    prep = o["build" if rebuild else "refit"][method]
    return prep + r["n"] * o["box"][method]


def crossovers(results, scene) -> dict:
    rs = [r for r in results if r["scene"] == scene]
    out = {}
    for rebuild in (True, False):
        for other in ("grid", "octree", "bvh"):
            pairs = [(r["n"], step_cost(r, "brute", rebuild), step_cost(r, other, rebuild)) for r in rs]
            pairs = [p for p in pairs if p[1] is not None and p[2] is not None]
            ns = [p[0] for p in pairs]
            c = crossover(ns, [p[1] for p in pairs], [p[2] for p in pairs]) if pairs else None
            below = bool(pairs) and pairs[0][1] > pairs[0][2]
            key = f"brute~{other} ({'build' if rebuild else 'refit'} + N queries)"
            out[key] = {"n": c, "sizes": ns, "other_faster_at_smallest": below}
    return out


def cross_text(c) -> str:
    if c["n"] is not None:
        return f"**{c['n']:.3g}**"
    if not c["sizes"]:
        return "not measured"
    if c["other_faster_at_smallest"]:
        return f"below {c['sizes'][0]} (brute force slower at every size measured)"
    return f"above {c['sizes'][-1]} (brute force faster at every size measured)"


def select_constants(results) -> dict:
    """The cost model of `spatial/select.py` fitted to this run: brute force costs Q N t_test, the BVH
    t_fixed + N t_box (build) + Q t_query; and the N where they meet with Q = N."""
    rs = [r for r in results if "brute" in r["ours"]["box"]]
    t_test = statistics.median(r["ours"]["box"]["brute"] / r["n"] for r in rs if r["n"] >= 3000)
    smallest = min(r["n"] for r in results)
    t_fixed = min(r["ours"]["build"]["bvh"] for r in results if r["n"] == smallest)
    mid = [r for r in results if 1000 <= r["n"] <= 100_000]
    t_box = statistics.median((r["ours"]["build"]["bvh"] - t_fixed) / r["n"] for r in mid)
    t_query = statistics.median(r["ours"]["box"]["bvh"] for r in results if r["n"] <= 10_000)
    b = t_box + t_query
    n_cross = (b + math.sqrt(b * b + 4.0 * t_test * t_fixed)) / (2.0 * t_test)
    return {
        "BRUTE_TEST_S": t_test,
        "BVH_BUILD_FIXED_S": t_fixed,
        "BVH_BUILD_PER_BOX_S": t_box,
        "BVH_QUERY_S": t_query,
        "CROSSOVER_N (Q = N)": n_cross,
    }


def rebuild_threshold(rows) -> dict:
    """Per scene: the smallest cost ratio at which rebuilding pays with N queries per step, i.e.
    N (q_refit - q_fresh) > build - refit."""
    out = {}
    for scene in sorted({r["scene"] for r in rows}):
        rs = [r for r in rows if r["scene"] == scene]
        pays = [r for r in rs if r["n"] * (r["q_refit"] - r["q_fresh"]) > r["build"] - r["refit"]]
        out[scene] = min((r["ratio"] for r in pays), default=None)
    return out


# ---------------------------------------------------------------------------------------------------------
# writing


def tables(results, deform, cross, threshold, constants) -> str:
    us = lambda s: f"{s * 1e6:.3g}"  # noqa: E731
    size_rows, query_rows, box_rows, check_rows, compile_rows = [], [], [], [], []
    for r in results:
        o, w = r["ours"], r["warp"]
        b, rf = o["build"], o["refit"]
        size_rows.append(
            [
                r["scene"],
                f"{r['n']:.0e}",
                fmt_s(b["bvh"]),
                fmt_s(rf["mesh (face boxes + bvh)"]),
                fmt_s(b["octree"]),
                fmt_s(b["grid"]),
                fmt_s(w["mesh_build"]),
                fmt_s(w["bvh_build"]),
                fmt_s(w["bvh_build_median"]),
                fmt_s(w["mesh_refit"]),
                fmt_s(w["bvh_refit"]),
                f"{w['bvh_build'] / b['bvh']:.2g}",
                f"{w['mesh_refit'] / rf['mesh (face boxes + bvh)']:.2g}",
            ]
        )
        box = o["box"]
        query_rows.append(
            [r["scene"], f"{r['n']:.0e}", r["queries"]]
            + [
                x
                for k in ("closest", "ray")
                for x in (
                    us(o[k]),
                    us(o[k + " (1 thread)"]),
                    us(w[k]),
                    f"{w[k] / o[k + ' (1 thread)']:.2g}",
                    us(o.get("brute_" + k, float("nan"))),
                )
            ]
        )
        box_rows.append(
            [r["scene"], f"{r['n']:.0e}", r["queries"], us(box["bvh"]), us(o["box (1 thread)"]), us(w["box"])]
            + [f"{w['box'] / o['box (1 thread)']:.2g}", us(box["octree"]), us(box["grid"])]
            + [us(box.get("brute", float("nan")))]
        )
        check_rows.append(
            [r["scene"], f"{r['n']:.0e}"] + ["yes" if v else "**NO**" for v in r["check"].values()]
        )
        compile_rows.append(
            [r["scene"], f"{r['n']:.0e}"]
            + [", ".join(f"{k} {fmt_s(v)}" for k, v in o["compile"].items())]
            + [", ".join(f"{k} {fmt_s(w['compile_' + k])}" for k in ("closest", "ray", "box"))]
        )
    slope_rows = []
    for scene in ("sheet", "soup"):
        rs = [r for r in results if r["scene"] == scene and r["n"] >= 1000]
        ns = [r["n"] for r in rs]
        get = {
            "bvh build": lambda r: r["ours"]["build"]["bvh"],
            "bvh refit (mesh)": lambda r: r["ours"]["refit"]["mesh (face boxes + bvh)"],
            "bvh closest / query": lambda r: r["ours"]["closest"],
            "bvh ray / query": lambda r: r["ours"]["ray"],
            "bvh box / query": lambda r: r["ours"]["box"]["bvh"],
            "octree build": lambda r: r["ours"]["build"]["octree"],
            "octree box / query": lambda r: r["ours"]["box"]["octree"],
            "warp mesh build": lambda r: r["warp"]["mesh_build"],
            "warp closest / query": lambda r: r["warp"]["closest"],
            "warp box / query": lambda r: r["warp"]["box"],
        }
        slope_rows += [[scene, k, f"{fit(ns, [g(r) for r in rs]):.2f}"] for k, g in get.items()]
    deform_rows = [
        [
            d["scene"],
            f"{d['n']:.0e}",
            d["frame"],
            f"{d['ratio']:.2f}",
            fmt_s(d["refit"]),
            fmt_s(d["build"]),
            us(d["q_refit"]),
            us(d["q_fresh"]),
            f"{d['q_refit'] / d['q_fresh']:.2f}",
            f"{(d['build'] - d['refit']) / max(d['q_refit'] - d['q_fresh'], 1e-12):.3g}",
            "yes" if d["counts_equal"] else "**NO**",
        ]
        for d in deform
    ]
    return (
        "## Build and refit\n\n"
        + md_table(
            [
                "scene",
                "N",
                "bvh build",
                "bvh refit (mesh)",
                "octree build",
                "grid build",
                "warp Mesh build (sah)",
                "warp Bvh build (sah)",
                "warp Bvh build (median)",
                "warp Mesh refit",
                "warp Bvh refit",
                "warp Bvh sah / ours build",
                "warp / ours refit",
            ],
            size_rows,
        )
        + "\n\n## Mesh queries (µs per query; 'warp / ours' compares one thread with one thread, > 1: ours "
        "faster)\n\n"
        + md_table(
            ["scene", "N", "Q"]
            + [
                f"{k}: {m}"
                for k in ("closest", "ray")
                for m in ("bvh", "bvh 1 thread", "warp", "warp / ours", "brute")
            ],
            query_rows,
        )
        + "\n\n## Box overlap queries (µs per query)\n\n"
        + md_table(
            [
                "scene",
                "N",
                "Q",
                "bvh",
                "bvh 1 thread",
                "warp Bvh",
                "warp / ours (1 thread each)",
                "octree",
                "grid",
            ]
            + ["brute"],
            box_rows,
        )
        + "\n\n## Crossovers (self-contact step: build or refit + one box query per primitive)\n\n"
        + md_table(
            ["scene", "brute force against", "crossover N"],
            [[s, k, cross_text(c)] for s, cs in cross.items() for k, c in cs.items()],
        )
        + "\n\nCost model of `spatial/select.py` fitted to this run (brute force: Q N BRUTE_TEST_S; BVH: "
        "BVH_BUILD_FIXED_S + N BVH_BUILD_PER_BOX_S + Q BVH_QUERY_S; brute force where it is cheaper), "
        "against the constants in the engine at the time of the run:\n\n"
        + md_table(
            ["constant", "fitted here", "in select.py"],
            [
                [k, f"{v:.3g}", f"{getattr(select_module, k.split(' ')[0], float('nan')):.3g}"]
                for k, v in constants.items()
            ],
        )
        + "\n\n## Slopes (d log t / d log N over N >= 10^3)\n\n"
        + md_table(["scene", "figure", "slope"], slope_rows)
        + "\n\n## Refit or rebuild\n\nEach frame refits the tree built on the rest shape; 'break-even Q' "
        "is the number of box queries per step above which a rebuild pays: (build - refit) / (query on the "
        "refit tree - query on a fresh tree). Smallest cost ratio at which a rebuild pays with N queries per "
        "step: "
        + ", ".join(f"{s} {f'{t:.2f}' if t else 'never in these frames'}" for s, t in threshold.items())
        + f"; `REBUILD_RATIO` in the engine at the time of the run: {lbvh_module.REBUILD_RATIO}.\n\n"
        + md_table(
            [
                "scene",
                "N",
                "frame",
                "cost ratio",
                "refit",
                "rebuild",
                "box query, refit tree [µs]",
                "fresh tree [µs]",
                "slowdown",
                "break-even Q",
                "same counts",
            ],
            deform_rows,
        )
        + "\n\n## Checks\n\n"
        + md_table(["scene", "N"] + list(results[0]["check"].keys()), check_rows)
        + "\n\n## JIT compile (first call minus a steady call; offline cache off)\n\n"
        + md_table(["scene", "N", "taichi_anim", "warp (kernel cache on disk)"], compile_rows)
        + "\n"
    )


def plot(results, deform, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    for scene, ls in (("sheet", "-"), ("soup", "--")):
        rs = [r for r in results if r["scene"] == scene]
        ns = [r["n"] for r in rs]
        a = axes[0]
        a.plot(ns, [r["ours"]["build"]["bvh"] for r in rs], "o" + ls, color="C0", label=f"bvh build, {scene}")
        a.plot(
            ns,
            [r["ours"]["refit"]["mesh (face boxes + bvh)"] for r in rs],
            "s" + ls,
            color="C1",
            label=f"bvh refit, {scene}",
        )
        a.plot(
            ns, [r["warp"]["mesh_build"] for r in rs], "^" + ls, color="C3", label=f"warp Mesh build, {scene}"
        )
        a.plot(
            ns, [r["warp"]["mesh_refit"] for r in rs], "v" + ls, color="C4", label=f"warp Mesh refit, {scene}"
        )
        a = axes[1]
        for key, color, name in (("closest", "C0", "closest"), ("ray", "C2", "ray")):
            a.plot(ns, [r["ours"][key] for r in rs], "o" + ls, color=color, label=f"{name} bvh, {scene}")
            a.plot(
                ns,
                [r["warp"][key] for r in rs],
                "^" + ls,
                color=color,
                alpha=0.5,
                label=f"{name} warp, {scene}",
            )
        a = axes[2]
        for m, color in (("bvh", "C0"), ("octree", "C1"), ("grid", "C2"), ("brute", "C3")):
            pts = [(r["n"], r["ours"]["box"][m]) for r in rs if m in r["ours"]["box"]]
            a.plot(*zip(*pts, strict=True), "o" + ls, color=color, label=f"{m}, {scene}")
        a.plot(ns, [r["warp"]["box"] for r in rs], "^" + ls, color="C4", label=f"warp Bvh, {scene}")
    titles = ("build and refit [s]", "closest point and ray cast [s per query]", "box overlap [s per query]")
    for a, t in zip(axes, titles, strict=True):
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel("triangles N")
        a.set_title(t, fontsize=10)
        a.grid(True, which="both", lw=0.3)
        a.legend(fontsize=6)
    fig.suptitle(
        "Hierarchies over triangles, f32, taichi_anim (2 threads) vs Warp CPU (1 thread), shared 2-core CPU",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    _, out_dir = output_paths(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    window = 0.1 if args.quick else 0.3
    sizes = {
        "sheet": [100, 1000, 10_000] if args.quick else [100, 300, 1000, 3000, 10_000, 100_000, 1_000_000],
        "soup": [1000] if args.quick else [100, 300, 1000, 10_000, 100_000, 1_000_000],
    }
    deform_n = 3000 if args.quick else 100_000
    load_start, engine, other = load_average(), engine_fingerprint(), OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()
    results = [measure(n, scene, window) for scene, ns in sizes.items() for n in ns]
    deform = deform_run(deform_n, "sheet", window) + deform_run(deform_n, "soup", window)
    cross = {s: crossovers(results, s) for s in sizes}
    threshold = rebuild_threshold(deform)
    constants = select_constants(results)
    total = time.perf_counter() - started
    text = (
        "# Hierarchies over triangles: BVH, octree, grid, brute force and Warp\n\n"
        f"Regenerate: `{command_line(args, 'bvh.py')}` (took {total / 60:.1f} min). Scenes, queries and "
        "timing as in the docstring of `benchmarks/bvh.py`: f32, Taichi on 2 threads, Warp on 1 (its CPU "
        f"kernels are serial); Q = min(N, {MAX_QUERIES}) queries of each kind; brute force over at most "
        f"{BRUTE_WORK:.0e} query-box tests per pass (per-query times from a prefix of the queries). "
        "\n\n"
        + machine_table(
            machine_info(),
            load_start=load_start,
            load_end=load_average(),
            date=date,
            engine=engine,
            other=other,
        )
        + "\n\n![bvh](bvh.png)\n\n"
        + tables(results, deform, cross, threshold, constants)
    )
    (out_dir / "bvh.md").write_text(text)
    (out_dir / "bvh.json").write_text(
        json.dumps(
            {
                "sizes": sizes,
                "results": results,
                "deform": deform,
                "crossovers": cross,
                "rebuild_threshold": threshold,
                "select_constants": constants,
                "machine": machine_info(),
            },
            indent=1,
            default=str,
        )
    )
    plot(results, deform, out_dir / "bvh.png")
    log(f"wrote {out_dir}/bvh.md, .json, .png in {total / 60:.1f} min")


if __name__ == "__main__":
    main()
