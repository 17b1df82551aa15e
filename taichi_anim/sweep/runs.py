"""A sweep's unit of work: one task, run in a fresh Python process (worker.py) by `run_one`, which any
concurrent.futures executor can call (a local pool, a Dask cluster's workers). A process per run is what
lets a sweep go on past anything one run does: an exception, a crash, a nonzero exit, or a run past its
timeout, which is stopped with SIGTERM (run_scene then records the frames so far as "interrupted") and,
GRACE_S later, SIGKILL. The row of a run is read back from its run.json and final_state.npz."""

from __future__ import annotations

import json
import os
import secrets
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from ..io.manifest import MANIFEST_NAME, read_manifest
from ..scenes.runner import health_brief
from .params import RUN_OPTIONS
from .worker import ERROR_MARK, FINAL_NAME

LOG_NAME = "sweep_worker.log"  # the worker's output (Taichi's lines, a traceback), in the run's folder
GRACE_S = 10.0  # after SIGTERM, time for the frame in progress and run.json before SIGKILL
_PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])  # the folder holding taichi_anim

_WORKER_CODE = "import sys; from taichi_anim.sweep.worker import main; sys.exit(main())"
_live: set[subprocess.Popen] = set()  # worker processes started by this process, for stop_all
_live_lock = threading.Lock()


def make_task(scene: str, run_id: str, out: Path, params: dict, build_names, *, threads, timeout) -> dict:
    """A run as plain JSON data: the scene spec, its folder, its build and run options (params split by
    name: run options go to run_scene and Taichi, the rest, and run options the build also takes, to
    the build), a token that marks its run.json as its own, and the Taichi CPU threads and timeout [s]."""
    params = json.loads(json.dumps(params))  # tuples as lists: what run.json gives back
    build = {k: v for k, v in params.items() if k not in RUN_OPTIONS or (build_names and k in build_names)}
    return {
        "scene": scene,
        "run_id": run_id,
        "out_dir": str(out / run_id),
        "params": params,
        "build": build,
        "run": {k: v for k, v in params.items() if k in RUN_OPTIONS},
        "token": secrets.token_hex(8),
        "sys_path": [p for p in sys.path if p],
        "threads": threads,
        "timeout": timeout,
    }


def run_one(task: dict) -> tuple[dict, dict | None]:
    """Run `task` in a new Python process and return (its row, its final state {"x", "alive"} or None)."""
    out = Path(task["out_dir"])
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [_PACKAGE_ROOT, env.get("PYTHONPATH")]))
    if task.get("threads"):
        env["TI_CPU_MAX_NUM_THREADS"] = str(task["threads"])  # read by ti.init in the worker
    # -c, not -m: the package (imported first by -m) already imports worker.py, which runpy warns about.
    cmd = [sys.executable, "-c", _WORKER_CODE, json.dumps(task)]
    timed_out, t0 = False, time.perf_counter()
    with open(out / LOG_NAME, "wb") as log:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env)
        with _live_lock:
            _live.add(proc)
        try:
            rc = proc.wait(timeout=task.get("timeout"))
        except subprocess.TimeoutExpired:
            timed_out, rc = True, _stop(proc)
        except BaseException:
            _stop(proc)
            raise
        finally:
            with _live_lock:
                _live.discard(proc)
    return collect(task, rc=rc, seconds=time.perf_counter() - t0, timed_out=timed_out)


def _stop(proc: subprocess.Popen) -> int:
    proc.terminate()  # SIGTERM: run_scene stops after the frame in progress and writes run.json
    try:
        return proc.wait(timeout=GRACE_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def stop_all() -> None:
    """Stop the worker processes this process started (when the sweep itself is interrupted)."""
    with _live_lock:
        live = list(_live)
    for proc in live:
        if proc.poll() is None:
            proc.terminate()


def completed(task: dict) -> tuple[dict, dict | None] | None:
    """(row, final state) of the run already in the task's folder, if its run.json says complete for the
    same parameters and its final state is there; else None (the run must be done)."""
    out = Path(task["out_dir"])
    doc = _manifest(out)
    if doc.get("status") != "complete" or not (out / FINAL_NAME).is_file():
        return None
    if ((doc.get("settings") or {}).get("sweep") or {}).get("params") != task["params"]:
        return None
    return collect(task, rc=0, seconds=None, timed_out=False, skipped=True)


def _manifest(out: Path) -> dict:
    try:
        doc = read_manifest(out / MANIFEST_NAME)
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def collect(task: dict, *, rc: int, seconds, timed_out: bool, skipped: bool = False):
    """The row of a finished (or skipped) task, and its final state when it completed."""
    out = Path(task["out_dir"])
    doc = _manifest(out)
    sweep = (doc.get("settings") or {}).get("sweep") or {}
    # A run.json left by an earlier run (this one failed before run_scene started) is not this run's.
    ours = sweep.get("params") == task["params"] if skipped else sweep.get("token") == task["token"]
    timings = (doc.get("timings") or {}) if ours else {}
    status = doc.get("status") if ours else None
    message = ((doc.get("error") or {}).get("message") or "") if ours else ""
    if timed_out:
        done = timings.get("frames_done")
        status = "timeout"
        message = f"stopped at the timeout of {task['timeout']:g} s" + (
            f" after {done} frames" if done is not None else ""
        )
    elif rc != 0 or status in (None, "running"):
        status = status if status not in (None, "running", "complete") else "failed"
        message = message or _log_error(out) or _exit_text(rc)
    final, cpu = None, None
    if status == "complete":
        try:
            with np.load(out / FINAL_NAME) as data:
                final = {"x": data["x"], "alive": data["alive"]}
                cpu = _cpu_per_frame(data["cpu_frame_s"], timings.get("compile_s"))
        except (OSError, ValueError, KeyError) as e:
            status, message = "failed", f"{FINAL_NAME} cannot be read: {e}"
    health = (doc.get("health") or {}) if ours else {}
    row = {"run_id": task["run_id"], "status": status, "skipped": skipped, "message": message}
    row.update({f"param_{k}": v for k, v in task["params"].items()})
    row.update(
        frames=timings.get("frames"),
        frames_done=timings.get("frames_done"),
        steps=timings.get("steps"),
        integrator=timings.get("integrator"),
        substeps=timings.get("substeps"),
        wall_ms_per_frame=timings.get("ms_per_frame"),
        cpu_ms_per_frame=cpu,
        compile_s=timings.get("compile_s"),
        compile_kernels=timings.get("compile_kernels"),
        first_frame_s=timings.get("first_frame_s"),
        run_s=seconds,
        particles_alive=timings.get("particles_alive"),
        health_events=sum(v for v in (health.get("counts") or {}).values() if isinstance(v, int)),
        health=health_brief(health),
        out_dir=str(out),
    )
    return row, final


def _cpu_per_frame(cpu_frame_s: np.ndarray, compile_s) -> float | None:
    """ms of CPU per steady frame, as run.json's ms_per_frame: the median after the first frame (with
    one frame, the first less its compile time)."""
    if len(cpu_frame_s) > 1:
        return float(np.median(cpu_frame_s[1:])) * 1e3
    if len(cpu_frame_s) == 1:
        return max(float(cpu_frame_s[0]) - (compile_s or 0.0), 0.0) * 1e3
    return None


def _log_error(out: Path) -> str:
    try:
        lines = (out / LOG_NAME).read_text(errors="replace").splitlines()
    except OSError:
        return ""
    marked = [line[len(ERROR_MARK) :] for line in lines if line.startswith(ERROR_MARK)]
    return marked[-1] if marked else ""


def _exit_text(rc: int) -> str:
    if rc < 0:
        try:
            return f"the worker process was killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"the worker process was killed by signal {-rc}"
    return f"the worker process exited with status {rc}"
