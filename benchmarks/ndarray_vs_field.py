"""Kernels over `ti.ndarray` arguments against kernels over fields (template arguments): the launch cost
on the CPU and what a new size costs to compile, the two facts that decide how kernels can be made
independent of a scene's sizes.

The same particle update (gravity, a drag term, symplectic Euler; 24 B read and written per particle) as
one kernel taking fields and one taking ndarrays. Per size: microseconds per launch (median of ROUNDS
blocks of LAUNCHES, after a warm-up), and the first launch's seconds for a second set of arrays of a new
size (fields: a new template instance, compiled or loaded from the offline cache; ndarrays: the compiled
kernel reused).

    .venv/bin/python benchmarks/ndarray_vs_field.py [--quick]
"""

import statistics
import sys
import time
from pathlib import Path

import taichi as ti

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import Page, init, parse_args  # noqa: E402

VEC = ti.types.ndarray(dtype=ti.math.vec3, ndim=1)


@ti.func
def update(x, v, dt):
    v = v + (ti.Vector([0.0, -9.81, 0.0]) - 0.1 * v) * dt
    return x + v * dt, v


@ti.kernel
def step_fields(x: ti.template(), v: ti.template(), n: ti.i32, dt: ti.f32):
    for i in range(n):
        x[i], v[i] = update(x[i], v[i], dt)


@ti.kernel
def step_ndarrays(x: VEC, v: VEC, n: ti.i32, dt: ti.f32):
    for i in range(n):
        x[i], v[i] = update(x[i], v[i], dt)


def arrays(kind: str, n: int):
    if kind == "field":
        return ti.Vector.field(3, ti.f32, n), ti.Vector.field(3, ti.f32, n)
    return ti.ndarray(ti.math.vec3, n), ti.ndarray(ti.math.vec3, n)


def first_launch(kind: str, n: int) -> float:
    """Seconds of the first launch on new arrays of n elements (holds any compile)."""
    step = step_fields if kind == "field" else step_ndarrays
    x, v = arrays(kind, n)
    ti.sync()
    t0 = time.perf_counter()
    step(x, v, n, 1e-3)
    ti.sync()
    return time.perf_counter() - t0


def per_launch_us(kind: str, n: int, launches: int, rounds: int) -> float:
    step = step_fields if kind == "field" else step_ndarrays
    x, v = arrays(kind, n)
    for _ in range(launches // 4):
        step(x, v, n, 1e-3)
    times = []
    for _ in range(rounds):
        ti.sync()
        t0 = time.perf_counter()
        for _ in range(launches):
            step(x, v, n, 1e-3)
        ti.sync()
        times.append((time.perf_counter() - t0) / launches * 1e6)
    return statistics.median(times)


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    init("f32")
    sizes = (1024, 65536) if args.quick else (1024, 16384, 262144, 1048576)
    launches, rounds = (200, 3) if args.quick else (2000, 7)
    rows, data = [], {}
    for kind in ("field", "ndarray"):
        first_launch(kind, 1000)  # the first instance of each kernel: a compile either way
    for n in sizes:
        f_us, a_us = (per_launch_us(k, n, launches, rounds) for k in ("field", "ndarray"))
        f_new, a_new = (first_launch(k, n + 1) for k in ("field", "ndarray"))
        data[n] = {
            "field_us": f_us,
            "ndarray_us": a_us,
            "field_new_size_s": f_new,
            "ndarray_new_size_s": a_new,
        }
        rows.append([n, f"{f_us:.1f}", f"{a_us:.1f}", f"{a_us / f_us:.2f}", f"{f_new:.3f}", f"{a_new:.3f}"])
        print(rows[-1], flush=True)
    page = Page(
        "ndarray_vs_field",
        "ndarray against field kernels: launch cost and a new size's compile",
        args,
        {
            "kernel": "gravity + drag + symplectic Euler over n vec3 positions, velocities; f32, CPU",
            "launch": f"median of {rounds} blocks of {launches} launches, after {launches // 4} warm-up",
            "new size": "first launch on new arrays of n + 1 elements (fields: a new template instance)",
        },
    )
    page.table(
        "µs per launch and a new size's first launch",
        ["n", "fields µs", "ndarrays µs", "ndarray / field", "fields: new size s", "ndarrays: new size s"],
        rows,
    )
    page.write(data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
