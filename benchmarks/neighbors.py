"""Neighbour search: brute force, the counting-sort grid and the hashed grid at N = 10^2 ... 10^6 points,
build and one query pass, log-log slopes and the crossover N below which brute force wins (the engine's
`CROSSOVER_N`, collision/neighbors.py). Pair counts must agree between the methods.

Scene: N points uniform (seed 0) in a cube sized for 8 expected neighbours within r = 0.01 m (a sphere
pile's density of contact candidates), f32. A pass visits every point's neighbours with
`for_each_neighbor` (index order) and sums a count and the weight 1 - d^2/r^2. Brute force stops once a
pass would take over 20 s.

    .venv/bin/python benchmarks/neighbors.py [--quick]
"""

import math

import numpy as np
import taichi as ti
from harness import Page, clock, fmt_s, init, log, median_time, parse_args

import taichi_anim as ta
from taichi_anim.collision import neighbors as nb

R = 0.01
METHODS = ("brute", "grid", "hash_grid")


def side(n: int) -> float:
    return R * (n * (4 / 3) * math.pi / 8.0) ** (1 / 3)


@ti.data_oriented
class QueryPass:
    def __init__(self, ns, x, n: int):
        self.ns, self.x = ns, x
        self.count = ti.field(ti.i32, n)

    @ti.func
    def visit(self, i, k, ret: ti.template()):
        if self.ns.sorted_id[k] != i:
            d = self.ns.sorted_x[k] - self.x[i]
            ret += ti.Vector([1.0, 1.0 - d.norm_sqr() / R**2])

    @ti.kernel
    def run(self, n: ti.i32):
        for i in range(n):
            acc = ti.Vector([0.0, 0.0])
            self.ns.for_each_neighbor(i, self.x[i], R, self.visit, acc)
            self.count[i] = ti.cast(acc[0], ti.i32)


def measure(n: int, methods, repeats: int) -> dict:
    init("f32")
    x = ti.Vector.field(3, ti.f32, n)
    x.from_numpy((np.random.default_rng(0).random((n, 3)) * side(n)).astype(np.float32))
    out = {}
    for m in methods:
        domain = ((0.0, 0.0, 0.0), (side(n),) * 3) if m == "grid" else None
        ns = ta.make_neighbor_search(n, R, domain=domain, method=m)
        q = QueryPass(ns, x, n)
        a = clock()
        ns.build(x)
        q.run(n)
        first = clock() - a
        build = median_time(lambda ns=ns: ns.build(x), repeats=repeats)
        query = median_time(lambda q=q: q.run(n), repeats=repeats)
        out[m] = {"first": first, "build": build, "query": query, "pairs": int(q.count.to_numpy().sum())}
        log(f"N={n:.0e} {m:9s} build {fmt_s(build)}, query {fmt_s(query)}, pairs {out[m]['pairs']}")
    return out


def crossover(ns, brute, grid) -> float | None:
    """N where brute force's build + query equals the grid's (log-log interpolation)."""
    f = [math.log(b / g) for b, g in zip(brute, grid, strict=False)]
    for i in range(len(f) - 1):
        if f[i] <= 0 < f[i + 1]:
            l0, l1 = math.log(ns[i]), math.log(ns[i + 1])
            return math.exp(l0 + (l1 - l0) * -f[i] / (f[i + 1] - f[i]))
    return None


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    sizes = (
        [10**2, 3 * 10**2, 10**3, 10**4]
        if args.quick
        else [10**k for k in (2, 2.5, 3, 3.5, 4, 4.5, 5, 5.5, 6)]
    )
    sizes = [int(round(s)) for s in sizes]
    results, rows, brute_on = [], [], True
    for n, following in zip(sizes, sizes[1:] + [sizes[-1]], strict=True):
        r = measure(n, [m for m in METHODS if m != "brute" or brute_on], 3 if args.quick else 7)
        brute_on = "brute" in r and (r["brute"]["build"] + r["brute"]["query"]) * (following / n) ** 2 < 20.0
        agree = len({v["pairs"] for v in r.values()}) == 1
        results.append({"n": n, **r})
        total = {m: r[m]["build"] + r[m]["query"] if m in r else None for m in METHODS}
        rows.append(
            [
                n,
                *(fmt_s(total[m]) for m in METHODS),
                f"{r['grid']['pairs'] / n:.2f}",
                "yes" if agree else "**NO**",
            ]
        )
    fits = {}
    for m in METHODS:
        pts = [(r["n"], r[m]["build"] + r[m]["query"]) for r in results if m in r and r["n"] >= 1000]
        if len(pts) >= 2:
            fits[m] = float(np.polyfit(*np.log(np.array(pts)).T, 1)[0])
    both = [r for r in results if "brute" in r]
    total = {m: [r[m]["build"] + r[m]["query"] for r in both] for m in METHODS}
    cross = {m: crossover([r["n"] for r in both], total["brute"], total[m]) for m in ("grid", "hash_grid")}
    slopes = ", ".join(f"{m} {s:.2f}" for m, s in fits.items())
    wins = ", ".join(f"{m} from N = {c:.0f}" if c else f"{m}: not within the sizes" for m, c in cross.items())
    page = Page(
        "neighbors",
        "Neighbour search: brute force, grid, hashed grid",
        args,
        {
            "points": "uniform in a cube with 8 expected neighbours within r = 0.01 m, seed 0, f32",
            "pass": "for_each_neighbor over every point (index order), count + weight",
            "repeats": "median of 3 (--quick) or 7 calls after one warm-up",
            "engine's CROSSOVER_N, CROSSOVER_N_HASHED": f"{nb.CROSSOVER_N}, {nb.CROSSOVER_N_HASHED}",
        },
    )
    page.table(
        "build + one query pass",
        ["N", *METHODS, "neighbours per point", "pairs agree"],
        rows,
        note=f"Log-log slopes (N >= 10^3): {slopes}. Faster than brute force: {wins}.",
    )
    page.plot(
        {
            m: (
                [r["n"] for r in results if m in r],
                [r[m]["build"] + r[m]["query"] for r in results if m in r],
            )
            for m in METHODS
        },
        xlabel="points",
        ylabel="build + query [s]",
    )
    page.write({"sizes": results, "slopes": fits, "crossovers": cross})


if __name__ == "__main__":
    main()
