"""The largest liquid that runs in real time at 30 frames per second on this CPU: the `dam_break` demo's
column (2 w^3 particles for w across its width) simulated in frames of 1/30 s for its first second
(the collapse and the surge, where the speeds and so the CFL substeps grow), by DFSPH and by
position-based fluids, with and without the blob surface each frame.

Per size: the median and the slowest frame's wall time (after the first frame, whose compile is
reported apart), the CFL steps per frame, and whether the median fits 1/30 s. Timed with ti.sync()
before the clock; f32, every core.

    .venv/bin/python benchmarks/fluid_realtime.py [--quick]
"""

import os
import statistics

from harness import Page, clock, fmt_s, init, log, parse_args

from taichi_anim.scenes import make_scene

FRAME = 1.0 / 30.0


def run(per_width: int, method: str, surface: bool, frames: int) -> dict:
    init("f32")
    scene = make_scene("dam_break", per_width=per_width, method=method)
    stepper = scene.integrator.stepper_for(scene.model)
    fluid = next(s for s in stepper.solvers if s.name == "fluid")
    times, steps = [], []
    for _ in range(frames):
        a = clock()
        stepper.advance(scene.state, FRAME, 1)
        if surface:
            scene.mesh()
        times.append(clock() - a)
        steps.append(fluid.frame_stats()["steps"])
    return dict(particles=scene.model.fluid_count, first=times[0], median=statistics.median(times[1:]),
                worst=max(times[1:]), steps=statistics.mean(steps[1:]))  # fmt: skip


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    # Odd widths too from 8: the sizes near 30 frames per second are 1,024-2,662 particles here.
    sizes, frames = ((4, 6), 8) if args.quick else ((4, 6, 8, 9, 10, 11, 12, 14, 16), 30)
    rows, data = [], []
    for method in ("dfsph", "pbf"):
        for surface in (False, True):
            for w in sizes:
                r = run(w, method, surface, frames)
                fits = r["median"] <= FRAME
                rows.append([method, "yes" if surface else "no", r["particles"], fmt_s(r["median"]),
                             fmt_s(r["worst"]), f"{r['steps']:.1f}", "yes" if fits else "no",
                             fmt_s(r["first"])])  # fmt: skip
                data.append(dict(method=method, surface=surface, per_width=w, **r))
                log(" | ".join(map(str, rows[-1])))
                if not fits:
                    break  # larger ones are slower still
    best = {}
    for d in data:
        if d["median"] <= FRAME:
            key = (d["method"], d["surface"])
            best[key] = max(best.get(key, 0), d["particles"])
    page = Page(
        "fluid_realtime",
        "The largest liquid at 30 frames per second",
        args,
        {"scene": "dam_break demo (a column of width a, 2a high, a deep, in a tank 4.5a long), "
                  "2 w^3 particles", "frames": f"{frames} of 1/30 s (the first second)",
         "solvers": "DFSPH, PBF at the demo's tolerance 5e-4", "threads": os.cpu_count(),
         "surface": "the demo's blob surface (BlobScene.mesh) each frame, or none"},
    )  # fmt: skip
    page.table(
        "Per frame of 1/30 s",
        ["solver", "surface", "particles", "median", "slowest", "steps/frame", "real time", "first frame"],
        rows,
        "Largest that fits: "
        + ", ".join(f"{m}{' + surface' if s else ''}: {n}" for (m, s), n in sorted(best.items())),
    )
    page.write(data)


if __name__ == "__main__":
    main()
