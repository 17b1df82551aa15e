"""What bounds the cloth against warp_cpu on this CPU: the engine's frame next to the smallest Taichi
kernel of the same step, and Warp's own CPU mode, same scene, same process.

Scene: Warp's cloth benchmark (`cloth_warp.py`): dim x dim vertices, structural, shear and bend springs
(k = 1000 N/m, damping 10), two pinned corners, gravity, 16 symplectic Euler substeps a 1/60 s frame, f32.
"minimal serial": one serial kernel a frame, nothing but the physics: per substep zero the forces, one
pass over the springs (sorted by their ends, as the engine sorts them) adding each force into its two
ends, one pass over the vertices (v += h f / m + h g, x += h v). No watchdog, no copies, no generality:
what Taichi's CPU code makes of the step on one core, the floor for any serial path of the engine.
"minimal parallel": two parallel loops a substep, the springs' forces into an array, then each vertex
summing its springs' (a compressed adjacency, as the engine's parallel path reads it) and updating.
"ours 1 thread": the engine's parallel frame (one launch a frame, its threads meeting at barriers between
passes) forced on one thread, which then runs every chunk: half of it is what two perfectly used cores
would give the engine's passes.
Each frame of ours and Warp's reads the positions as NumPy, as `cloth_warp.py` does (ours a float64 copy,
`state.positions()`; warp_cpu a view of its array, no copy); the minimal kernels read nothing.

    .venv/bin/python benchmarks/cloth_bound.py [--quick]
"""

import numpy as np
import taichi as ti
from cloth_warp import ours, theirs
from harness import Page, Run, fmt_s, host_clock, init, log, parse_args, peer, ratio, time_run, versions

SIZES, QUICK_SIZES = (32, 64, 128, 256), (32, 64)
GRAVITY = -9.81


@ti.data_oriented
class MinimalCloth:
    """The cloth's step and nothing else, in one kernel a frame (module docstring)."""

    def __init__(self, cloth, parallel: bool):
        pairs = np.sort(np.asarray(cloth.spring_indices).reshape(-1, 2), axis=1)
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        x0 = np.asarray(cloth.positions, np.float64)
        rest = np.linalg.norm(x0[pairs[:, 0]] - x0[pairs[:, 1]], axis=1)
        k, c = (
            np.broadcast_to(cloth.spring_stiffness, len(pairs)),
            np.broadcast_to(cloth.spring_damping, len(pairs)),
        )
        n, s = len(x0), len(pairs)
        self.n, self.s, self.parallel = n, s, parallel
        self.x = ti.Vector.field(3, ti.f32, n)
        self.v = ti.Vector.field(3, ti.f32, n)
        self.f = ti.Vector.field(3, ti.f32, n)
        self.pair = ti.Vector.field(2, ti.i32, s)
        self.param = ti.Vector.field(3, ti.f32, s)  # rest length, stiffness, damping
        self.inv_m = ti.field(ti.f32, n)
        self.x.from_numpy(x0.astype(np.float32))
        self.pair.from_numpy(pairs.astype(np.int32))
        self.param.from_numpy(np.stack([rest, k, c], axis=1).astype(np.float32))
        inv = np.where(np.asarray(cloth.inv_masses) > 0, 1.0 / 0.1, 0.0)
        self.inv_m.from_numpy(inv.astype(np.float32))
        # Each vertex's springs, +(q+1) where it is the first end (force +f_q), -(q+1) the second.
        owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
        signed = np.concatenate([np.arange(1, s + 1), -np.arange(1, s + 1)])
        order = np.argsort(owner, kind="stable")
        start = np.zeros(n + 1, np.int32)
        np.cumsum(np.bincount(owner, minlength=n), out=start[1:])
        self.fs = ti.Vector.field(3, ti.f32, s)
        self.adj_start = ti.field(ti.i32, n + 1)
        self.adj = ti.field(ti.i32, 2 * s)
        self.adj_start.from_numpy(start)
        self.adj.from_numpy(signed[order].astype(np.int32))

    @ti.func
    def spring(self, q):
        a, b = self.pair[q][0], self.pair[q][1]
        p = self.param[q]
        d = self.x[a] - self.x[b]
        dv = self.v[a] - self.v[b]
        inv = ti.rsqrt(ti.max(d.dot(d), 1e-24))
        n = d * inv
        return a, b, -(p[1] * (d.dot(n) - p[0]) + p[2] * dv.dot(n)) * n

    @ti.func
    def update(self, i, h):
        w = self.inv_m[i]
        g = ti.Vector([0.0, GRAVITY, 0.0]) * (1.0 if w > 0.0 else 0.0)
        vi = self.v[i] + h * (self.f[i] * w + g)
        self.v[i] = vi
        self.x[i] += h * vi

    @ti.kernel
    def serial_frame(self, h: ti.f32, substeps: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(1):
            for _k in range(substeps):
                for i in range(self.n):
                    self.f[i] = ti.Vector([0.0, 0.0, 0.0])
                for q in range(self.s):
                    a, b, fs = self.spring(q)
                    self.f[a] += fs
                    self.f[b] -= fs
                for i in range(self.n):
                    self.update(i, h)

    @ti.kernel
    def springs(self):
        for q in range(self.s):
            _, _, self.fs[q] = self.spring(q)

    @ti.kernel
    def gather_update(self, h: ti.f32):
        for i in range(self.n):
            f = ti.Vector([0.0, 0.0, 0.0])
            for e in range(self.adj_start[i], self.adj_start[i + 1]):
                q = self.adj[e]
                if q > 0:
                    f += self.fs[q - 1]
                else:
                    f -= self.fs[-q - 1]
            self.f[i] = f
            self.update(i, h)

    def frame(self, h: float, substeps: int) -> None:
        if not self.parallel:
            self.serial_frame(h, substeps)
            return
        for _ in range(substeps):
            self.springs()
            self.gather_update(h)


def minimal(cloth, parallel: bool, dt: float, substeps: int):
    init("f32")
    sim = MinimalCloth(cloth, parallel)
    return lambda: sim.frame(dt / substeps, substeps)


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    wc = peer("warp_cloth")
    if wc is None:
        return 1
    import warp as wp

    wp.config.quiet = True
    sizes, frames = (QUICK_SIZES, 10) if args.quick else (SIZES, 40)
    sc = wc.scene(32)["constants"]
    dt, substeps = float(sc["sim_dt"]), int(sc["sim_substeps"])
    rows, data = [], []
    for dim in sizes:
        log(f"{dim}^2")
        cloth = wc.make_cloth(dim)
        runs = [
            Run("warp_cpu", lambda c=cloth: theirs(wc, "warp_cpu", c, dt, substeps), sync=host_clock),
            Run("taichi_anim", lambda c=cloth: ours(wc.fresh(c), "cpu", dt, substeps)),
            # The parallel frame forced onto one thread, which then runs every chunk: the work of its
            # passes, which two threads can at best halve.
            Run(
                "ours 1 thread",
                lambda c=cloth: ours(wc.fresh(c), "cpu", dt, substeps, cpu_threads=1, mode="parallel_frame"),
            ),
            Run("minimal serial", lambda c=cloth: minimal(wc.fresh(c), False, dt, substeps)),
            Run("minimal parallel", lambda c=cloth: minimal(wc.fresh(c), True, dt, substeps)),
        ]
        res = {r.name: time_run(r, frames=frames, budget_s=15 if args.quick else 60) for r in runs}
        t = {k: v["median"] for k, v in res.items()}
        best = min(t["minimal serial"], t["minimal parallel"])
        rows.append(
            [
                f"{dim}²",
                *(
                    f"{t[k] * 1e3:.2f}"
                    for k in (
                        "warp_cpu",
                        "taichi_anim",
                        "ours 1 thread",
                        "minimal serial",
                        "minimal parallel",
                    )
                ),
            ]
            + [
                ratio(t["warp_cpu"], t["taichi_anim"]),
                ratio(t["warp_cpu"], t["ours 1 thread"] / 2),
                ratio(t["warp_cpu"], best),
                ratio(best, t["taichi_anim"]),
            ]
            + [f"{res['taichi_anim']['cores']:.2f}", fmt_s(res["minimal serial"]["first"])]
        )
        data.append({"dim": dim, "runs": res})
    page = Page(
        "cloth_bound",
        "Cloth: the engine against the smallest Taichi kernel of the same step, and warp_cpu",
        args,
        {
            "scene": f"Warp's benchmark_cloth.py Cloth: {wc.scene(32)['cloth_kwargs']}",
            "step": f"{substeps} symplectic Euler substeps per 1/{round(1 / dt)} s frame, f32, cpu",
            "minimal serial": "one serial kernel a frame: zero forces, springs into their ends, update",
            "minimal parallel": "two parallel loops a substep: per-spring forces, each vertex's sum, update",
            "ours 1 thread": "the engine's parallel frame forced on one thread (cpu_threads=1)",
            "copies": "every frame ours copies positions to NumPy (state.positions()) and warp_cpu returns a "
            "view of its array; the minimal kernels read nothing",
            "frames": f"{frames} timed after 2 warm-up frames (cut after the time budget)",
            "peers": ", ".join(f"{k} {v}" for k, v in versions("warp-lang").items()),
        },
    )
    page.table(
        "ms per frame (medians)",
        ["grid", "warp_cpu", "taichi_anim", "ours 1 thread", "minimal serial", "minimal parallel",
         "warp_cpu / ours", "warp_cpu / (ours 1 thread / 2)", "warp_cpu / best minimal",
         "best minimal / ours", "our cores busy", "minimal serial first frame"],
        rows,
        "\"ours 1 thread\": the engine's parallel frame on one thread (its passes' work, the read included); "
        "halved, what two perfectly used cores would give. \"warp_cpu / best minimal\": the most this CPU "
        "gives over warp_cpu with Taichi's code for this step as written; \"best minimal / ours\": what "
        "the engine keeps of that floor.",
    )  # fmt: skip
    page.write({"sizes": data})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
