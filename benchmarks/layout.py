"""Memory layout, float width and the CPU thread pool, measured on the mass-spring cloth substep.

What: the engine's explicit substep (a spring pass writing each spring's force, then a particle pass
summing its springs over a CSR adjacency with signed spring indices, and symplectic Euler v += h (f/m + g),
x += h v: terms/springs.py `evaluate` + `gather`, integrators/symplectic_euler.py) on Warp's
benchmark_cloth scene (n x n vertices 0.1 m apart, 0.1 kg, two corners pinned, structural + shear + bend
springs of k = 1000 N/m and damping 10 kg/s, sorted by their ends), h = 1/960 s, at 32^2 ... 256^2.
(1) AoS against SoA for the vertex and per-spring force fields, and the spring parameters as the engine's
two vector fields, one packed struct or separate arrays, serialized and parallel; (2) f32 against f64;
(3) the bytes a substep must move (each array once per pass) over its time, against a NumPy copy of
512 MiB and of the working set's size; (4) the thread pool: the fixed cost of a parallel range-for, the
adaptive block size that keeps a loop of < 1024 items on one thread, and a two-worker spin-barrier
persistent kernel against the same substeps serialized in one kernel.

How: one process on the CPU (Taichi re-initialised for f64 and for one thread). Each case is called once
first (JIT or offline-cache load, reported apart) and twice more, then timed in batches with ti.sync()
before every clock read; figures are medians over the batches. Every layout's positions are compared with
the engine layout's after the same substeps, the persistent kernel's with the serialized kernel's.

    .venv/bin/python benchmarks/layout.py          # full run (~1 min): benchmarks/results/layout.{md,json}
    .venv/bin/python benchmarks/layout.py --quick  # smoke run into benchmarks/out/
    .venv/bin/python benchmarks/layout.py --from-json benchmarks/results/layout.json  # page only, no timing
"""

import argparse
import json
import statistics
import time
from pathlib import Path

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
    memory_bandwidth,
    output_paths,
    parse_args,
)

H, G, EPS2 = 1.0 / 960.0, -9.81, 1e-24  # substep [s], gravity [m/s^2], as the engine's spring_force
LAYOUTS = [("AoS", "pair+param"), ("AoS", "packed struct"), ("SoA", "pair+param"), ("SoA", "separate arrays")]
MODE = {True: "serialized", False: "parallel"}  # by the serial flag (also 1 and 0)
CAP = 1 << 20  # spin iterations before a barrier gives up (counted as a stall): nothing can hang
FULL = dict(sizes=(32, 64, 128, 256), repeats=9, loops=(1024, 4096, 16384, 65536, 262144), iters=20000)
QUICK = dict(sizes=(32, 64), repeats=3, loops=(1024, 16384), iters=2000)


def cloth_arrays(n: int) -> dict:
    """Warp's cloth grid: positions (N,3) [m], inverse masses (N,) [1/kg], springs (S,2) sorted by (i, j),
    rest lengths (S,) [m], and the CSR adjacency: start (N+1,), entries +(s+1) / -(s+1) at each end."""
    idx = np.arange(n * n).reshape(n, n)
    gz, gx = np.divmod(idx.ravel(), n)
    x = np.stack([0.1 * gx, np.zeros(n * n), 0.1 * gz], 1)
    pairs = []
    for dz, dx in ((0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0)):  # structural, shear, bend
        lo, hi = max(0, -dx), min(n, n - dx)
        pairs.append(np.stack([idx[: n - dz, lo:hi].ravel(), idx[dz:, lo + dx : hi + dx].ravel()], 1))
    p = np.sort(np.concatenate(pairs), 1)
    p = p[np.lexsort((p[:, 1], p[:, 0]))]
    s = len(p)
    owner, other = np.concatenate([p[:, 0], p[:, 1]]), np.concatenate([p[:, 1], p[:, 0]])
    signed = np.concatenate([np.arange(1, s + 1), -np.arange(1, s + 1)])[np.lexsort((other, owner))]
    start = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=n * n))])
    w = np.full(n * n, 10.0)
    w[[0, n - 1]] = 0.0
    rest = np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=1)
    return dict(x=x, w=w, pairs=p.astype(np.int32), rest=rest, start=start.astype(np.int32), signed=signed)


@ti.data_oriented
class Cloth:
    """The substep on one layout: vertices and forces "AoS" or "SoA"; spring parameters "pair+param",
    "packed struct" (one AoS struct) or "separate arrays" (the struct in SoA)."""

    def __init__(self, n: int, vertex: str, springs: str):
        a = cloth_arrays(n)
        self.n_particles, self.n_springs = len(a["x"]), len(a["pairs"])
        lay = ti.Layout.SOA if vertex == "SoA" else ti.Layout.AOS
        self.x, self.v = (ti.Vector.field(3, float, self.n_particles, layout=lay) for _ in range(2))
        self.f = ti.Vector.field(3, float, self.n_springs, layout=lay)
        self.w, self.start = ti.field(float, self.n_particles), ti.field(ti.i32, self.n_particles + 1)
        self.signed = ti.field(ti.i32, 2 * self.n_springs)
        self.engine_springs = springs == "pair+param"
        k, c = np.full(self.n_springs, 1000.0), np.full(self.n_springs, 10.0)
        if self.engine_springs:
            self.pair = ti.Vector.field(2, ti.i32, self.n_springs)
            self.param = ti.Vector.field(3, float, self.n_springs)
            self.pair.from_numpy(a["pairs"])
            self.param.from_numpy(np.stack([a["rest"], k, c], 1))
        else:
            members = {"i": ti.i32, "j": ti.i32, "rest": float, "k": float, "c": float}
            slay = ti.Layout.SOA if springs == "separate arrays" else ti.Layout.AOS
            self.sp = ti.Struct.field(members, shape=self.n_springs, layout=slay)
            self.sp.from_numpy(dict(i=a["pairs"][:, 0], j=a["pairs"][:, 1], rest=a["rest"], k=k, c=c))
        for field, key in ((self.x, "x"), (self.w, "w"), (self.start, "start"), (self.signed, "signed")):
            field.from_numpy(a[key])
        self.bar, self.zero, self.stalls = (ti.field(ti.i32, ()) for _ in range(3))

    @ti.func
    def spring(self, s):
        """The engine's spring_force (one rsqrt): force on the first end into f[s]."""
        i, j, rest, k, c = 0, 0, 0.0, 0.0, 0.0
        if ti.static(self.engine_springs):
            ij, p = self.pair[s], self.param[s]
            i, j, rest, k, c = ij[0], ij[1], p[0], p[1], p[2]
        else:
            q = self.sp[s]
            i, j, rest, k, c = q.i, q.j, q.rest, q.k, q.c
        d, dv = self.x[i] - self.x[j], self.v[i] - self.v[j]
        nrm = d * ti.rsqrt(ti.max(d.dot(d), EPS2))
        self.f[s] = -(k * (d.dot(nrm) - rest) + c * dv.dot(nrm)) * nrm

    @ti.func
    def particle(self, i, h):
        f = ti.Vector.zero(float, 3)
        for e in range(self.start[i], self.start[i + 1]):
            s = self.signed[e]
            if s > 0:
                f += self.f[s - 1]
            else:
                f -= self.f[-s - 1]
        a = f * self.w[i]
        if self.w[i] > 0:
            a[1] += G
        v = self.v[i] + h * a
        self.v[i] = v
        self.x[i] += h * v

    @ti.kernel
    def substep(self, h: float, serial: ti.template()):
        ti.loop_config(serialize=serial)
        for s in range(self.n_springs):
            self.spring(s)
        ti.loop_config(serialize=serial)
        for i in range(self.n_particles):
            self.particle(i, h)

    @ti.kernel
    def substeps_serial(self, h: float, count: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(count):
            for s in range(self.n_springs):
                self.spring(s)
            for i in range(self.n_particles):
                self.particle(i, h)

    @ti.func
    def barrier(self, target):
        ti.atomic_add(self.bar[None], 1)
        it = 0
        while ti.atomic_or(self.bar[None], self.zero[None]) < target and it < CAP:  # an atomic read
            it += 1
        if it >= CAP:
            ti.atomic_add(self.stalls[None], 1)

    @ti.kernel
    def substeps_persistent(self, h: float, count: ti.i32):
        self.bar[None] = 0
        for t in range(1024):  # two tasks of 512 items (the adaptive block size): one worker per thread
            if t % 512 == 0:
                w = t // 512
                s0, s1 = w * self.n_springs // 2, (w + 1) * self.n_springs // 2
                p0, p1 = w * self.n_particles // 2, (w + 1) * self.n_particles // 2
                for sub in range(count):
                    for s in range(s0, s1):
                        self.spring(s)
                    self.barrier(4 * sub + 2)
                    for i in range(p0, p1):
                        self.particle(i, h)
                    self.barrier(4 * sub + 4)


@ti.kernel
def loops24(a: ti.template(), serial: ti.template()):
    for _ in ti.static(range(24)):
        ti.loop_config(serialize=serial)
        for i in range(a.shape[0]):
            a[i] += 1


@ti.kernel
def empty(a: ti.template()):
    a[0] += 1


@ti.func
def heavy(a: ti.template(), i, iters):
    y = ti.cast(i, float) * 1e-3
    for _ in range(iters):  # a dependent chain: neither vectorised nor folded
        y = ti.sin(y) + 0.5
    a[i] = ti.Vector([y, ti.cast(ti.global_thread_idx(), float)])  # the result and the thread that ran it


@ti.kernel
def heavy_plain(a: ti.template(), iters: ti.i32):
    ti.loop_config(block_dim=1)
    for i in range(64):
        heavy(a, i, iters)


@ti.kernel
def heavy_spread(a: ti.template(), iters: ti.i32):
    for t in range(64 * 512):  # 64 tasks of 512 items, one heavy item each
        if t % 512 == 0:
            heavy(a, t // 512, iters)


@ti.kernel
def heavy_unadaptive(a: ti.template(), iters: ti.i32):
    ti.loop_config(block_dim=1, block_dim_adaptive=False)  # sets a program-wide flag: compiled last
    for i in range(64):
        heavy(a, i, iters)


def timed(fn, batch: int, repeats: int) -> dict:
    """First call (compile included), two warm-up calls, then seconds per call in `repeats` batches of
    `batch` calls: median, min, max."""
    t0 = clock()
    fn()
    first = clock() - t0
    fn(), fn()
    samples = []
    for _ in range(repeats):
        t0 = clock()
        for _ in range(batch):
            fn()
        samples.append((clock() - t0) / batch)
    return {"first_s": first, "s": statistics.median(samples), "min_s": min(samples), "max_s": max(samples)}


def substep_bytes(n_particles: int, n_springs: int, fb: int) -> int:
    """Each array once per pass. Spring pass: pair, 3 params, x and v read, f written; particle pass:
    start, 1/m, 2 signed entries per spring, f, x and v read, x and v written."""
    return n_springs * (8 + 6 * fb + 8 + 3 * fb) + n_particles * (6 * fb + 4 + fb + 12 * fb)


def sweep(sizes, layouts, repeats, precision: str) -> list[dict]:
    rows, ref = [], {}
    for n in sizes:
        for (vertex, springs), serial in ((lay, sr) for lay in layouts for sr in (True, False)):
            c = Cloth(n, vertex, springs)
            r = timed(lambda c=c, sr=serial: c.substep(H, sr), 16, repeats)
            x = c.x.to_numpy()
            nbytes = substep_bytes(c.n_particles, c.n_springs, 8 if precision == "f64" else 4)
            dx = float(np.abs(x - ref.setdefault(n, x)).max())  # same substeps as the first (engine) case
            row = dict(
                n=n, vertex=vertex, springs=springs, serial=serial, n_springs=c.n_springs, bytes=nbytes
            )
            rows.append(row | {"dx": dx} | r)
            log(f"{precision} {n}^2 {vertex}/{springs} serial={serial}: {r['s'] * 1e6:.0f} us")
    return rows


def pool_facts(sizes, repeats) -> dict:
    """(i): µs per loop of the 24-loop kernel minus an empty launch."""
    other, z = OtherLoad(), ti.field(ti.i32, 1)
    empty_s = timed(lambda: empty(z), 32, repeats)["s"]
    loops = []
    for n, serial in ((n, sr) for n in sizes for sr in (True, False)):
        a = ti.field(ti.i32, n)
        r = timed(lambda a=a, sr=serial: loops24(a, sr), 4, repeats)
        loops.append(dict(n=n, serial=serial, per_loop_s=(r["s"] - empty_s) / 24))
    return dict(empty_launch_s=empty_s, loops=loops, other_cores=other.cores())


def heavy_times(repeats, iters) -> dict:
    """(ii): time of each 64-item kernel, and the share of the items its busiest thread ran (median of 9)."""
    a, out = ti.Vector.field(2, float, 64), {}
    kernels = {"plain, block_dim=1": heavy_plain, "t % 512 spread": heavy_spread}
    kernels["block_dim=1, block_dim_adaptive=False"] = heavy_unadaptive
    for name, f in kernels.items():
        r = timed(lambda f=f: f(a, iters), 2, repeats)
        share = []
        for _ in range(9):
            f(a, iters)
            share.append(np.bincount(a.to_numpy()[:, 1].astype(int)).max() / 64)
        out[name] = dict(s=r["s"], busiest_share=float(np.median(share)))
    return out


def persistent(n, repeats) -> dict:
    """(iii): µs per substep of four ways to run 16 substeps, and a check of the persistent kernel."""
    other, out = OtherLoad(), {}
    calls = {
        "one launch per substep, parallel": (1, lambda c: c.substep(H, False)),
        "one launch per substep, serialized": (1, lambda c: c.substep(H, True)),
        "16 substeps in one serialized kernel": (16, lambda c: c.substeps_serial(H, 16)),
        "16 substeps in a 2-worker spin-barrier kernel": (16, lambda c: c.substeps_persistent(H, 16)),
    }
    for name, (per, call) in calls.items():
        c = Cloth(n, "AoS", "pair+param")
        r = timed(lambda c=c, f=call: f(c), 16 // per, repeats)
        out[name] = {k: r[k] * 1e6 / per for k in ("s", "min_s", "max_s")} | {"stalls": int(c.stalls[None])}
    a, b = Cloth(n, "AoS", "pair+param"), Cloth(n, "AoS", "pair+param")
    a.substeps_serial(H, 64)
    b.substeps_persistent(H, 64)
    dx = float(np.abs(a.x.to_numpy() - b.x.to_numpy()).max())
    return dict(cases=out, check=dict(dx=dx, stalls=int(b.stalls[None])), other_cores=other.cores())


def measure(q: dict) -> dict:
    init("f32")
    res = {"dram_copy_gbs": memory_bandwidth()["median"]}
    res["f32"] = sweep(q["sizes"], LAYOUTS, q["repeats"], "f32")
    sizes = {r["n"]: r["bytes"] for r in res["f32"]}  # a copy moving as many bytes as the f32 substep
    res["copy_gbs"] = {str(n): memory_bandwidth(nbytes // 2, 30)["median"] for n, nbytes in sizes.items()}
    res["pool"] = pool_facts(q["loops"], q["repeats"])
    res["persistent"] = persistent(32, 4 * q["repeats"])
    res["heavy"] = {"2": heavy_times(q["repeats"], q["iters"])}
    init("f32", cpu_threads=1)
    res["heavy"]["1"] = heavy_times(q["repeats"], q["iters"])
    init("f64")
    res["f64"] = sweep(q["sizes"], [LAYOUTS[0], LAYOUTS[3]], q["repeats"], "f64")
    return res


def pick(rows, n, lay, serial) -> dict:
    return next(r for r in rows if (r["n"], (r["vertex"], r["springs"]), r["serial"]) == (n, lay, serial))


def ns(r: dict) -> str:
    return f"{r['s'] * 1e9 / r['n_springs']:.2f}"


def table(head: str, rows: list[str]) -> str:
    """A markdown table from "|"-separated header and row strings."""
    return md_table(head.split("|"), [r.split("|") for r in rows])


def layout_table(rows) -> str:
    out = []
    for r in (r for r in rows if r["serial"]):
        p, e = pick(rows, r["n"], (r["vertex"], r["springs"]), False), pick(rows, r["n"], LAYOUTS[0], False)
        out.append(
            f"{r['n']}²|{r['n_springs']}|{r['vertex']}|{r['springs']}|{ns(r)}|{ns(p)}|{r['s'] / p['s']:.2f}|"
            f"{p['s'] / e['s']:.2f}|{max(r['dx'], p['dx']):.1e}|{fmt_s(r['first_s'])}"
        )
    head = "grid|springs|vertices, forces|spring params|ns/spring serialized|ns/spring parallel|"
    return table(
        head + "parallel speed-up|parallel time / engine layout's|max abs(x - engine's) [m]|first call", out
    )


def fp_table(res) -> str:
    out = []
    for r in (r for r in res["f64"] if r["serial"]):
        row, lay = f"{r['n']}²|{r['vertex']}, {r['springs']}", (r["vertex"], r["springs"])
        for a, b in ((pick(res["f32"], r["n"], lay, sr), pick(res["f64"], r["n"], lay, sr)) for sr in (1, 0)):
            row += f"|{ns(a)}|{ns(b)}|{b['s'] / a['s']:.2f}"
        out.append(row)
    head = "grid|layout|ns/spring f32, serialized|f64|f64/f32|ns/spring f32, parallel|f64|f64/f32"
    return table(head, out)


def bytes_table(res) -> tuple[str, str]:
    """The table, and a sentence naming what bounds the faster mode at each size and precision."""
    pool, out, verdicts = res["pool"], [], []
    par = next(r["per_loop_s"] for r in pool["loops"] if not r["serial"])  # at the smallest size
    fixed = {True: pool["empty_launch_s"], False: pool["empty_launch_s"] + 2 * par}
    for prec in ("f32", "f64"):
        rows = [r for r in res[prec] if (r["vertex"], r["springs"]) == LAYOUTS[0]]
        for r in rows:
            gbs, copy, share = (
                r["bytes"] / r["s"] / 1e9,
                res["copy_gbs"][str(r["n"])],
                fixed[r["serial"]] / r["s"],
            )
            r["gbs"], r["bound"] = gbs, "bandwidth" if gbs > 0.5 * copy else "latency/compute"
            r["bound"] = "launch/thread pool" if share > 0.5 else r["bound"]
            out.append(
                f"{r['n']}²|{prec}|{MODE[r['serial']]}|{r['bytes'] / 1e6:.2f}|{r['s'] * 1e6:.0f}|{gbs:.1f}|"
                f"{gbs / res['dram_copy_gbs']:.2f}|{gbs / copy:.2f}|{share:.2f}|{r['bound']}"
            )
        for n in sorted({r["n"] for r in rows}):
            r = min((r for r in rows if r["n"] == n), key=lambda r: r["s"])
            verdicts.append(
                f"{n}² {prec}: {MODE[r['serial']]} faster, {r['gbs'] / res['copy_gbs'][str(n)]:.2f} of a "
                f"same-size copy, {r['bound']}"
            )
    head = (
        "grid|fp|loops|MB per substep|µs per substep|GB/s|/ DRAM copy|/ same-size copy|fixed share|bound by"
    )
    if all(v.endswith("latency/compute") for v in verdicts):
        verdicts[-1] += (
            ". Every size is latency/compute-bound (gathers through the adjacency and dependent loads, far "
            "below what the caches stream), so a layout that saves bytes cannot pay: launches, thread-pool "
            "costs and keeping both cores busy are what is left"
        )
    return table(head, out), "; ".join(verdicts) + "."


def pool_tables(res) -> tuple[str, str, str]:
    loops = {(r["n"], r["serial"]): r["per_loop_s"] * 1e6 for r in res["pool"]["loops"]}
    sizes, h, p = sorted({n for n, _ in loops}), res["heavy"], res["persistent"]["cases"]
    t1 = table(
        "items per loop|µs per loop, serialized|µs per loop, parallel",
        [f"{n}|{loops[n, True]:.1f}|{loops[n, False]:.1f}" for n in sizes],
    )
    t2 = table(
        "64 heavy items|1 thread|2 threads|1 thread / 2 threads|busiest thread's share (2 threads)",
        [
            f"{k}|{fmt_s(h['1'][k]['s'])}|{fmt_s(h['2'][k]['s'])}|{h['1'][k]['s'] / h['2'][k]['s']:.2f}|"
            f"{h['2'][k]['busiest_share']:.2f}"
            for k in h["1"]
        ],
    )
    t3 = table(
        "32² cloth|µs per substep (median)|min|max|barrier stalls",
        [f"{k}|{v['s']:.1f}|{v['min_s']:.1f}|{v['max_s']:.1f}|{v['stalls']}" for k, v in p.items()],
    )
    return t1, t2, t3


def conclusions(res) -> dict:
    """The figures and verdicts the page's conclusions quote, from this run."""
    rows, sizes, e = res["f32"], sorted({r["n"] for r in res["f32"]}), LAYOUTS[0]
    ratio = {
        lay: [
            pick(rows, r["n"], lay, r["serial"])["s"] / r["s"]
            for r in rows
            if (r["vertex"], r["springs"]) == e
        ]
        for lay in LAYOUTS[1:]
    }
    med = {lay: statistics.median(v) for lay, v in ratio.items()}
    best = min(med, key=med.get)
    keep = (
        "no layout is 10% faster: keep the engine's AoS fields"
        if med[best] > 0.9
        else (f"{best[0]}/{best[1]} is faster by {1 / med[best]:.2f}× (median)")
    )
    f64 = {sr: [pick(res["f64"], n, e, sr)["s"] / pick(rows, n, e, sr)["s"] for n in sizes] for sr in (1, 0)}
    loops = {(r["n"], r["serial"]): r["per_loop_s"] * 1e6 for r in res["pool"]["loops"]}
    p, n0, h = res["persistent"]["cases"], min(n for n, _ in loops), res["heavy"]
    short = min(
        h["2"][k]["busiest_share"] for k in ("plain, block_dim=1", "block_dim=1, block_dim_adaptive=False")
    )
    per, ser = (p[f"16 substeps in {k} kernel"]["s"] for k in ("a 2-worker spin-barrier", "one serialized"))
    return dict(
        layout="Time relative to the engine layout, median over sizes and modes (range): "
        + ", ".join(f"{a}/{b} {med[a, b]:.2f}× ({min(v):.2f}–{max(v):.2f})" for (a, b), v in ratio.items())
        + f"; {keep}.",
        speed=", ".join(f"{n}² {pick(rows, n, e, 1)['s'] / pick(rows, n, e, 0)['s']:.2f}×" for n in sizes),
        fp=f"f64 takes {min(f64[1]):.2f}–{max(f64[1]):.2f}× the f32 time with serialized loops and "
        f"{min(f64[0]):.2f}–{max(f64[0]):.2f}× with parallel ones (engine layout) for 1.7× the bytes: "
        + (
            "float width hardly matters to this substep; f32 stays the default for its memory, and f64 is "
            "nearly free where accuracy needs it (the parallel ratios at small sizes move with the thread "
            "pool's fixed cost, item 4)"
            if max(f64[1]) < 1.3
            else "f32 buys real speed here"
        ),
        empty=res["pool"]["empty_launch_s"] * 1e6,
        par_fixed=loops[n0, False] - loops[n0, True],
        pays=", ".join(f"{n}²" for n in sizes if pick(rows, n, e, 1)["s"] > 1.05 * pick(rows, n, e, 0)["s"])
        or "no size",
        loop=f"{loops[n0, False]:.0f} µs parallel against {loops[n0, True]:.1f} µs serialized at {n0} items",
        cross=next(
            (f"from {n} items on" for n, sr in sorted(loops) if not sr and loops[n, sr] < loops[n, True]),
            f"at none of these sizes (up to {max(n for n, _ in loops)} items)",
        ),
        plain=h["2"]["plain, block_dim=1"]["busiest_share"],
        unadaptive=h["2"]["block_dim=1, block_dim_adaptive=False"]["busiest_share"],
        neither="neither option spreads" if short > 0.9 else "an option spreads",
        spread=h["1"]["t % 512 spread"]["s"] / h["2"]["t % 512 spread"]["s"],
        even=" (its items split evenly, yet 2 threads were no faster: the halves did not overlap, as when "
        "another process holds the second core; see the CPU used by other processes)"
        if h["2"]["t % 512 spread"]["busiest_share"] < 0.6
        and h["1"]["t % 512 spread"]["s"] < 1.3 * h["2"]["t % 512 spread"]["s"]
        else "",
        best=f"best batches {p['16 substeps in a 2-worker spin-barrier kernel']['min_s']:.0f} against "
        f"{p['16 substeps in one serialized kernel']['min_s']:.0f} µs",
        pers=f"{per:.0f} µs a substep against {ser:.0f} µs serialized ({'faster' if per < ser else 'slower'}",
        tail=p["16 substeps in a 2-worker spin-barrier kernel"]["max_s"] / per,
    )


def render(data: dict) -> str:
    """The page, from a run's JSON (what `measure` returned plus the run's settings and machine table)."""
    r = data
    t_layout, t_fp, (t_bytes, verdicts) = layout_table(r["f32"]), fp_table(r), bytes_table(r)
    t_loops, t_heavy, t_pers = pool_tables(r)
    c, h, cap = conclusions(r), r["settings"]["h"], r["settings"]["spin_cap"]
    return TEMPLATE.format(**r["run"], **locals())  # the template names these locals


def main(argv=None) -> None:
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument(
        "--from-json", type=Path, help="re-render the page from a run's layout.json, measuring nothing"
    )
    known, rest = pre.parse_known_args(argv)
    args = parse_args(__doc__.splitlines()[0] + " Also: --from-json PATH.", rest)
    _, folder = output_paths(args)
    if known.from_json:
        data = json.loads(known.from_json.read_text())
    else:
        load_start, engine, other, t0 = load_average(), engine_fingerprint(), OtherLoad(), time.perf_counter()
        res = measure(QUICK if args.quick else FULL)
        date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
        info = machine_table(
            machine_info(),
            load_start=load_start,
            load_end=load_average(),
            date=date,
            engine=engine,
            other=other,
        )
        run = dict(cmd=command_line(args, "layout.py"), wall=(time.perf_counter() - t0) / 60, info=info)
        data = json.loads(json.dumps({"settings": {"h": H, "spin_cap": CAP}, "run": run, **res}))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "layout.json").write_text(json.dumps(data, indent=1))
    (folder / "layout.md").write_text(render(data))
    log(f"wrote {folder / 'layout.md'}")


TEMPLATE = """# Memory layout, float width and the CPU thread pool (cloth substep)

Regenerate: `{cmd}` (took {wall:.1f} min). The module docstring of `benchmarks/layout.py` describes the
scene and the method. The 2-core machine is shared with other sessions (see the load averages and the
CPU used by other processes): compare ratios within this run.

{info}

Substep h = {h:.6g} s (1/60 s in 16). A figure is the median over batches of 16 substeps, one kernel
launch per substep (the spring loop and the particle loop in one kernel) unless said otherwise.

## 1. AoS against SoA (f32)

"AoS" = `ti.Vector.field(3, float, n)` (what the engine uses) for x, v and the per-spring force; "SoA" =
the same with `layout=ti.Layout.SOA` (one array per component). Spring parameters: "pair+param" = the
engine's `Vector.field(2, i32)` + `Vector.field(3, float)`; "packed struct" = one AoS `Struct.field`
(i, j, rest, k, c); "separate arrays" = that struct in SOA layout. Serialized = `ti.loop_config(serialize=
True)` on both loops; parallel = Taichi's default (2 threads).

{t_layout}

**Conclusion.** {c[layout]} Parallel speed-up of the engine layout over its serialized loops: {c[speed]}.

## 2. f32 against f64

The same kernels after `ta.init(precision="f64")` in the same process.

{t_fp}

**Conclusion.** {c[fp]}.

## 3. Bytes per substep against bandwidth

Bytes = each array read or written once per pass (a lower bound: repeated gathers of x, v and f are
assumed to hit the cache). DRAM copy: NumPy copy of 512 MiB, {r[dram_copy_gbs]:.1f} GB/s (read + write, one
thread); same-size copy: a NumPy copy of the substep's bytes (cache-resident where the working set fits).
"fixed share" = (empty launch + 2 parallel loops' fixed cost at the smallest size of item 4, or the
empty launch for serialized loops) / the substep's time. "bound by": fixed share > 0.5 -> launch/thread
pool, else GB/s > 0.5 × same-size copy -> bandwidth, else latency/compute (gathers, dependent loads).

{t_bytes}

**Conclusion.** {verdicts}

## 4. Thread-pool facts of this machine

(i) Fixed cost of a range-for inside one kernel: a kernel of 24 `ti.static`-unrolled loops `a[i] += 1`,
(time − an empty launch of {c[empty]:.0f} µs) / 24: {c[loop]} (other processes used
{r[pool][other_cores]:.2f} cores meanwhile).

{t_loops}

**Conclusion.** A parallel loop costs a fixed {c[par_fixed]:.0f} µs or so here (the thread pool wakes
its workers for every loop), so a loop pays to run in parallel only when its serialized time is several
times that: for `a[i] += 1` parallel beats serialized {c[cross]}; the cloth substep's two parallel loops
are more than 5% faster than serialized ones at {c[pays]} (item 1). Serialize small loops and fuse substeps.

(ii) Taichi's CPU range-for is cut into tasks of min(1024, max(512, n / (threads × 32))) items, so a loop
of < 1024 items is one task on one thread. 64 heavy items (a dependent chain of `sin`) on 1 and on 2
threads; "busiest thread's share": the fraction of the items the busiest of the 2 threads ran
(`ti.global_thread_idx()`, median of 9 calls). Tried: `ti.loop_config(block_dim=1)`, the same with
`block_dim_adaptive=False` (a program-wide flag, so compiled last), and spreading the items over 64 × 512
iterations (`if t % 512 == 0`).

{t_heavy}

**Conclusion.** The busiest thread ran {c[plain]:.2f} of the items of the plain loop and
{c[unadaptive]:.2f} with the adaptive size switched off: {c[neither]} a short loop in taichi 1.7.4.
Spread over 64 × 512 iterations the loop ran {c[spread]:.2f}× faster on 2 threads than on 1{c[even]}.
Any engine loop under 1024 items (a small model's particle loop, per-block loops) uses one core whatever
it asks for.

(iii) 32² cloth: a persistent kernel of two workers (a 1024-item loop, `if t % 512 == 0`), each owning half
the springs and half the particles, two spin barriers per substep (atomic_add, then spin on
`atomic_or(bar, 0)` at most {cap} times; a stall is counted past that), 16 substeps per launch, against the
same 16 substeps serialized in one kernel and against one launch per substep; median, min and max over
batches (other processes used {r[persistent][other_cores]:.2f} cores meanwhile). Check: 64 substeps
persistent against serialized, max abs(dx) = {r[persistent][check][dx]:.1e} m, {r[persistent][check][stalls]}
stalls.

{t_pers}

**Conclusion.** The spin-barrier kernel takes {c[pers]}); {c[best]}; its slowest batch took
{c[tail]:.1f}× its median. A spin barrier needs both threads on a core at once: when another process
holds the other core, every barrier waits for a time slice of the scheduler (milliseconds), so it is a
bet on an idle machine.
"""


if __name__ == "__main__":
    main()
