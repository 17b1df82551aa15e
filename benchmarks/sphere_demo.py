"""The spheres demo: closest pair against cost — steps per frame and Jacobi sweeps per step, to choose the
demo's settings by measurement.

Scene: `taichi_anim.scenes.spheres.build` (hard spheres of radius 6 mm, 1 g, on a jittered lattice in a
column 0.3 m above the floor of a 1.2 m box, falling with random velocities; spheres restitution 0.5,
friction 0.4; walls 0.3 / 0.4), 1/30 s frames, symplectic Euler, float32, 2 threads. For each option the
scene runs its first frames (the column's splash onto the floor is the deepest compression); the error is
the closest centre distance over the diameter after each frame (`overlap_stats`), and its worst over the
frames; the cost is the median wall time per frame after the first (which holds the JIT compile). The
options are compared at 20,000 spheres (15 frames); the old and the chosen setting then run the demo at
its full 10^5 spheres over its first 13 frames.

    .venv/bin/python benchmarks/sphere_demo.py                  # writes benchmarks/results/sphere_demo.*
    .venv/bin/python benchmarks/sphere_demo.py --quick          # 2,000 spheres, 8 frames, benchmarks/out/
"""

import json
import sys
import time

import numpy as np
import taichi as ti
from common import (
    OtherLoad,
    clock,
    command_line,
    engine_fingerprint,
    init,
    load_average,
    log,
    machine_info,
    machine_table,
    md_table,
    output_paths,
    parse_args,
)

from taichi_anim.scenes import spheres as spheres_scene

# (steps per frame, sweeps per step); the first is the demo's old setting.
OPTIONS = [(80, 1), (80, 2), (80, 4), (160, 1), (200, 1)]
# The demo at its full size (10^5 spheres), its old setting and the chosen one, over the splash.
FULL_SIZE, FULL_FRAMES, FULL_OPTIONS = 100_000, 13, [(80, 1), (200, 1)]


def run(particles: int, frames: int, steps_per_frame: int, sweeps: int) -> dict:
    init("f32")
    scene = spheres_scene.build(particles=particles, steps_per_frame=steps_per_frame, sweeps=sweeps)
    model, state, integ = scene.model, scene.state, scene.integrator
    closest, wall = [], []
    for _ in range(frames):
        t0 = clock()
        for _ in range(scene.substeps):
            integ.step(model, state, scene.dt)
        wall.append(clock() - t0)
        overlap, _ = integ.stepper_for(model).contacts.overlap_stats(model, state)
        closest.append(1.0 - overlap / (2.0 * scene.point_radius))
    return {
        "particles": particles,
        "frames": frames,
        "steps_per_frame": steps_per_frame,
        "sweeps": sweeps,
        "closest_over_diameter": closest,
        "worst_closest_over_diameter": min(closest),
        "worst_frame": int(np.argmin(closest)) + 1,
        "ms_per_frame": 1e3 * float(np.median(wall[1:])),
        "first_frame_s": wall[0],
    }


def main() -> None:
    particles = 2000 if "--quick" in sys.argv else 20_000
    frames = 8 if "--quick" in sys.argv else 15
    args = parse_args(__doc__.split("\n")[0])
    md_path, out_dir = output_paths(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    load_start, other, engine = load_average(), OtherLoad(), engine_fingerprint()
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    rows = []
    full = [] if "--quick" in sys.argv else [(FULL_SIZE, FULL_FRAMES, *o) for o in FULL_OPTIONS]
    for n, f, steps, sweeps in [(particles, frames, *o) for o in OPTIONS] + full:
        r = run(n, f, steps, sweeps)
        closest = r["worst_closest_over_diameter"]
        log(f"{steps} steps x {sweeps} sweeps: closest {closest:.3f} d, {r['ms_per_frame']:.0f} ms")
        rows.append(r)
    base = {r["particles"]: r["ms_per_frame"] for r in rows[::-1]}  # each size's first option
    table = md_table(
        ["spheres", "steps/frame", "sweeps/step", "closest / d (worst frame)", "ms/frame", "cost vs 80x1"],
        [
            [
                r["particles"],
                r["steps_per_frame"],
                r["sweeps"],
                f"**{r['worst_closest_over_diameter']:.3f}** ({r['worst_frame']})",
                f"{r['ms_per_frame']:.0f}",
                f"{r['ms_per_frame'] / base[r['particles']]:.2f}",
            ]
            for r in rows
        ],
    )
    machine = machine_table(
        machine_info(), load_start=load_start, load_end=load_average(), date=date, engine=engine, other=other
    )
    text = "\n\n".join(
        [
            "# The spheres demo: closest pair against cost",
            f"Regenerate: `{command_line(args, 'sphere_demo.py')}`.",
            __doc__.split("\n\n")[1].replace("\n", " "),
            f"Options at {particles} spheres over the first {frames} frames"
            + (f"; the demo's size, {FULL_SIZE} spheres, over {FULL_FRAMES} frames." if full else "."),
            machine,
            table,
        ]
    )
    md = out_dir / "sphere_demo.md" if md_path.name == "RESULTS.md" else md_path
    md.write_text(text + "\n")
    (out_dir / "sphere_demo.json").write_text(json.dumps(rows, indent=1))
    log(f"wrote {md}")
    ti.reset()


if __name__ == "__main__":
    main()
