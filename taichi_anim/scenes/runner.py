"""Run a scene for N frames: step, export each frame atomically, render the last one, write run.json.

The output folder follows io/manifest.py's policy: the run holds the folder's lock (one run per folder;
a second one stops with FolderBusyError before it touches anything), the previous run's files there are
removed first, run.json says "running" while the run goes on and "complete", "diverged", "interrupted"
or "failed" after it, with every file written (size and SHA-256) and the run's health (solver, stability
and divergence reports). Every option is checked before anything is removed. The divergence watch is
read before each frame is exported, so with `check_every` > 1 no frame after a bad step is written.

Signals (interrupts.py): SIGINT, SIGTERM and SIGHUP during a run stop it after the frame in progress;
the frames before are kept (the USD stage and the video are saved with them, as after a divergence),
the picture of the last frame is skipped, run.json says "interrupted" with the signal, and run_scene
raises RunInterrupted (a KeyboardInterrupt) carrying the signal and the summary.

Timings: a frame's substeps run as one call (Stepper.advance, launched as Stepper.frame_mode says,
recorded in run.json) timed with `ti.sync()` before every clock read. The first frame also compiles the
kernels: compile_s is the time Taichi spent compiling (or loading from its offline cache) the kernels
first used in that frame, measured (compile_clock.py), with compile_kernels the number of kernel
instances; ms_per_frame is a steady frame (the median of the frames after the first; with one frame,
the first minus its compile time) and ms_per_step that over its substeps; export and render time are
kept apart.

Video (`video=PATH`): each frame is rendered (Scene.render_frame) after it is exported and appended to
an MP4 or GIF at the demo's frame rate, 1 / scene.frame_dt (render/video.py), published when the run
ends; run.json's "video" records its path, fps, frames, size and the milliseconds per rendered frame
(rendering and encoding; the median after the first, which compiles the renderer). A video outside the
output folder is locked on its own (`.clip.mp4.taichi-anim.lock` beside `clip.mp4`), and the
temporaries a killed run left under its name there are removed."""

import contextlib
import os
import time
from pathlib import Path

import numpy as np
import taichi as ti

from .. import validate
from ..compile_clock import CompileClock
from ..errors import DivergenceError, OutputError, ParameterError
from ..interrupts import RunInterrupted, SignalStop, stop_on_signals
from ..io.atomic import recording_files, remove_stale_temporaries
from ..io.export import frame_numbering
from ..io.lock import hold_lock, lock_path_for
from ..io.manifest import (
    check_output_folder,
    error_record,
    locked_run_folder,
    prepare_run_folder,
    write_manifest,
)
from ..io.usd import UsdStageWriter
from ..render import VideoWriter
from ..runtime import backend_name
from .base import Scene

_EXPORT_FORMATS = ("ply", "usd", "both")
_VIDEO_FORMATS = (".mp4", ".gif")  # what render/video.py writes


def run_scene(
    scene: Scene,
    *,
    frames: int,
    out_dir,
    export: bool = True,
    progress: bool = True,
    viewer=None,
    extra_settings: dict | None = None,
    export_format: str = "ply",
    video=None,
    color_by: str | None = None,
) -> dict:
    """Simulate `frames` frames of `scene`; return the summary (also written to out_dir/run.json).

    export_format: "ply" (a file per item and frame), "usd" (one stage, out_dir/<scene>.usd, saved at
    the end: io/usd.py) or "both"; with export=False nothing is written.
    video: None, "" (out_dir/<scene>.mp4) or the path of an MP4 or GIF of the run; color_by: what the
    pictures colour points by ("speed", "height", "age", "none"; None: the scene's default).

    Every option is checked before anything in out_dir is touched. Raises FolderBusyError (an
    OutputError) at once if another run holds out_dir (or the video), RunInterrupted (a
    KeyboardInterrupt) after a SIGINT, SIGTERM or SIGHUP stopped the run between frames, and whatever
    else stopped the run (DivergenceError, OutputError, ...), each after recording it in run.json."""
    frames = validate.count("frames", frames, 1)
    validate.choice("export_format", export_format, _EXPORT_FORMATS)
    out = check_output_folder(out_dir)
    video = video_target(video, out, scene.name)
    options = dict(
        export=export,
        export_format=export_format,
        progress=progress,
        viewer=viewer,
        extra_settings=extra_settings,
        video=video,
        color_by=color_by,
    )
    with stop_on_signals() as stop, contextlib.ExitStack() as held:
        held.enter_context(locked_run_folder(out))
        outside = video is not None and video.parent.resolve() != out.resolve()
        if outside:  # a video beside the user's files: locked on its own, before anything is removed
            try:
                video.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise OutputError(f"cannot write the video {video}: {e.strerror}") from e
            held.enter_context(hold_lock(lock_path_for(video), what=f"the video {video}"))
        removed = prepare_run_folder(out, names=[scene.name])
        if outside:
            removed += remove_stale_temporaries(video.parent, target=video)
        return _run(scene, frames, out, removed, stop, **options)


def video_target(video, out_dir, name: str, *, option: str = "video") -> Path | None:
    """The path `video` (None: no video; "": out_dir/<name>.mp4) stands for, checked before a run touches
    anything: ParameterError naming `option` unless it names an .mp4 or .gif file, OutputError unless it
    can be written there (a folder of that name, a read-only or impossible place)."""
    if video is None:
        return None
    text = os.fspath(video)
    path = Path(out_dir) / f"{name}.mp4" if text == "" else Path(text)
    if text.endswith(("/", os.sep)) or path.suffix.lower() not in _VIDEO_FORMATS:
        bare = path.name.lower() in _VIDEO_FORMATS  # ".mp4" is a hidden file's name, not a suffix
        why = " (a suffix without a file name)" if bare else ""
        raise ParameterError(f"{option} must name an .mp4 or .gif file, got {text!r}{why}")
    if path.is_dir():
        raise OutputError(f"cannot write the video {path}: a folder of that name exists")
    check_output_folder(path.parent, what="the video's folder")
    return path


def _run(scene, frames, out, removed, stop: SignalStop, **options) -> dict:
    from tqdm import tqdm

    export, export_format = options["export"], options["export_format"]
    stepper = scene.integrator.stepper_for(scene.model)
    settings = {**scene.settings(), "frames": frames, "export": export, "export_format": export_format}
    settings.update(options["extra_settings"] or {})
    write_manifest(out, settings, {}, status="running", health=stepper.health.to_dict())
    run = {"frame_times": [], "first_frame_s": None, "export_s": 0.0, "render_s": 0.0, "frames_done": 0}
    run.update(compile_s=None, compile_kernels=None, stop=stop, solver_frames={})
    run.update(video_path=options["video"], color_by=options["color_by"], video_times=[], video=None)
    files: list[dict] = []  # what the run published, in order (see recording_files)
    status, failure = "failed", None
    try:
        with recording_files(out) as files:
            formats = () if not export else ("ply", "usd") if export_format == "both" else (export_format,)
            if not stop.requested:  # a signal while the folder was prepared: no frame at all
                _simulate(
                    scene, stepper, frames, out, formats, options["progress"], options["viewer"], run, tqdm
                )
        if stop.requested:
            raise stop.interrupted(frames_done=run["frames_done"], frames=frames)
        status = "complete"
    except DivergenceError as e:
        status, failure = "diverged", e
        raise
    except RunInterrupted as e:
        status, failure = "interrupted", e
        raise
    except BaseException as e:
        failure = e
        raise
    finally:
        stop.forcible = False  # from here on a second signal waits: run.json must be written whole
        summary = _summary(scene, stepper, out, frames, run, files, status == "complete")
        summary["status"] = status
        summary["files_removed"] = len(removed)
        try:
            timings = {k: v for k, v in summary.items() if k != "health"}
            summary["manifest"] = str(
                write_manifest(
                    out,
                    settings,
                    timings,
                    status=status,
                    files=files,
                    health=summary["health"],
                    error=None if failure is None else error_record(failure),
                )
            )
        except OutputError as e:
            if failure is None:
                raise
            # Keep the original error; the run.json left behind says "running", i.e. not complete.
            failure.add_note(f"run.json could not be updated: {e}")
        if isinstance(failure, RunInterrupted):
            failure.summary = summary
    return summary


def _usd_stage(scene, out, formats):
    """The run's UsdStageWriter (out/<scene>.usd), or a null context without USD export."""
    if "usd" not in formats:
        return contextlib.nullcontext()
    return UsdStageWriter(
        out / f"{scene.name}.usd",
        fps=1.0 / scene.frame_dt,
        name=scene.name,
        point_radius=scene.point_radius,
        colliders=scene.model.colliders,
        bounds=scene.bounds,
    )


def _simulate(scene, stepper, frames, out, formats, progress, viewer, run, tqdm) -> None:
    state = scene.state
    desc = scene.name if run["video_path"] is None else f"{scene.name} (+video)"
    bar = tqdm(range(frames), desc=desc, unit="frame", disable=not progress, leave=False)
    video = None if run["video_path"] is None else VideoWriter(run["video_path"], fps=1.0 / scene.frame_dt)
    try:
        # A stage is saved when the block ends, also when a frame diverges: with the frames before it.
        outputs = frame_numbering(frames), _usd_stage(scene, out, formats), video or contextlib.nullcontext()
        with outputs[0], outputs[1] as stage, outputs[2]:
            for frame in bar:
                ti.sync()
                first = run["first_frame_s"] is None
                with CompileClock() if first else contextlib.nullcontext() as clock:
                    t0 = time.perf_counter()
                    scene.advance_frame()
                    ti.sync()
                    dt_wall = time.perf_counter() - t0
                if first:
                    run.update(first_frame_s=dt_wall, compile_s=clock.seconds, compile_kernels=clock.kernels)
                else:
                    run["frame_times"].append(dt_wall)
                # The watch may be read only every check_every steps: read it now, so a frame after a
                # diverged step is never written.
                stepper.check(state, energy=True)
                _record_solver_frames(stepper, run["solver_frames"])
                items = None
                if formats:
                    t0 = time.perf_counter()
                    items = scene.frame_content()  # once for every format and the video
                    if "ply" in formats:
                        scene.export_frame(out, frame, items)
                    if stage is not None:
                        stage.add_frame(items, time=state.time)
                    run["export_s"] += time.perf_counter() - t0
                if video is not None:
                    t0 = time.perf_counter()
                    video.append(scene.render_frame(color_by=run["color_by"], items=items))
                    run["video_times"].append(time.perf_counter() - t0)
                    run["video"] = video.record()
                run["frames_done"] = frame + 1
                if viewer is not None:
                    snap = state.snapshot()
                    if not viewer.draw(snap.x, snap.color, scene.point_radius):
                        break
                if run["stop"].requested:
                    break  # a signal: stop between frames; the stage and video keep the frames so far
            if stage is not None:
                t0 = time.perf_counter()
                stage.save()
                run["export_s"] += time.perf_counter() - t0
    finally:
        bar.close()
    if run["stop"].requested:
        return  # stopping on a signal: no picture (a first render compiles the renderer)
    t0 = time.perf_counter()
    scene.render(out / f"{scene.name}_last.png", color_by=run["color_by"])
    run["render_s"] = time.perf_counter() - t0


def _summary(scene, stepper, out, frames, run, files, complete: bool) -> dict:
    model, state, integ = scene.model, scene.state, scene.integrator
    frame_times, first_frame_s, compile_s = run["frame_times"], run["first_frame_s"], run["compile_s"]
    if frame_times:
        steady = float(np.median(frame_times))
    else:  # one frame (or none): the first without its compile, where that was measured
        steady = max(float(first_frame_s or 0.0) - (compile_s or 0.0), 0.0)
    per_step = steady / scene.substeps
    png = [f["path"] for f in files if f["path"].endswith("_last.png")]
    summary = {
        "scene": scene.name,
        "frames": frames,
        "frames_done": run["frames_done"],
        "steps": state.step_count,
        "simulated_s": state.time,
        "ms_per_frame": steady * 1e3,
        "ms_per_step": per_step * 1e3,
        "ms_per_frame_mean": float(np.mean(frame_times)) * 1e3 if frame_times else None,
        "first_frame_s": first_frame_s,
        "compile_s": compile_s,
        "compile_kernels": run["compile_kernels"],
        "frame_mode": stepper.frame_mode(),
        "integrator": integ.name,
        "substeps": scene.substeps,
        "integrator_auto": scene.integrator_choice is not None,
        "export_s": run["export_s"],
        "render_s": run["render_s"],
        "video": None if run["video"] is None else {**run["video"], "ms_per_frame": _per_frame(run)},
        "files_written": len(files),
        "out_dir": str(out),
        "png": str(out / png[0]) if png else None,
        "arch": backend_name(),
        "health": stepper.health.to_dict(),
        "watchdog": stepper.watchdog.describe(),  # the divergence bounds in force (watchdog.py)
        "solver_frames": run["solver_frames"],  # per frame, from solvers that report (frame_stats)
    }
    if not complete:
        return summary  # the state may be non-finite or the runtime interrupted: report only the counts
    summary["particles_alive"] = int(state.alive_mask().sum())
    summary["rigid_bodies"] = int(state.model.rigid_count)
    spheres = stepper.contacts
    if spheres is not None:
        overlap, contacts = spheres.overlap_stats(model, state)
        summary["neighbor_search"] = spheres.neighbors.describe()
        summary["sphere_contacts"] = contacts
        summary["max_overlap_over_radius"] = overlap / spheres.min_radius
    solver = getattr(integ, "linear_solver", None)
    if model.coupled and solver is not None and solver.solves:
        summary["linear_solver"] = solver.name
        summary["mean_iterations"] = solver.total_iterations / solver.solves
        summary["last_residual"] = solver.last.residual
    return summary


def _record_solver_frames(stepper, record: dict) -> None:
    """Each solver that reports per frame (an optional `frame_stats()`: the liquid's pressure iterations
    and density errors) appends its frame's figures to run.json's `solver_frames` [name] list."""
    for solver in stepper.solvers:
        stats = getattr(solver, "frame_stats", None)
        if stats is not None:
            record.setdefault(solver.name, []).append(stats())


def _per_frame(run: dict) -> float:
    """Milliseconds per video frame, rendering and encoding: the median after the first frame (which
    holds the renderer's JIT compile)."""
    times = run["video_times"]
    return 1e3 * float(np.median(times[1:] if len(times) > 1 else times))


def health_brief(health: dict | None, *, limit: int = 4) -> str:
    """The non-zero health counters, e.g. "linear_unconverged 12, unstable_step 1", or ""."""
    counts = [(k, v) for k, v in sorted(((health or {}).get("counts") or {}).items()) if v]
    text = ", ".join(f"{k} {v}" for k, v in counts[:limit])
    if len(counts) > limit:
        text += f" (+{len(counts) - limit} more in run.json)"
    return text


def summary_line(s: dict) -> str:
    """One line per run: particles alive, ms per step, compile time, health, where the output went (and
    the status, when the run did not complete)."""
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
    health = health_brief(s.get("health"))
    health = f"health: {health}, " if health else ""
    status = "" if s.get("status", "complete") == "complete" else f" ({s['status']})"
    alive = s.get("particles_alive")
    alive = "" if alive is None else f"{alive} particles alive, "
    if s.get("rigid_bodies"):
        alive = ("" if not s.get("particles_alive") else alive) + f"{s['rigid_bodies']} rigid bodies, "
    method = f"{s['integrator']} x{s['substeps']}/frame" + (
        " (auto: cheapest stable)" if s["integrator_auto"] else ""
    )
    return (
        f"{s['scene']}{status}: {s['frames_done']} frames, {s['steps']} steps on {s['arch']} ({method}): "
        f"{alive}"
        f"{spheres}{health}{s['ms_per_frame']:.2f} ms/frame ({s['ms_per_step']:.3f} ms/step, "
        f"{s['frame_mode']['mode']}), compile {_seconds(s.get('compile_s'))}, "
        f"export {s['export_s']:.2f} s ({s['files_written']} files), picture {s['png']}"
        + _video_note(s.get("video"))
    )


def _seconds(value) -> str:
    return "not measured" if value is None else f"{value:.2f} s"


def _video_note(video: dict | None) -> str:
    if not video:
        return ""
    rate = f"{video['frames']} frames at {video['fps']:.4g}/s, {video['ms_per_frame']:.0f} ms/frame"
    return f", video {video['path']} ({rate})"
