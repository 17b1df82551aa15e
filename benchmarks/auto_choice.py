"""integrator="auto" against measurement: for each cloth demo, every candidate method run at the substeps
the chooser gives it, timed per frame, next to the chooser's estimated cost; the chosen method must be
the measured fastest. Also the figures behind the cost model's constants (taichi_anim/integrators/
choice.py): an implicit step's cost in explicit steps, and PCG iterations against the estimate.

Scenes: the `cloth` (48², springs), `drape` (64², springs, ball and floor) and `flag` (40 x 27, StVK
membrane + bending + aerodynamics) demos at their defaults. Candidates: symplectic Euler and RK4 at the
smallest stable substep count per 1/60 s frame (stability limit of the highest frequency, Lanczos, x 0.8),
implicit Euler with the demo's PCG (tol 1e-4; flag 1e-3) at 4 steps per frame. Each candidate: a fresh
scene, 2 warm-up frames (the first holds the JIT compile), then frames timed one by one with `ti.sync()`
before each clock read until FRAMES frames or BUDGET_S seconds (at least 3): median ms per frame.
f32, CPU, Taichi's default threads.

    .venv/bin/python benchmarks/auto_choice.py           # benchmarks/results/auto_choice.{md,json}
    .venv/bin/python benchmarks/auto_choice.py --quick   # smoke: the cloth demo at 24², benchmarks/out/
"""

from __future__ import annotations

import statistics
import time

import taichi as ti
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
from taichi_anim.integrators import choice as choice_module
from taichi_anim.scenes import make_scene

SCENES = {"cloth": {}, "drape": {}, "flag": {}}
QUICK_SCENES = {"cloth": {"resolution": 24}}
FRAMES, BUDGET_S = 30, 10.0


def time_frames(scene, frames: int, budget: float) -> dict:
    t0 = clock()
    scene.advance_frame()
    first = clock() - t0
    scene.advance_frame()
    times = []
    while len(times) < frames and (sum(times) < budget or len(times) < 3):
        a = clock()
        scene.advance_frame()
        times.append(clock() - a)
    out = {"ms_per_frame": 1e3 * statistics.median(times), "frames": len(times), "first_frame_s": first}
    solver = getattr(scene.integrator, "linear_solver", None)
    if solver is not None and solver.solves:
        out["pcg_iterations"] = solver.total_iterations / solver.solves
        out["ms_per_step"] = out["ms_per_frame"] / scene.substeps
    else:
        out["ms_per_step"] = out["ms_per_frame"] / scene.substeps
    return out


def measure(scenes: dict, frames: int, budget: float) -> list[dict]:
    rows = []
    for name, options in scenes.items():
        auto = make_scene(name, **options, integrator="auto")
        record = auto.integrator_choice
        row = {"scene": name, "options": options, "choice": record, "measured": {}}
        for cand, est in record["candidates"].items():
            if est["evaluations_per_frame"] is None:
                continue
            kw = dict(options, integrator=cand)
            if cand != "implicit_euler":
                kw["substeps"] = est["substeps"]
            scene = make_scene(name, **kw)
            m = time_frames(scene, frames, budget)
            m["substeps"] = scene.substeps
            row["measured"][cand] = m
            log(f"{name} {cand} x{scene.substeps}: {m['ms_per_frame']:.2f} ms/frame (est {est['note']})")
        fastest = min(row["measured"], key=lambda k: row["measured"][k]["ms_per_frame"])
        row["fastest"] = fastest
        row["chosen_is_fastest"] = fastest == record["chosen"]
        explicit = row["measured"].get("symplectic_euler")
        implicit = row["measured"].get("implicit_euler")
        if explicit and implicit and "pcg_iterations" in implicit:
            ratio = implicit["ms_per_step"] / explicit["ms_per_step"]
            it = implicit["pcg_iterations"]
            row["implicit_step_in_explicit_steps"] = ratio
            row["cg_iteration_in_explicit_steps"] = (ratio - choice_module.IMPLICIT_ASSEMBLY) / it
        rows.append(row)
    return rows


def report(rows, args, started: dict, elapsed: float) -> str:
    table, fit = [], []
    for r in rows:
        for cand, m in r["measured"].items():
            est = r["choice"]["candidates"][cand]
            mark = " (chosen)" if cand == r["choice"]["chosen"] else ""
            table.append(
                [
                    r["scene"],
                    cand + mark,
                    m["substeps"],
                    f"{est['evaluations_per_frame']:.0f}",
                    f"{m['ms_per_frame']:.1f}",
                    f"{m['ms_per_step']:.3f}",
                    f"{m.get('pcg_iterations', float('nan')):.1f}" if "pcg_iterations" in m else "–",
                    est["note"],
                ]
            )
        if "cg_iteration_in_explicit_steps" in r:
            fit.append(
                [
                    r["scene"],
                    f"{r['implicit_step_in_explicit_steps']:.0f}",
                    f"{r['measured']['implicit_euler']['pcg_iterations']:.1f}",
                    f"{r['cg_iteration_in_explicit_steps']:.2f}",
                ]
            )
    verdict = "; ".join(
        f"{r['scene']}: chosen {r['choice']['chosen']}, measured fastest {r['fastest']}"
        + ("" if r["chosen_is_fastest"] else " (**MISMATCH**)")
        for r in rows
    )
    return "\n".join(
        [
            "## integrator='auto': the chooser against measured frame times",
            "",
            f"Regenerate: `{command_line(args, 'auto_choice.py')}` (took {elapsed / 60:.1f} min).",
            "",
            "Each cloth demo at its defaults; every candidate at the substeps the chooser gives it "
            "(explicit: smallest count within 0.8 x the stability limit; implicit Euler: the demos' 4 steps "
            f"per frame and PCG), median of up to {FRAMES} frames after 2 warm-up frames, f32, CPU. "
            "Estimated cost: force evaluations per frame from the cost model "
            "(taichi_anim/integrators/choice.py).",
            "",
            f"**Verdict**: {verdict}.",
            "",
            md_table(
                [
                    "scene",
                    "method",
                    "substeps",
                    "estimated evaluations / frame",
                    "ms / frame",
                    "ms / step",
                    "PCG iterations",
                    "estimate",
                ],
                table,
            ),
            "",
            "Cost-model constants from these runs (an implicit step in explicit steps of the same scene; "
            "the CG iteration's cost after subtracting IMPLICIT_ASSEMBLY = "
            f"{choice_module.IMPLICIT_ASSEMBLY}; the model uses CG_ITERATION = "
            f"{choice_module.CG_ITERATION}):",
            "",
            md_table(
                ["scene", "implicit step / explicit step", "PCG iterations", "CG iteration / explicit step"],
                fit,
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
    rows = measure(QUICK_SCENES if args.quick else SCENES, 5 if args.quick else FRAMES, BUDGET_S)
    elapsed = time.perf_counter() - t0
    text = report(rows, args, started, elapsed)
    publish(md_path, out_dir, "auto_choice", text, rows, elapsed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
