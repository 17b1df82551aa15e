"""Triangle hierarchies: build, refit and queries of the engine's linear BVH (through `TriangleMesh` for
closest point and ray cast), loose octree, uniform loose grid and brute force, against Warp's `wp.Mesh`
and `wp.Bvh` (peers/warp_bvh.py, CPU, one thread) in the same process, on a cloth-like sheet of
10^3 ... 10^6 triangles. Box-overlap counts must agree between every method and Warp; closest distances
must equal Warp's to f32 tolerance. (The crossovers of `spatial/select.py` and the refit-or-rebuild rule
of `BVH.update` were studies: results/bvh.md.)

Scene: an m x m grid of the unit square (2 m^2 triangles), height 0.05 sin(6x) cos(5y), f32. Queries
(Q = min(N, 10^4)): points in the mesh's box grown 10 % (closest point), rays from such points in random
directions (nearest hit), boxes of random triangles grown by 0.01 m (overlap count, the self-contact
pattern).

    .venv/bin/python benchmarks/bvh.py [--quick]
"""

import math

import numpy as np
import taichi as ti
from harness import Page, clock, fmt_s, init, log, median_time, parse_args, peer, ratio

from taichi_anim.spatial import BVH, BruteBoxes, Octree, TriangleMesh, TriGrid

STRUCTURES = {"bvh": BVH, "octree": Octree, "grid": TriGrid, "brute": BruteBoxes}


def sheet(n: int):
    m = max(1, round(math.sqrt(n / 2)))
    i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
    x, y = i.ravel() / m, j.ravel() / m
    v = np.stack([x, y, 0.05 * np.sin(6 * x) * np.cos(5 * y)], 1)
    k = (i[:-1, :-1] * (m + 1) + j[:-1, :-1]).ravel()
    f = np.concatenate([np.stack([k, k + m + 1, k + 1], 1), np.stack([k + 1, k + m + 1, k + m + 2], 1)])
    return v.astype(np.float32), f.astype(np.int32)


def queries(v, f, q: int):
    rng = np.random.default_rng(0)
    lo, hi = v.min(0), v.max(0)
    pad = 0.1 * (hi - lo).max()
    p, o = (rng.uniform(lo - pad, hi + pad, (q, 3)).astype(np.float32) for _ in range(2))
    d = rng.normal(size=(q, 3)).astype(np.float32)
    t = v[f[rng.integers(0, len(f), q)]]
    return p, o, d, (t.min(1) - 0.01).astype(np.float32), (t.max(1) + 0.01).astype(np.float32)


@ti.data_oriented
class Pass:
    """Q closest points, ray casts and box-overlap counts through the engine's query functions."""

    def __init__(self, mesh, p, o, d, qlo, qhi):
        self.mesh, q = mesh, len(p)
        self.p, self.o, self.d, self.lo, self.hi = (ti.Vector.field(3, ti.f32, q) for _ in range(5))
        for field, a in zip((self.p, self.o, self.d, self.lo, self.hi), (p, o, d, qlo, qhi), strict=True):
            field.from_numpy(a)
        self.dist, self.t, self.count = ti.field(ti.f32, q), ti.field(ti.f32, q), ti.field(ti.i32, q)

    @ti.kernel
    def closest(self, q: ti.i32):
        for i in range(q):
            self.dist[i], _f, _w = self.mesh.closest_point(self.p[i], 1.0e30)

    @ti.kernel
    def rays(self, q: ti.i32):
        for i in range(q):
            self.t[i], _f, _u, _v = self.mesh.ray_cast(self.o[i], self.d[i], 1.0e30)

    @ti.func
    def visit(self, i, prim, ret: ti.template()):
        ret += 1

    @ti.kernel
    def boxes(self, tree: ti.template(), q: ti.i32):
        for i in range(q):
            acc = 0
            tree.for_each_overlap(i, self.lo[i], self.hi[i], self.visit, acc)
            self.count[i] = acc


def measure(n: int, wb, repeats: int) -> dict:
    init("f32")
    v, f = sheet(n)
    n, q = len(f), min(len(f), 10_000)
    p, o, d, qlo, qhi = queries(v, f, q)
    t = v[f]
    mesh = TriangleMesh(v, f)
    ps = Pass(mesh, p, o, d, qlo, qhi)
    r: dict = {"n": n, "q": q}
    a = clock()
    ps.closest(q)
    r["compile closest"] = clock() - a
    r["closest"] = median_time(lambda: ps.closest(q), repeats=repeats) / q
    r["ray"] = median_time(lambda: ps.rays(q), repeats=repeats) / q
    r["mesh refit"] = median_time(mesh.refit, repeats=repeats)
    counts = {}
    for name, cls in STRUCTURES.items():
        if name == "brute" and n * q > 3e8:
            continue
        tree = cls(n)
        tree.prim_lo.from_numpy(t.min(1))
        tree.prim_hi.from_numpy(t.max(1))
        r[f"{name} build"] = median_time(lambda tree=tree: tree.build(n), repeats=repeats)
        r[f"{name} box"] = median_time(lambda tree=tree: ps.boxes(tree, q), repeats=repeats) / q
        counts[name] = ps.count.to_numpy()
    dist, hit = ps.dist.to_numpy(), ps.t.to_numpy()
    r["counts agree"] = all(np.array_equal(c, counts["bvh"]) for c in counts.values())
    if wb is not None:
        w = wb.WarpMesh(v, f, p, o, d, qlo, qhi)
        w.closest()
        r["warp closest"] = median_time(w.closest, repeats=repeats, sync=w.sync) / q
        r["warp ray"] = median_time(w.rays, repeats=repeats, sync=w.sync) / q
        r["warp box"] = median_time(w.boxes, repeats=repeats, sync=w.sync) / q
        r["warp build"] = median_time(w.build, repeats=repeats, sync=w.sync)
        r["warp refit"] = median_time(w.refit, repeats=repeats, sync=w.sync)
        r["counts agree"] &= bool(np.array_equal(w.count.numpy(), counts["bvh"]))
        r["distances agree"] = bool(np.allclose(dist, w.dist.numpy(), rtol=1e-5, atol=1e-6))
        both = (hit < 1e29) & (w.t.numpy() < 1e29)
        r["rays agree"] = bool(np.allclose(hit[both], w.t.numpy()[both], rtol=1e-4, atol=1e-6))
    log(f"N={n}: " + ", ".join(f"{k} {fmt_s(x) if isinstance(x, float) else x}" for k, x in r.items()))
    return r


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    sizes = [10**3, 10**4] if args.quick else [10**3, 10**4, 10**5, 10**6]
    wb = peer("warp_bvh")
    data = [measure(n, wb, 3 if args.quick else 7) for n in sizes]
    page = Page(
        "bvh",
        "Triangle hierarchies against Warp's wp.Mesh / wp.Bvh",
        args,
        {
            "scene": "wavy sheet of the unit square, f32; Q = min(N, 10^4) queries of each kind",
            "threads": "ours: Taichi's default (all cores); Warp: one thread (its CPU kernels)",
            "repeats": "median of 3 (--quick) or 7 calls after one warm-up",
        },
    )
    cols = ["closest", "ray", "box"]
    rows = [
        [
            r["n"],
            *(
                f"{fmt_s(r[ours])} ({ratio(r.get('warp ' + c), r[ours])})"
                for c, ours in zip(cols, ("closest", "ray", "bvh box"), strict=True)
            ),
            fmt_s(r["bvh build"]),
            fmt_s(r.get("warp build")),
            fmt_s(r["mesh refit"]),
            fmt_s(r.get("warp refit")),
            "yes"
            if r["counts agree"] and r.get("distances agree", True) and r.get("rays agree", True)
            else "**NO**",
        ]
        for r in data
    ]
    page.table(
        "Per query (Warp / ours in brackets), build and refit",
        [
            "N",
            "closest point",
            "ray cast",
            "box overlap (BVH)",
            "BVH build",
            "Warp Mesh + Bvh build",
            "mesh refit",
            "Warp refit",
            "agree",
        ],
        rows,
    )
    rows = [
        [r["n"], *(f"{fmt_s(r.get(f'{s} build'))} / {fmt_s(r.get(f'{s} box'))}" for s in STRUCTURES)]
        for r in data
    ]
    page.table("Our structures: build / per box query", ["N", *STRUCTURES], rows)
    page.write(data)


if __name__ == "__main__":
    main()
