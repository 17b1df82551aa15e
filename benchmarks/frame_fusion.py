"""A frame in few launches: the three ways `Stepper.advance` can run a frame of substeps, timed on the
same cloth at sizes around the crossover, to set `taichi_anim.stepper.FRAME_SERIAL_BELOW`.

Scene: NVIDIA Warp's cloth-benchmark layout (warp/examples/benchmarks/benchmark_cloth.py): n x n vertices
in the XZ plane, spacing 0.1 m, 0.1 kg each, the corners (0, 0) and (n - 1, 0) pinned; structural, shear
and bend springs (cloth_implicit.warp_springs), k = 1000 N/m, damping 10 kg/s; gravity. Symplectic Euler,
16 substeps per 1/60 s frame, f32, `check_every=16`. Modes (forced through the stepper's frame_mode):
- "steps": 16 calls of Stepper.step (the per-step Python work: validation, guard, watchdog, counters);
- "launches": the method's fused kernel launched once per substep, nothing else in between;
- "serial_frame": one kernel runs the 16 substeps, every loop serial (one launch per frame).
Each mode: its own model and state (a fresh Taichi runtime per size), 3 warm-up frames (the first holds
the JIT compile), then FRAMES frames timed one by one (`ti.sync()` before each clock read; each frame
ends with the positions copied to NumPy, as Warp's benchmark does), median ms per frame; modes alternate
in ROUNDS rounds (each continuing its own run) and the median of the rounds' medians is reported, with
the process's cores busy. Also checked: every mode's positions
after the same frames are bitwise equal to "steps".

    .venv/bin/python benchmarks/frame_fusion.py           # benchmarks/results/frame_fusion.{md,json}
    .venv/bin/python benchmarks/frame_fusion.py --quick   # smoke: 2 sizes, benchmarks/out/
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np
import taichi as ti
from cloth_implicit import warp_springs
from common import (
    clock,
    command_line,
    log,
    machine_section,
    md_table,
    output_paths,
    parse_args,
    publish,
    run_started,
)

import taichi_anim as ta
from taichi_anim import stepper as stepper_module

SIZES = (32, 48, 64, 80, 96, 112, 128, 192, 256)
QUICK_SIZES = (32, 96)
MODES = ("steps", "launches", "serial_frame")
SUBSTEPS, FRAME_DT = 16, 1 / 60
FRAMES, ROUNDS = 30, 3


def build(n: int):
    j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    x = np.stack([0.1 * i.ravel(), np.zeros(n * n), 0.1 * j.ravel()], axis=1)
    mass = np.full(n * n, 0.1)
    mass[[0, n - 1]] = 0.0
    b = ta.Builder()
    b.add_particles(x, mass=mass)
    b.add_springs(warp_springs(n), stiffness=1000.0, damping=10.0)
    b.add_force_gravity((0.0, -9.81, 0.0))
    model = b.finalize()
    integ = ta.make_integrator("symplectic_euler", check_every=SUBSTEPS)
    return model, model.state(), integ


def make_run(n: int, mode: str):
    """A model, state and stepper forced to `mode`, and its first frame [s] (compile included) plus two
    warm-up frames."""
    model, state, integ = build(n)
    st = integ.stepper_for(model)
    st._frame_mode = {"mode": mode, "reason": "benchmark"}
    t0 = clock()
    st.advance(state, FRAME_DT / SUBSTEPS, SUBSTEPS)
    state.particle_x.to_numpy()
    first = clock() - t0
    for _ in range(2):
        st.advance(state, FRAME_DT / SUBSTEPS, SUBSTEPS)
    return st, state, first


def frame_times(run, frames: int) -> tuple[list[float], np.ndarray, float]:
    """(ms per timed frame, final positions, cores busy) of `frames` more frames of one run."""
    st, state, _ = run
    h = FRAME_DT / SUBSTEPS
    out = []
    c0 = sum(os.times()[:2])
    w0 = clock()
    for _ in range(frames):
        a = clock()
        st.advance(state, h, SUBSTEPS)
        state.particle_x.to_numpy()
        out.append((clock() - a) * 1e3)
    busy = (sum(os.times()[:2]) - c0) / (clock() - w0)
    return out, state.particle_x.to_numpy(), busy


def measure(sizes, frames: int, rounds: int) -> list[dict]:
    rows = []
    for n in sizes:
        # A fresh runtime per size: Taichi holds a bounded number of field trees (many models crash it).
        ta.init("cpu", log_level=ti.ERROR)
        model, _, _ = build(n)
        row = {"n": n, "work": model.work, "modes": {}}
        chosen = ta.make_integrator("symplectic_euler").stepper_for(model).frame_mode()
        row["chosen"] = chosen
        finals = {}
        per_mode = {m: {"medians": [], "busy": []} for m in MODES}
        runs = {m: make_run(n, m) for m in MODES}  # every mode runs the same frames: bitwise comparable
        for _ in range(rounds):
            for mode in MODES:
                times, x, busy = frame_times(runs[mode], frames)
                per_mode[mode]["medians"].append(statistics.median(times))
                per_mode[mode]["busy"].append(busy)
                per_mode[mode]["first_s"] = runs[mode][2]
                finals[mode] = x
        for mode in MODES:
            d = per_mode[mode]
            row["modes"][mode] = {
                "ms_per_frame": statistics.median(d["medians"]),
                "round_medians": d["medians"],
                "cores_busy": statistics.median(d["busy"]),
                "first_frame_s": d["first_s"],
                "bitwise_equal_to_steps": bool(np.array_equal(finals[mode], finals["steps"])),
            }
        best = min(MODES, key=lambda m: row["modes"][m]["ms_per_frame"])
        row["fastest"] = best
        log(
            f"{n}^2 (work {model.work}): "
            + ", ".join(f"{m} {row['modes'][m]['ms_per_frame']:.2f} ms" for m in MODES)
            + f"; fastest {best}, chosen {chosen['mode']}"
        )
        rows.append(row)
    return rows


def report(rows, args, started: dict, elapsed: float) -> str:
    table = []
    for r in rows:
        m = r["modes"]
        table.append(
            [f"{r['n']}²", r["work"]]
            + [f"{m[k]['ms_per_frame']:.2f} ({m[k]['cores_busy']:.2f})" for k in MODES]
            + [
                r["fastest"],
                r["chosen"]["mode"],
                "yes" if all(m[k]["bitwise_equal_to_steps"] for k in MODES) else "NO",
            ]
        )
    threshold = stepper_module.FRAME_SERIAL_BELOW
    return "\n".join(
        [
            "## Frame fusion: one launch per frame, per substep, or per step",
            "",
            f"Regenerate: `{command_line(args, 'frame_fusion.py')}` (took {elapsed / 60:.1f} min).",
            "",
            "Warp's cloth layout (k = 1000 N/m, damping 10 kg/s, 0.1 kg per vertex), symplectic "
            f"Euler, {SUBSTEPS} substeps per 1/60 s frame, f32; {FRAMES} frames timed per mode after 3 "
            f"warm-up frames, modes alternating over {ROUNDS} rounds, median of the rounds' medians; each "
            "frame copies the positions to NumPy. Cells: ms per frame (cores busy). work = particles + "
            "spring entries (2 per spring), the size `frame_mode` decides on: serial_frame below "
            f"{threshold} on the CPU, launches above.",
            "",
            md_table(
                ["grid", "work", "steps", "launches", "serial_frame", "fastest", "chosen", "bitwise equal"],
                table,
            ),
            "",
            machine_section(started),
        ]
    )


def main(argv=None) -> int:
    args = parse_args(__doc__.splitlines()[0], argv)
    md_path, out_dir = output_paths(args)
    started = run_started()
    ta.init("cpu", log_level=ti.ERROR)
    t0 = time.perf_counter()
    quick = args.quick
    rows = measure(QUICK_SIZES if quick else SIZES, 10 if quick else FRAMES, 1 if quick else ROUNDS)
    elapsed = time.perf_counter() - t0
    text = report(rows, args, started, elapsed)
    publish(md_path, out_dir, "frame_fusion", text, rows, elapsed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
