"""Cost of the divergence watchdog (taichi_anim/watchdog.py): ms per step with its bound checks compiled
into the particle finish and without them (TAICHI_ANIM_WATCHDOG_BOUNDS=0 when the State is made, which
leaves the old non-finite test only), on 10^6 free particles in a box and on a 128^2 mass-spring cloth,
both symplectic Euler, float32. The two states share the model and the integrator and are timed in
alternating blocks (warm-up and JIT excluded, `ti.sync()` before each clock read); the ratio is what to
read. Also a step under the "retry" policy (a backup copy of the state and a counter read every step,
and the energy every step).

    .venv/bin/python benchmarks/watchdog.py [--quick]
"""

import os
import statistics
import time

import numpy as np
from harness import Page, clock, init, log, parse_args

import taichi_anim as ta

CHECK_EVERY = 10  # the divergence counter read once per 10 steps (a 60 Hz frame of the particle demos)
ROUNDS = 9


def particles(n: int):
    """n particles with random positions and velocities in a 2 m box, gravity; dt = 1/600 s."""
    rng = np.random.default_rng(0)
    b = ta.Builder()
    b.add_particles(rng.uniform(-1, 1, (n, 3)), rng.normal(0, 1, (n, 3)), mass=1e-3)
    b.add_force_gravity()
    b.add_collider_box((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), restitution=0.5)
    return b.finalize(), 1 / 600


def cloth(n: int):
    """An n x n cloth (1 m, default ClothMaterial) pinned at two corners, gravity; dt = 2e-5 s (5e-5 s
    explodes at 128^2 from its light free corners: the watchdog stops it at step ~46, at 124 m/s)."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(
        origin=(-0.5, 1.0, -0.5), resolution=(n, n), material=ta.ClothMaterial(), pinned=[0, n - 1]
    )
    return b.finalize(), 2e-5


def state_without_bounds(model):
    os.environ["TAICHI_ANIM_WATCHDOG_BOUNDS"] = "0"
    try:
        return model.state()
    finally:
        del os.environ["TAICHI_ANIM_WATCHDOG_BOUNDS"]


def ms_per_step(integ, model, state, dt: float, steps: int) -> float:
    t0 = clock()
    for _ in range(steps):
        integ.step(model, state, dt)
    return (clock() - t0) / steps * 1e3


def measure(name: str, model, dt: float, steps: int) -> dict:
    integ = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY)
    with_bounds, without = model.state(), state_without_bounds(model)
    t0 = time.perf_counter()
    for s in (with_bounds, without):
        ms_per_step(integ, model, s, dt, 2 * CHECK_EVERY)  # compile and warm up
    log(f"{name}: compiled and warmed up in {time.perf_counter() - t0:.1f} s")
    on, off = [], []
    for _ in range(ROUNDS):
        on.append(ms_per_step(integ, model, with_bounds, dt, steps))
        off.append(ms_per_step(integ, model, without, dt, steps))
    retry = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY, policy={"divergence": "retry"})
    rs = model.state()
    ms_per_step(retry, model, rs, dt, 2)
    retry_ms = statistics.median(ms_per_step(retry, model, rs, dt, max(steps // 4, 5)) for _ in range(3))
    assert int(with_bounds.nonfinite_count[None]) == 0 and int(rs.nonfinite_count[None]) == 0
    row = {
        "scene": name,
        "particles": model.particle_count,
        # The fastest block: other processes on a shared machine only ever add time.
        "off": min(off),
        "on": min(on),
        "off_median": statistics.median(off),
        "on_median": statistics.median(on),
        "retry": retry_ms,
    }
    log(row)
    return row


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    init("f32")
    n_particles, n_cloth, steps = (10**5, 64, 50) if args.quick else (10**6, 128, 100)
    data = [
        measure(f"particles 10^{round(np.log10(n_particles))}", *particles(n_particles), steps),
        measure(f"cloth {n_cloth}^2", *cloth(n_cloth), steps),
    ]
    rows = [
        [
            r["scene"],
            r["particles"],
            f"{r['off']:.3f} / {r['off_median']:.3f}",
            f"{r['on']:.3f} / {r['on_median']:.3f}",
            f"{r['on'] / r['off']:.3f} ({r['on_median'] / r['off_median']:.3f})",
            f"{r['retry']:.3f}",
        ]
        for r in data
    ]
    page = Page(
        "watchdog",
        "Divergence watchdog: cost",
        args,
        {
            "step": f"symplectic Euler, f32, check_every = {CHECK_EVERY}",
            "blocks": f"{steps} steps per block, {ROUNDS} alternating blocks per variant (fastest / median); "
            f"policy retry: median of 3 blocks of {max(steps // 4, 5)} steps",
        },
    )
    page.table(
        "ms per step",
        [
            "scene",
            "particles",
            "without bounds (min / median)",
            "with bounds (min / median)",
            "ratio of minima (of medians)",
            "policy retry",
        ],
        rows,
    )
    page.write(data)


if __name__ == "__main__":
    main()
