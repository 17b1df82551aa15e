"""A frame of K launches three ways: kernels over fields launched from Python, kernels over ndarrays
launched from Python, and the ndarray kernels recorded once in a `ti.graph` and replayed with one call
(Taichi's way to skip the per-launch Python work). It decides whether graphs could cut the host share
of small frames (benchmarks/results/step_breakdown.md).

The kernel is ndarray_vs_field.py's particle update (gravity, drag, symplectic Euler over n vec3
positions and velocities, f32). Per size: µs per frame of K launches (median of ROUNDS blocks of
FRAMES frames, after a warm-up), each frame ended by `ti.sync()`. Graph nodes take only ndarrays and
scalars (no template arguments), which is why the engine's kernels (fields, data_oriented templates)
cannot be recorded as they are.

    .venv/bin/python benchmarks/graph_launch.py [--quick]
"""

import statistics
import sys
import time
from pathlib import Path

import taichi as ti

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import Page, init, parse_args  # noqa: E402
from ndarray_vs_field import arrays, step_fields, step_ndarrays  # noqa: E402

K = 10  # launches per frame: the fountain's substeps


def frame_runner(way: str, n: int):
    """A callable running one frame of K launches the given way, on fresh arrays of n elements."""
    x, v = arrays("field" if way == "fields" else "ndarray", n)
    if way == "fields":
        return lambda: [step_fields(x, v, n, 1e-3) for _ in range(K)]
    if way == "ndarrays":
        return lambda: [step_ndarrays(x, v, n, 1e-3) for _ in range(K)]
    vec = ti.math.vec3
    sym_x = ti.graph.Arg(ti.graph.ArgKind.NDARRAY, "x", dtype=vec, ndim=1)
    sym_v = ti.graph.Arg(ti.graph.ArgKind.NDARRAY, "v", dtype=vec, ndim=1)
    sym_n = ti.graph.Arg(ti.graph.ArgKind.SCALAR, "n", ti.i32)
    sym_dt = ti.graph.Arg(ti.graph.ArgKind.SCALAR, "dt", ti.f32)
    builder = ti.graph.GraphBuilder()
    for _ in range(K):
        builder.dispatch(step_ndarrays, sym_x, sym_v, sym_n, sym_dt)
    graph = builder.compile()
    args = {"x": x, "v": v, "n": n, "dt": 1e-3}
    return lambda: graph.run(args)


def us_per_frame(run, frames: int, rounds: int) -> float:
    for _ in range(max(frames // 4, 1)):
        run()
    ti.sync()
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(frames):
            run()
            ti.sync()
        times.append((time.perf_counter() - t0) / frames * 1e6)
    return statistics.median(times)


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    init("f32")
    sizes = (1024, 65536) if args.quick else (1024, 16384, 65536, 262144)
    frames, rounds = (50, 3) if args.quick else (400, 7)
    ways = ("fields", "ndarrays", "graph")
    rows, data = [], {}
    for n in sizes:
        us = {w: us_per_frame(frame_runner(w, n), frames, rounds) for w in ways}
        data[n] = us
        rows.append([n] + [f"{us[w]:.0f}" for w in ways])
        rows[-1] += [f"{us['graph'] / us['fields']:.2f}", f"{us['ndarrays'] / us['fields']:.2f}"]
        print(rows[-1], flush=True)
    page = Page(
        "graph_launch",
        "A frame of launches: fields, ndarrays and a ti.graph",
        args,
        {
            "kernel": "gravity + drag + symplectic Euler over n vec3 positions, velocities; f32, CPU",
            "frame": f"{K} launches, then ti.sync()",
            "timing": f"median of {rounds} blocks of {frames} frames (warm-up: {max(frames // 4, 1)})",
            "graph": "ti.graph.GraphBuilder: K dispatches of the ndarray kernel, one Graph.run per frame",
        },
    )
    page.table(
        "µs per frame",
        ["n", "fields", "ndarrays", "graph", "graph / fields", "ndarrays / fields"],
        rows,
    )
    page.write(data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
