"""Run a scene for N frames: step, export each frame atomically, render the last one, write run.json.

Timings: the first step runs alone (it includes JIT compilation, reported as compile_s = first step
minus a steady step); step time is measured with `ti.sync()` before every clock read and kept apart
from export and render time."""

import time
from pathlib import Path

import numpy as np
import taichi as ti

from ..io.manifest import write_manifest
from ..runtime import backend_name
from .base import Scene


def run_scene(
    scene: Scene,
    *,
    frames: int,
    out_dir,
    export: bool = True,
    progress: bool = True,
    viewer=None,
    extra_settings: dict | None = None,
) -> dict:
    """Simulate `frames` frames of `scene`; return the summary (also written to out_dir/run.json)."""
    from tqdm import tqdm

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model, state, integ = scene.model, scene.state, scene.integrator
    step_times: list[float] = []
    export_s = 0.0
    files = 0
    first_step_s = None
    bar = tqdm(range(frames), desc=scene.name, unit="frame", disable=not progress, leave=False)
    for frame in bar:
        for _ in range(scene.substeps):
            ti.sync()
            t0 = time.perf_counter()
            integ.step(model, state, scene.dt)
            ti.sync()
            dt_wall = time.perf_counter() - t0
            if first_step_s is None:
                first_step_s = dt_wall
            else:
                step_times.append(dt_wall)
        if export:
            t0 = time.perf_counter()
            files += len(scene.export_frame(out, frame))
            export_s += time.perf_counter() - t0
        if viewer is not None:
            snap = state.snapshot()
            if not viewer.draw(snap.x, snap.color, scene.point_radius):
                break
    bar.close()
    t0 = time.perf_counter()
    png = scene.render(out / f"{scene.name}_last.png")
    render_s = time.perf_counter() - t0
    steady = float(np.median(step_times)) if step_times else float(first_step_s or 0.0)
    alive = int(state.alive_mask().sum())
    summary = {
        "scene": scene.name,
        "frames": frames,
        "steps": state.step_count,
        "simulated_s": state.time,
        "particles_alive": alive,
        "ms_per_step": steady * 1e3,
        "ms_per_step_mean": float(np.mean(step_times)) * 1e3 if step_times else None,
        "first_step_s": first_step_s,
        "compile_s": max((first_step_s or 0.0) - steady, 0.0),
        "export_s": export_s,
        "render_s": render_s,
        "files_written": files,
        "png": str(png),
        "arch": backend_name(),
    }
    spheres = integ.stepper_for(model).contacts
    if spheres is not None:
        overlap, contacts = spheres.overlap_stats(model, state)
        summary["neighbor_search"] = spheres.neighbors.describe()
        summary["sphere_contacts"] = contacts
        summary["max_overlap_over_radius"] = overlap / spheres.min_radius
    solver = getattr(scene.integrator, "linear_solver", None)
    if model.coupled and solver is not None and solver.solves:
        summary["linear_solver"] = solver.name
        summary["mean_iterations"] = solver.total_iterations / solver.solves
        summary["last_residual"] = solver.last.residual
    settings = {**scene.settings(), "frames": frames, "export": export, **(extra_settings or {})}
    summary["manifest"] = str(write_manifest(out, settings, summary))
    return summary


def summary_line(s: dict) -> str:
    """One line per run: particles alive, ms per step, compile time, where the output went."""
    spheres = ""
    if "neighbor_search" in s:
        spheres = (
            f"neighbour search {s['neighbor_search']}, {s['sphere_contacts']} contacts, largest overlap "
            f"{100 * s['max_overlap_over_radius']:.2f}% of the radius, "
        )
    if "linear_solver" in s:
        spheres += (
            f"{s['linear_solver']} {s['mean_iterations']:.1f} iterations per step (last residual "
            f"{s['last_residual']:.1e}), "
        )
    return (
        f"{s['scene']}: {s['frames']} frames, {s['steps']} steps on {s['arch']}: {s['particles_alive']} "
        f"particles alive, {spheres}{s['ms_per_step']:.3f} ms/step, compile {s['compile_s']:.2f} s, export "
        f"{s['export_s']:.2f} s ({s['files_written']} files), picture {s['png']}"
    )
