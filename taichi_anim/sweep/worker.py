"""One run of a sweep, in a Python process of its own (runs.run_one starts it with the task as JSON).

It starts Taichi, builds the scene, runs it with run_scene (which writes run.json into the run's folder,
with the sweep's parameters under settings["sweep"]) and then saves the final state beside it as
final_state.npz: x (N,3) [m] every particle slot's position, alive (N,) bool, cpu_frame_s (F,) [s] the
process CPU time (all threads) of each frame's simulation. A failure prints one line starting with
ERROR_MARK (after the traceback) and exits nonzero (a signal's run: 128 + its number)."""

from __future__ import annotations

import json
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import taichi as ti

from .. import runtime
from ..io.atomic import atomic_path
from ..io.manifest import check_run_folder
from ..scenes import runner
from .params import load_build

FINAL_NAME = "final_state.npz"
ERROR_MARK = "taichi-anim sweep: error: "


def run(task: dict) -> None:
    """Run `task` (see runs.make_task) and save its final state."""
    out = Path(task["out_dir"])
    check_run_folder(out)  # busy or unusable: stop before the previous final state is removed
    (out / FINAL_NAME).unlink(missing_ok=True)
    opts = task["run"]
    arch = opts.get("arch", "cpu")
    # Threads: TI_CPU_MAX_NUM_THREADS. Capacity buckets unless the sweep turns them off: runs of other
    # sizes in one bucket then find every kernel in the cache the warm-up filled.
    runtime.init(arch, precision=opts.get("precision", "f32"), size_buckets=opts.get("size_buckets", True))
    scene = load_build(task["scene"])(**task["build"])
    cpu_frame_s: list[float] = []
    advance = scene.advance_frame

    def timed_advance():
        c0 = time.process_time()
        advance()
        ti.sync()
        cpu_frame_s.append(time.process_time() - c0)

    scene.advance_frame = timed_advance  # the runner calls it once per frame
    sweep = {"run_id": task["run_id"], "params": task["params"], "token": task["token"]}
    settings = {"sweep": sweep, "arch_requested": arch, "arch_choice": runtime.arch_choice()}
    if "seed" in task["build"]:
        settings["seed"] = task["build"]["seed"]
    runner.run_scene(
        scene,
        frames=opts.get("frames") or scene.frames,
        out_dir=out,
        export=opts.get("export", True),
        export_format=opts.get("export_format", "ply"),
        progress=False,
        extra_settings=settings,
        video=opts.get("video"),
        color_by=opts.get("color_by"),
    )
    state = scene.state
    with atomic_path(out / FINAL_NAME) as tmp, open(tmp, "wb") as f:
        np.savez(f, x=state.positions(), alive=state.alive_mask(), cpu_frame_s=np.asarray(cpu_frame_s))


def main(argv: list[str] | None = None) -> int:
    """Run the task given as JSON in argv[0]; returns the exit status."""
    task = json.loads((sys.argv[1:] if argv is None else argv)[0])
    for path in task.get("sys_path", ()):  # so "module:function" scenes import as in the sweep's process
        if path not in sys.path:
            sys.path.append(path)
    try:
        run(task)
    except BaseException as e:  # every way out is reported in one line the sweep reads back
        sys.stdout.flush()
        traceback.print_exc()
        message = " ".join(str(e).split()) or type(e).__name__
        print(f"{ERROR_MARK}{type(e).__name__}: {message}", file=sys.stderr, flush=True)
        if isinstance(e, SystemExit):
            return e.code if isinstance(e.code, int) and e.code else 1
        return int(getattr(e, "exit_code", 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
