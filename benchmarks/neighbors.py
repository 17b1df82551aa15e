"""Neighbour search: brute force against the bounded grid and the hashed grid, N = 10^3 ... 10^6, with the
log-log slopes and the crossover N below which brute force is faster (`CROSSOVER_N` in
taichi_anim/collision/neighbors.py).

Scene (every N): N points drawn uniformly (seed 0) in the cube [0, L]^3 with the query radius r = 0.01 m and
L = r (N (4/3) pi / 8)^(1/3), so the expected number of neighbours within r of a point is 8 away from the
walls (the measured mean, lower near the walls at small N, is reported): the density of contact
candidates in a sphere pile, where 2 x sphere radius is the query radius. Precision f32 (the engine's
default), Taichi on the CPU with its default thread count.

Structures: `make_neighbor_search(N, r, domain=((0,0,0), (L,L,L)), method="grid")`, `method="hash_grid"`
(no domain) and `method="brute"`. Measured per N and method, each in the same `ta.init` (one per N):
  build: `ns.build(x)` (x a Vector field of N positions);
  query: one pass in which every particle visits its neighbours within r with `ns.for_each_neighbor` and
         sums a count and the weight 1 - d^2 / r^2 (`QueryPass` below: one kernel, a loop over particles).
The query loop follows the engine's rule for particle loops (`taichi_anim.runtime.serial_loops`: serial
below `CPU_SERIAL_BELOW` particles, else parallel); up to 3 x 10^4 particles it is also timed both ways.
The pass takes particles in index order (random in space); for the grids it is also timed in slot order
(cell by cell through `ns.sorted_id`, as the sphere solver's sweeps run), which isolates memory locality.
Every method must find the same number of (ordered) pairs; the weight sums must agree to float tolerance.

Timing: the first build and query of each structure run on 1 particle (this compiles the kernels; the
offline cache is off, so the time is a real compile, reported apart); then each call is repeated with
`ti.sync()` before every clock read until about `window` seconds are spent (at least 3 calls, except a
single call for a brute-force pass longer than 5 s), and the median is reported. Brute force runs while
its predicted pass (the last one scaled by (N'/N)^2) stays under 20 s; beyond, its figures are
extrapolated from the least-squares fit and marked so. The crossover is where brute force's build + query
time equals the grid's, by linear interpolation of log(time ratio) against log N between the two measured
sizes that bracket it (sizes 10^2 and 3 x 10^2 are added below the measured range for that purpose only;
the slopes are fitted over N >= 10^3).

    .venv/bin/python benchmarks/neighbors.py           # full run (~5 min), writes benchmarks/results/
    .venv/bin/python benchmarks/neighbors.py --quick   # smoke run (~1 min), writes benchmarks/out/
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

from taichi_anim.collision import neighbors as nb
from taichi_anim.runtime import CPU_SERIAL_BELOW, serial_loops

RADIUS = 0.01  # [m] query radius (= cell size of the grids)
MEAN_NEIGHBORS = 8.0  # expected neighbours within RADIUS away from the walls
SEED = 0
METHODS = ("brute", "grid", "hash_grid")
BRUTE_LIMIT = 20.0  # [s] largest predicted brute-force query pass that is still run
LONG_CALL = 5.0  # [s] a call longer than this is timed once
BOTH_LOOPS_UP_TO = 30_000  # query also timed serial and parallel up to this N
FIT_FROM = 1000  # slopes are fitted over N >= this


def box_side(n: int) -> float:
    """Side L [m] of the cube holding n points at MEAN_NEIGHBORS expected neighbours within RADIUS."""
    return RADIUS * (n * (4.0 / 3.0) * math.pi / MEAN_NEIGHBORS) ** (1.0 / 3.0)


def points(n: int) -> np.ndarray:
    rng = np.random.default_rng(SEED)
    return (rng.random((n, 3)) * box_side(n)).astype(np.float32)


@ti.data_oriented
class QueryPass:
    """Per particle i: count[i] = neighbours j != i within RADIUS, weight[i] = sum of 1 - d^2 / r^2."""

    def __init__(self, ns, x, n: int):
        self.ns = ns
        self.x = x
        self.count = ti.field(ti.i32, n)
        self.weight = ti.field(ti.f32, n)
        self.inv_r2 = 1.0 / (RADIUS * RADIUS)

    @ti.func
    def visit(self, i, k, ret: ti.template()):
        if self.ns.sorted_id[k] != i:
            d = self.ns.sorted_x[k] - self.x[i]
            ret += ti.Vector([1.0, 1.0 - d.norm_sqr() * self.inv_r2])

    @ti.kernel
    def run(self, n: ti.i32, serial: ti.template(), slot_order: ti.template()):
        ti.loop_config(serialize=serial)
        for s in range(n):
            # Particle order (random in space) by default; slot order visits them cell by cell.
            i = s
            if ti.static(slot_order):
                i = self.ns.sorted_id[s]
            acc = ti.Vector([0.0, 0.0])
            self.ns.for_each_neighbor(i, self.x[i], RADIUS, self.visit, acc)
            self.count[i] = ti.cast(acc[0], ti.i32)
            self.weight[i] = acc[1]


def timed(fn, window: float) -> tuple[float, list[float]]:
    """Median seconds per call of fn() (synchronised), repeated as the module docstring says."""
    times: list[float] = []
    while True:
        a = clock()
        fn()
        times.append(clock() - a)
        total = sum(times)
        if times[0] > LONG_CALL:
            break
        if len(times) >= 3 and total >= window:
            break
        if len(times) >= 2000:
            break
    return statistics.median(times), times


def measure_size(n: int, methods, window: float, both_loops: bool) -> dict:
    """Build and query times of each method at n points, in one fresh `ta.init`."""
    init("f32", offline_cache=False)
    x_np = points(n)
    x = ti.Vector.field(3, ti.f32, n)
    x.from_numpy(x_np)
    side = box_side(n)
    serial = serial_loops(n)
    out: dict = {"n": n, "box_side": side, "engine_serial": serial, "methods": {}}
    for method in methods:
        domain = ((0.0, 0.0, 0.0), (side, side, side)) if method == "grid" else None
        ns = nb.make_neighbor_search(n, RADIUS, domain=domain, method=method)
        q = QueryPass(ns, x, n)
        # Compile on one particle: the kernels take the count at run time.
        a = clock()
        ns.build(x, count=1)
        b = clock()
        q.run(1, serial, False)
        c = clock()
        modes = [serial] + ([not serial] if both_loops else [])
        compile_query = {"serial" if serial else "parallel": c - b}
        for mode in modes[1:]:
            a2 = clock()
            q.run(1, mode, False)
            compile_query["serial" if mode else "parallel"] = clock() - a2
        t_build, builds = timed(lambda ns=ns: ns.build(x), window)
        r: dict = {
            "describe": ns.describe(),
            "compile_build": b - a,
            "compile_query": compile_query,
            "build": t_build,
            "build_calls": len(builds),
            "query": {},
        }
        for mode in modes:
            t_q, calls = timed(lambda q=q, mode=mode: q.run(n, mode, False), window)
            r["query"]["serial" if mode else "parallel"] = {"time": t_q, "calls": len(calls)}
        if method != "brute":  # brute force's slots are the particles in index order: nothing to compare
            q.run(1, serial, True)
            t_q, calls = timed(lambda q=q: q.run(n, serial, True), window)
            r["query_slot_order"] = {"time": t_q, "calls": len(calls)}
        count = q.count.to_numpy()
        r["pairs"] = int(count.sum(dtype=np.int64))
        r["weight_sum"] = float(q.weight.to_numpy().astype(np.float64).sum())
        r["query_engine"] = r["query"]["serial" if serial else "parallel"]["time"]
        r["total"] = r["build"] + r["query_engine"]
        r["size_after_build"] = int(ns.size[None])
        out["methods"][method] = r
        log(
            f"n={n:.0e} {method:9s} build {fmt_s(r['build'])}, query "
            + ", ".join(f"{k} {fmt_s(v['time'])}" for k, v in r["query"].items())
            + f", pairs {r['pairs']}, compile {fmt_s(r['compile_build'])} + {fmt_s(c - b)}"
        )
    pairs = {m: r["pairs"] for m, r in out["methods"].items()}
    out["pairs_agree"] = len(set(pairs.values())) == 1
    w = [r["weight_sum"] for r in out["methods"].values()]
    out["weight_rel_spread"] = (max(w) - min(w)) / max(abs(max(w)), 1e-30)
    out["mean_neighbors"] = next(iter(pairs.values())) / n
    if not out["pairs_agree"]:
        log(f"PAIR COUNTS DIFFER at n={n}: {pairs}")
    return out


def fit(ns, ts) -> tuple[float, float]:
    """Least-squares log t = a + s log N: returns (slope s, intercept a)."""
    s, a = np.polyfit(np.log(ns), np.log(ts), 1)
    return float(s), float(a)


def crossover(ns, ta_, tb) -> float | None:
    """N where ta_ == tb, by linear interpolation of log(ta_/tb) against log N between the first bracketing
    pair of measured sizes (ta_ faster below it); None if the sign never changes."""
    f = [math.log(a / b) for a, b in zip(ta_, tb, strict=True)]
    for i in range(len(f) - 1):
        if f[i] <= 0.0 < f[i + 1]:
            l0, l1 = math.log(ns[i]), math.log(ns[i + 1])
            return math.exp(l0 + (l1 - l0) * (-f[i]) / (f[i + 1] - f[i]))
    return None


SPHERE_QUERIES = 5  # queries per build in the sphere solver: 4 projection sweeps (its default) + 1 velocity
CROSS_KEYS = ("total", "parallel", "serial", "best", "sweeps")


def cost(m, key):
    """Seconds of one build plus the query work `key` names, or None where it was not measured:
    total = one query in the engine's loop mode; parallel / serial = one query in that mode; best = one
    query in the faster mode; sweeps = SPHERE_QUERIES queries in the engine's loop mode."""
    if m is None:
        return None
    q = m["query"]
    if key == "total":
        return m["build"] + m["query_engine"]
    if key in ("parallel", "serial"):
        return m["build"] + q[key]["time"] if key in q else None
    if key == "best":
        return m["build"] + min(v["time"] for v in q.values())
    if key == "sweeps":
        return m["build"] + SPHERE_QUERIES * m["query_engine"]
    raise ValueError(key)


def series(results, method, key):
    """(N, time) for the sizes where `method` ran; key = build | query | total | serial | parallel."""
    xs, ys = [], []
    for r in results:
        m = r["methods"].get(method)
        if m is None:
            continue
        if key == "slot_order":
            if "query_slot_order" not in m:
                continue
            y = m["query_slot_order"]["time"]
        elif key in ("serial", "parallel"):
            if key not in m["query"]:
                continue
            y = m["query"][key]["time"]
        else:
            y = m["query_engine"] if key == "query" else m[key]
        xs.append(r["n"])
        ys.append(y)
    return xs, ys


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    _, fig_dir = output_paths(args)
    fig_dir.mkdir(parents=True, exist_ok=True)
    if args.quick:
        sizes = [10**2, 3 * 10**2, 10**3, 3 * 10**3, 10**4, 3 * 10**4, 10**5]
        window = 0.2
        brute_limit = 3.0
    else:
        sizes = [10**2, 3 * 10**2, 10**3, 3 * 10**3, 10**4, 3 * 10**4, 10**5, 3 * 10**5, 10**6]
        window = 1.0
        brute_limit = BRUTE_LIMIT
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()

    results = []
    brute_on = True
    for n in sizes:
        methods = [m for m in METHODS if m != "brute" or brute_on]
        res = measure_size(n, methods, window, both_loops=n <= BOTH_LOOPS_UP_TO)
        results.append(res)
        if brute_on:
            b = res["methods"]["brute"]
            nxt = [s for s in sizes if s > n]
            if nxt:
                predicted = b["query_engine"] * (nxt[0] / n) ** 2
                if b["query"].get("parallel"):
                    predicted = min(predicted, b["query"]["parallel"]["time"] * (nxt[0] / n) ** 2)
                if predicted > brute_limit:
                    brute_on = False
                    log(f"brute force stops after n={n:.0e}: next pass predicted {fmt_s(predicted)}")
    total_time = time.perf_counter() - started
    load_end = load_average()

    # slopes over N >= FIT_FROM
    slopes: dict = {}
    fits: dict = {}
    for method in METHODS:
        for key in ("build", "query", "total", "slot_order"):
            xs, ys = series(results, method, key)
            sel = [(a, b) for a, b in zip(xs, ys, strict=True) if a >= FIT_FROM]
            if len(sel) >= 2:
                s, a0 = fit([p[0] for p in sel], [p[1] for p in sel])
                slopes[(method, key)] = s
                fits[(method, key)] = (s, a0, sel[0][0], sel[-1][0])
    # brute force's asymptotic slope: its last three measured sizes
    xs, ys = series(results, "brute", "query")
    brute_tail = fit(xs[-3:], ys[-3:])[0] if len(xs) >= 3 else float("nan")

    cross: dict = {}
    for other_m in ("grid", "hash_grid"):
        for key in CROSS_KEYS:
            db = {r["n"]: cost(r["methods"].get("brute"), key) for r in results}
            dg = {r["n"]: cost(r["methods"].get(other_m), key) for r in results}
            common = sorted(n for n in db if db[n] is not None and dg[n] is not None)
            c = crossover(common, [db[n] for n in common], [dg[n] for n in common])
            cross[(other_m, key)] = {
                "n": c,
                "sizes": common,
                "below": bool(common) and db[common[0]] > dg[common[0]],
            }

    def cross_text(other_m, key):
        c = cross[(other_m, key)]
        if c["n"] is not None:
            return f"**{c['n']:.3g}**"
        if c["below"]:
            return f"below {c['sizes'][0]} (grid already faster at the smallest size measured)"
        return f"above {c['sizes'][-1]} (brute force faster at every size measured)"

    # ---- tables
    main_rows = []
    for r in results:
        for method in METHODS:
            m = r["methods"].get(method)
            if m is None:
                s, a0, lo, hi = fits.get((method, "total"), (float("nan"),) * 4)
                if method == "brute" and s == s:
                    ext = math.exp(a0 + s * math.log(r["n"]))
                    main_rows.append(
                        [f"{r['n']:.0e}", method, "–", "–", f"*{fmt_s(ext)} (extrapolated)*", "–", "–"]
                    )
                continue
            mode = "serial" if r["engine_serial"] else "parallel"
            main_rows.append(
                [
                    f"{r['n']:.0e}",
                    method,
                    fmt_s(m["build"]),
                    f"{fmt_s(m['query_engine'])} ({mode})",
                    fmt_s(m["total"]),
                    f"{m['build_calls']} / {m['query'][mode]['calls']}",
                    m["pairs"],
                ]
            )
    loop_rows = []
    for r in results:
        for method, m in r["methods"].items():
            q = m["query"]
            if "serial" in q and "parallel" in q:
                s_, p_ = q["serial"]["time"], q["parallel"]["time"]
                loop_rows.append(
                    [
                        f"{r['n']:.0e}",
                        method,
                        fmt_s(s_),
                        fmt_s(p_),
                        f"{s_ / p_:.2f}",
                        "serial" if r["engine_serial"] else "parallel",
                    ]
                )
    slot_rows = []
    for r in results:
        for method, m in r["methods"].items():
            if "query_slot_order" in m:
                a_, b_ = m["query_engine"], m["query_slot_order"]["time"]
                slot_rows.append([f"{r['n']:.0e}", method, fmt_s(a_), fmt_s(b_), f"{a_ / b_:.2f}"])
    check_rows = [
        [
            f"{r['n']:.0e}",
            f"{r['box_side']:.4g}",
            ", ".join(f"{k} {v['pairs']}" for k, v in r["methods"].items()),
            "yes" if r["pairs_agree"] else "**NO**",
            f"{r['weight_rel_spread']:.1e}",
            f"{r['mean_neighbors']:.2f}",
        ]
        for r in results
    ]
    compile_rows_ = []
    for r in results:
        for method, m in r["methods"].items():
            compile_rows_.append(
                [
                    f"{r['n']:.0e}",
                    method,
                    fmt_s(m["compile_build"]),
                    ", ".join(f"{k} {fmt_s(v)}" for k, v in m["compile_query"].items()),
                ]
            )
    slope_rows = []
    for method in METHODS:
        row = [method]
        for key in ("build", "query", "total"):
            f = fits.get((method, key))
            row.append(f"{f[0]:.2f} ({f[2]:.0e}..{f[3]:.0e})" if f else "–")
        f = fits.get((method, "slot_order"))
        row.append(f"{f[0]:.2f} ({f[2]:.0e}..{f[3]:.0e})" if f else "same as query")
        slope_rows.append(row)
    brute_sizes = [r["n"] for r in results if "brute" in r["methods"]]
    extrapolated = [r["n"] for r in results if "brute" not in r["methods"]]
    agree_all = all(r["pairs_agree"] for r in results)

    text = (
        "# Neighbour search: brute force against grid\n\n"
        f"Regenerate: `{command_line(args, 'neighbors.py')}` (took {total_time / 60:.1f} min).\n\n"
        f"Settings: float32 (`ta.init('cpu', precision='f32', offline_cache=False)`), one fresh `ta.init` "
        f"per N. Points: N uniform in [0, L]^3 (seed {SEED}), query radius r = {RADIUS} m, "
        f"L = r (N (4/3) pi / {MEAN_NEIGHBORS:g})^(1/3) (expected {MEAN_NEIGHBORS:g} neighbours within r "
        "away from the walls; the measured mean is in the check table). Structures from "
        "`taichi_anim.collision.neighbors.make_neighbor_search(N, r, ...)`: `brute`, `grid` with domain "
        "(0, 0, 0)..(L, L, L) and `hash_grid` (no domain). Build = `ns.build(x)`; query = one pass where "
        "every particle sums a count and 1 - d²/r² over its neighbours within r through "
        "`ns.for_each_neighbor` (`QueryPass` in `benchmarks/neighbors.py`, one kernel); its loop "
        "follows the engine's rule (`taichi_anim.runtime.serial_loops`: serial below CPU_SERIAL_BELOW = "
        f"{CPU_SERIAL_BELOW} particles). "
        f"Each figure is the median of calls repeated for ~{window:g} s (at least 3; one call when a call "
        f"takes over {LONG_CALL:g} s), `ti.sync()` before every clock read, after a first build and query "
        "on 1 particle that holds the JIT compile (reported apart). Brute force ran at N = "
        + ", ".join(f"{n:.0e}" for n in brute_sizes)
        + (
            f" and stopped where its next pass was predicted over {brute_limit:g} s; at N = "
            + ", ".join(f"{n:.0e}" for n in extrapolated)
            + " its figures are **extrapolated** from the least-squares fit (marked so)."
            if extrapolated
            else "."
        )
        + f" `CROSSOVER_N` in the engine at the time of the run: {nb.CROSSOVER_N}; "
        f"`MAX_CELLS_PER_PARTICLE` = {nb.MAX_CELLS_PER_PARTICLE}.\n\n"
        + machine_table(
            machine_info(), load_start=load_start, load_end=load_end, date=date, engine=engine, other=other
        )
        + "\n\n![neighbors](neighbors.png)\n\n"
        "## Crossover and slopes\n\n"
        + md_table(
            [
                "brute force against",
                "crossover N, build + query (engine's loop rule)",
                "query parallel",
                "query serial",
                "query in the faster mode",
                f"build + {SPHERE_QUERIES} queries (engine's loop rule)",
            ],
            [[m] + [cross_text(m, k) for k in CROSS_KEYS] for m in ("grid", "hash_grid")],
        )
        + "\n\nCrossover: N where brute force's build + query time equals the other method's, interpolated "
        "linearly in log N between the two measured sizes bracketing it (brute force faster below). The "
        "loop-mode columns use build + that query mode over the sizes where both modes ran "
        f"(N <= {BOTH_LOOPS_UP_TO}); the last column counts {SPHERE_QUERIES} query passes per build, as the "
        f"sphere solver runs ({SPHERE_QUERIES - 1} projection sweeps, its default, and a velocity sweep).\n\n"
        f"Log-log slopes d log t / d log N, least squares over the measured sizes N >= {FIT_FROM} (range in "
        "brackets):\n\n"
        + md_table(["method", "build", "query", "build + query", "query in slot order"], slope_rows)
        + f"\n\nBrute-force query slope over its last three measured sizes: {brute_tail:.2f}.\n\n"
        "## Times\n\n"
        + md_table(
            [
                "N",
                "method",
                "build",
                "query (loop mode)",
                "build + query",
                "calls timed (build / query)",
                "pairs",
            ],
            main_rows,
        )
        + "\n\nQuery loop serial against parallel (2 threads):\n\n"
        + md_table(["N", "method", "serial", "parallel", "serial / parallel", "engine's choice"], loop_rows)
        + "\n\nQuery in particle (index) order, random in space, against slot order (particles taken cell by "
        "cell through `ns.sorted_id`, as the sphere solver's sweeps do): the difference is memory locality. "
        "Same loop mode as the main table.\n\n"
        + md_table(["N", "method", "particle order", "slot order", "particle / slot"], slot_rows)
        + "\n\n## Checks\n\nPairs are ordered (i, j), i != j, |x_i - x_j| < r; every method must find "
        "the same number, and the total weight sum must agree to float tolerance (summation order differs). "
        + ("All sizes agree." if agree_all else "**Some sizes disagree: see the table.**")
        + "\n\n"
        + md_table(
            ["N", "L [m]", "pairs found", "same count", "weight sum rel. spread", "mean neighbours"],
            check_rows,
        )
        + "\n\n## JIT compile (first build and query, on 1 particle, offline cache off)\n\n"
        "Each structure is a new instance with its own fields, so its kernels compile at every N.\n\n"
        + md_table(["N", "method", "build", "query"], compile_rows_)
        + "\n"
    )
    (fig_dir / "neighbors.md").write_text(text)
    (fig_dir / "neighbors.json").write_text(
        json.dumps(
            {
                "settings": {
                    "radius": RADIUS,
                    "mean_neighbors_target": MEAN_NEIGHBORS,
                    "seed": SEED,
                    "precision": "f32",
                    "sizes": sizes,
                    "window_s": window,
                    "brute_limit_s": brute_limit,
                    "cpu_serial_below": CPU_SERIAL_BELOW,
                    "crossover_n_in_engine": nb.CROSSOVER_N,
                },
                "machine": machine_info(),
                "load": [load_start, load_end],
                "results": results,
                "slopes": {f"{m}/{k}": v for (m, k), v in slopes.items()},
                "brute_query_tail_slope": brute_tail,
                "crossover": {f"brute~{m}/{k}": v for (m, k), v in cross.items()},
            },
            indent=1,
            default=str,
        )
    )
    plot(results, fits, cross, fig_dir / "neighbors.png")
    log(f"crossover brute~grid (build + query): {cross_text('grid', 'total')}")
    log("slopes: " + ", ".join(f"{m}/{k} {v:.2f}" for (m, k), v in slopes.items()))
    log(f"wrote {fig_dir}/neighbors.md, .json, .png in {total_time / 60:.1f} min")


def plot(results, fits, cross, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    colors = {"brute": "C3", "grid": "C0", "hash_grid": "C2"}
    ax = axes[0]
    for method in METHODS:
        xs, ys = series(results, method, "total")
        ax.plot(xs, ys, "-o", color=colors[method], label=f"{method}, build + query")
        f = fits.get((method, "total"))
        if f and method == "brute":
            nmax = max(r["n"] for r in results)
            if nmax > xs[-1]:
                xe = np.geomspace(xs[-1], nmax, 20)
                ax.plot(
                    xe,
                    np.exp(f[1] + f[0] * np.log(xe)),
                    ":",
                    color=colors[method],
                    label=f"brute, extrapolated (slope {f[0]:.2f})",
                )
    c = cross[("grid", "total")]["n"]
    if c is not None:
        ax.axvline(c, color="grey", lw=1, ls="--", label=f"crossover brute/grid N = {c:.3g}")
    ax.set_title("build + one query pass", fontsize=10)
    ax2 = axes[1]
    for method in METHODS:
        for key, style in (("build", "--s"), ("query", "-^")):
            xs, ys = series(results, method, key)
            ax2.plot(xs, ys, style, color=colors[method], label=f"{method}, {key}")
    ax2.set_title("build and query apart", fontsize=10)
    for a in axes:
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel("particles N")
        a.set_ylabel("seconds")
        a.grid(True, which="both", lw=0.3)
        a.legend(fontsize=7)
    fig.suptitle(
        f"Neighbour search, f32, uniform points, ~{MEAN_NEIGHBORS:g} neighbours within r, 2-core CPU",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
