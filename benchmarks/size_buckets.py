"""Capacity buckets (capacity.py) off and on: what they cost at run time, what they save in compiles, and
the memory the doubling takes.

1. Run time: ms per frame of the fountain and the cloth (symplectic Euler) at three sizes each, buckets off
   and on, each measurement a fresh process on a warm offline cache (the check: no size > 5 % slower);
   the other demos with a size option, and a liquid in a fixed tank (`tank`, this file's scene).
2. Compile across processes: two sizes in one bucket, each in its own process on one offline-cache folder
   (empty at the start): the kernels the second size adds to the cache, and both processes' compiles.
3. Compile in one process: the same two sizes one after the other (the first scene deleted and collected
   between), so buckets on reuse the first scene's fields from the pool.
4. Memory: the bytes of the particle arrays at each size of (1), off (count rows) and on (capacity rows).

Every measurement runs in its own process (`--worker SPEC`, a JSON dict), with TI_OFFLINE_CACHE_FILE_PATH
set to a folder of its mode, so nothing depends on ~/.cache/taichi or on an earlier measurement.

    .venv/bin/python benchmarks/size_buckets.py [--reps R] [--frames F] [--quick]
"""

import argparse
import gc
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from harness import Page, log, parse_args  # noqa: E402

# The build() keyword a size sets.
SIZE_OPTION = {
    "fountain": "particles",
    "cloth": "resolution",
    "flag": "resolution",
    "spheres": "particles",
    "layers": "resolution",
    "tablecloth": "resolution",
    "blobs": "particles",
    "tank": "layers",
}
# Cloth sizes that are not powers of two, so the padded rows are there (48^2 -> 4096 rows, 96^2 -> 16384);
# the flag: a membrane, bending and aerodynamics, stepped by implicit Euler with PCG (the linear solver's
# live row and block counts).
RUN_SIZES = {
    "fountain": (10_000, 100_000, 1_000_000),
    "cloth": (48, 96, 128),
    "flag": (40, 64),
    "spheres": (10_000, 100_000),
    # Cloth self-contact (two sheets; its BVHs, pair lists and guard), self-contact with a mesh collider
    # (the table), and the blob field of a jet.
    "layers": (24, 33),
    "tablecloth": (30, 48),
    "blobs": (1500, 6000),
    # A liquid (DFSPH, its walls' samples and neighbour grid) of 2,000 and 6,000 particles in one tank.
    "tank": (10, 30),
}
QUICK_RUN_SIZES = {
    "fountain": (2000,),
    "cloth": (16, 24),
    "flag": (20,),
    "spheres": (2000,),
    "layers": (12,),
    "tablecloth": (16,),
    "blobs": (500,),
    "tank": (5,),
}
# Two sizes in one bucket: 3000 and 3900 particles -> 4096; 30^2 = 900 and 31^2 = 961 vertices -> 1024;
# the flag at 36 and 39 (864 and 1014 vertices -> 1024; triangles -> 2048, hinges -> 4096).
# Spheres 3000 and 3500: the demo's column is 25 layers high either way, so its box is the same (a
# collider's shape is a compile-time constant, and the demo's box grows with the column).
# Two sheets at 14 and 15 (392 and 450 vertices, 676 and 784 triangles, 1066 and 1232 edges); the
# tablecloth at 30 and 31; the blobs' pool of 1500 and 1900 particles (the blob field sized by it).
PAIRS = {
    "fountain": (3000, 3900),
    "cloth": (30, 31),
    "flag": (36, 39),
    "spheres": (3000, 3500),
    "layers": (14, 15),
    "tablecloth": (30, 31),
    "blobs": (1500, 1900),
    "tank": (15, 19),  # 3000 and 3800 liquid particles -> 4096
}
# The spheres demo steps 240 times a frame; 24 keep a 10^5-sphere run of 30 frames to seconds.
BUILD_OPTIONS = {"spheres": {"steps_per_frame": 24}, "layers": {"layers": 2}}
# Scenes whose frames include their surface (the blob field and its isosurface): timed and compiled too.
SURFACED = {"blobs"}
COMPILE_FRAMES = 5
INTEGRATORS = {
    "fountain": "symplectic_euler",
    "cloth": "symplectic_euler",
    "flag": "implicit_euler",
    "spheres": "symplectic_euler",
    "layers": "implicit_euler",
    "tablecloth": "implicit_euler",
    "blobs": "symplectic_euler",
    "tank": "symplectic_euler",
}
MODES = {"off": False, "on": True}
RESULT_MARK = "SIZE_BUCKETS_RESULT "  # the worker's answer line (Taichi prints its banner to stdout too)


# ---------------------------------------------------------------------------------------------------------
# the worker: one process, one mode


def tank(*, layers: int, integrator: str):
    """A liquid block 20 x `layers` x 10 cm at 1 cm spacing (200 particles a layer) against a corner of a
    40 x 40 x 10 cm tank, DFSPH, frames of 1/60 s: the fluid kind at counts that keep its tank (a
    collider's shape is a compile-time constant, and the dam_break demo's tank grows with its column)."""
    from types import SimpleNamespace

    import taichi_anim as ta

    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (0.4, 0.4, 0.1), restitution=0.0)
    b.add_fluid(spacing=0.01)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.2, 0.01 * layers, 0.1))
    model = b.finalize()
    scene = dict(model=model, state=model.state(), integrator=ta.make_integrator(integrator), dt=1 / 60)
    return SimpleNamespace(**scene, substeps=1)  # the liquid's solver splits each frame by its CFL


def build(scene: str, size: int):
    from taichi_anim.scenes import SCENES

    options = {SIZE_OPTION[scene]: size, "integrator": INTEGRATORS[scene], **BUILD_OPTIONS.get(scene, {})}
    if scene == "tank":
        return tank(**options)
    return SCENES[scene].build(**options)


def field_bytes(f) -> int:
    from taichi.lang.matrix import MatrixField

    components = f.n * f.m if isinstance(f, MatrixField) else 1
    bits = int(str(f.dtype)[1:])  # Taichi's primitive types are named by their width: f32, u32, i64, ...
    return math.prod(f.shape) * components * bits // 8


def particle_array_bytes(owners, rows: int) -> int:
    """Bytes of the Taichi fields that `owners` hold (as attributes, or in lists) with `rows` rows: the
    particle arrays, found by their shape so that none is missed when a part adds one."""
    from taichi.lang.field import Field

    found = {}
    for owner in owners:
        for value in vars(owner).values():
            for f in value if isinstance(value, (list, tuple)) else (value,):
                if isinstance(f, Field) and f.shape and f.shape[0] == rows:
                    found[id(f)] = f
    return sum(field_bytes(f) for f in found.values())


def time_frames(spec: dict) -> dict:
    """ms per frame of `frames` frames after a warm-up frame (which loads the kernels from the cache)."""
    import taichi as ti

    import taichi_anim as ta

    scene = build(spec["scene"], spec["size"])
    stepper = ta.Stepper(scene.model, scene.integrator)
    stepper.step(scene.state, scene.dt, scene.substeps)
    ti.sync()
    t0 = time.perf_counter()
    for _ in range(spec["frames"]):
        stepper.step(scene.state, scene.dt, scene.substeps)
        if spec["scene"] in SURFACED:
            scene.frame_content()
    ti.sync()
    seconds = time.perf_counter() - t0
    m = scene.model
    owners = [m, scene.state, scene.integrator, stepper]
    return {
        "ms_per_frame": seconds / spec["frames"] * 1e3,
        "particles": m.particle_count,
        "capacity": m.particle_capacity,
        "particle_bytes": particle_array_bytes(owners, m.particle_capacity),
    }


def compile_sizes(spec: dict) -> list[dict]:
    """For each size in turn, in this process: build it and step COMPILE_FRAMES frames, then drop it
    (deleted and collected, so that with buckets on its fields go back to the pool for the next size)."""
    import taichi as ti
    from taichi.lang import impl

    import taichi_anim as ta
    from taichi_anim.compile_clock import CompileClock

    prog = impl.get_runtime().prog
    out = []
    for size in spec["sizes"]:
        ti.sync()
        t0, c0 = time.perf_counter(), prog.get_total_compilation_time()
        scene = build(spec["scene"], size)
        stepper = ta.Stepper(scene.model, scene.integrator)
        with CompileClock() as clock:  # the frames only: kernels launched while building are not in it
            for _ in range(COMPILE_FRAMES):
                stepper.step(scene.state, scene.dt, scene.substeps)
                if spec["scene"] in SURFACED:
                    scene.frame_content()
            ti.sync()
        out.append(
            {
                "size": size,
                "capacity": scene.model.particle_capacity,
                "wall_s": time.perf_counter() - t0,
                "taichi_compile_s": prog.get_total_compilation_time() - c0,  # build and frames
                "clock_s": clock.seconds,
                "clock_kernels": clock.kernels,
            }
        )
        del scene, stepper
        gc.collect()
    return out


def worker(spec: dict) -> None:
    import taichi as ti

    import taichi_anim as ta

    ta.init("cpu", size_buckets=spec["buckets"], log_level=ti.ERROR)
    result = time_frames(spec) if spec["task"] == "time" else compile_sizes(spec)
    print(RESULT_MARK + json.dumps(result), flush=True)


# ---------------------------------------------------------------------------------------------------------
# the parent: processes, caches, tables


def call(spec: dict, cache: Path):
    """Run one worker process on offline-cache folder `cache`; its result (process_s added to a dict)."""
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=str(cache), PYTHONPATH=str(ROOT))
    env.pop("TAICHI_ANIM_SIZE_BUCKETS", None)  # init(size_buckets=...) decides, not the caller's shell
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(spec)]
    t0 = time.perf_counter()
    run = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
    process_s = time.perf_counter() - t0
    lines = [line for line in run.stdout.splitlines() if line.startswith(RESULT_MARK)]
    if run.returncode or not lines:
        raise RuntimeError(f"worker {spec} failed (exit {run.returncode}): {run.stderr[-2000:]}")
    result = json.loads(lines[-1][len(RESULT_MARK) :])
    if isinstance(result, dict):
        result["process_s"] = process_s
    return result


def cached_kernels(cache: Path) -> set[str]:
    """The compiled kernels in an offline-cache folder (one .tic file each, written at process exit)."""
    return {str(p.relative_to(cache)) for p in cache.rglob("*.tic")}


def run_times(scene: str, size: int, reps: int, frames: int, caches: dict) -> dict:
    spec = {"task": "time", "scene": scene, "size": size, "frames": frames}
    for mode, on in MODES.items():  # fill each mode's cache: the timed runs load, never compile
        call({**spec, "buckets": on}, caches[mode])
    runs: dict = {mode: [] for mode in MODES}
    for r in range(reps):
        # off-on, then on-off: a machine that slows down or speeds up through the run hits both alike
        for mode in list(MODES)[:: 1 if r % 2 == 0 else -1]:
            runs[mode].append(call({**spec, "buckets": MODES[mode]}, caches[mode]))
    ms = {mode: statistics.median(x["ms_per_frame"] for x in runs[mode]) for mode in MODES}
    log(f"{scene} {size}: off {ms['off']:.3f} ms, on {ms['on']:.3f} ms")
    return {"scene": scene, "size": size, "ms": ms, "runs": runs}


def compile_spec(scene: str, sizes: list, on: bool) -> dict:
    return {"task": "compile", "scene": scene, "sizes": sizes, "buckets": on}


def across_processes(scene: str, on: bool, tmp: Path) -> dict:
    """Process A at the pair's first size, then B at the second, on one cache folder, empty at first."""
    cache = Path(tempfile.mkdtemp(prefix="cache_", dir=tmp))
    first, second = PAIRS[scene]
    a = call(compile_spec(scene, [first], on), cache)[0]
    after_a = cached_kernels(cache)
    b = call(compile_spec(scene, [second], on), cache)[0]
    new = cached_kernels(cache) - after_a
    log(f"{scene} buckets {'on' if on else 'off'}: {len(after_a)} kernels, {len(new)} new")
    return {"scene": scene, "on": on, "first": a, "second": b, "kernels_first": len(after_a), "new": len(new)}


def one_process(scene: str, on: bool, tmp: Path) -> dict:
    cache = Path(tempfile.mkdtemp(prefix="cache_", dir=tmp))
    first, second = call(compile_spec(scene, list(PAIRS[scene]), on), cache)
    return {"scene": scene, "on": on, "first": first, "second": second}


def both(p: dict, key: str) -> list[str]:
    """The first and the second size's `key` of a compile measurement, as table cells."""
    return ["–" if p[k][key] is None else f"{p[k][key]:.2f}" for k in ("first", "second")]


def compile_row(p: dict) -> list:
    return [p["scene"], "on" if p["on"] else "off", p["first"]["size"], p["second"]["size"]]


def run_time_table(page: Page, timing: list) -> None:
    rows = []
    for t in timing:
        on = t["runs"]["on"][0]
        ms_off, ms_on = t["ms"]["off"], t["ms"]["on"]
        rows.append([t["scene"], t["size"], on["particles"], on["capacity"]])
        rows[-1] += [f"{ms_off:.3f}", f"{ms_on:.3f}", f"{ms_on / ms_off:.3f}"]
    worst = max(t["ms"]["on"] / t["ms"]["off"] for t in timing)
    page.table(
        "Run time, buckets off and on",
        ["scene", "size", "particles", "capacity", "ms/frame off", "ms/frame on", "on / off"],
        rows,
        f"Largest on / off: {worst:.3f} ({'within' if worst <= 1.05 else 'OVER'} the 5 % limit).",
    )


def compile_tables(page: Page, procs: list, single: list) -> None:
    page.table(
        "Compile across sizes, one process per size (first, then second, on one cache folder)",
        ["scene", "buckets", "first size", "second size", "kernels in cache after first"]
        + ["new kernels after second", "Taichi compile s first", "Taichi compile s second"]
        + ["clock s first", "clock s second", "wall s first", "wall s second"],
        [
            compile_row(p)
            + [p["kernels_first"], p["new"]]
            + both(p, "taichi_compile_s")
            + both(p, "clock_s")
            + both(p, "wall_s")
            for p in procs
        ],
    )
    page.table(
        "Compile across sizes in one process (the first scene deleted and collected before the second)",
        ["scene", "buckets", "first size", "second size", "Taichi compile s first", "Taichi compile s second"]
        + ["new kernel instances first", "new kernel instances second", "wall s first", "wall s second"],
        [
            compile_row(p)
            + both(p, "taichi_compile_s")
            + [p["first"]["clock_kernels"], p["second"]["clock_kernels"]]
            + both(p, "wall_s")
            for p in single
        ],
    )


def memory_table(page: Page, timing: list) -> None:
    rows = []
    for t in timing:
        off, on = t["runs"]["off"][0], t["runs"]["on"][0]
        b_off, b_on = off["particle_bytes"], on["particle_bytes"]
        rows.append([t["scene"], t["size"], on["particles"], on["capacity"], b_on // on["capacity"]])
        rows[-1] += [f"{b_off / 2**20:.3g}", f"{b_on / 2**20:.3g}", f"{b_on / b_off:.3f}" if b_off else "–"]
    page.table(
        "Memory of the particle arrays",
        ["scene", "size", "particles", "capacity", "bytes per slot", "MiB off", "MiB on", "on / off"],
        rows,
    )


def write_page(args, timing: list, procs: list, single: list) -> None:
    page = Page(
        "size_buckets" if args.scenes is None else "size_buckets_" + "_".join(args.scenes),
        "Capacity buckets: run time, compiles across sizes, memory",
        args,
        {
            "scenes": "the size option of each: "
            + ", ".join(f"{k} {v}" for k, v in SIZE_OPTION.items())
            + "; integrators "
            + ", ".join(f"{k} {v}" for k, v in INTEGRATORS.items())
            + "; spheres with steps_per_frame=24, layers with 2 sheets; blobs frames include the blob field "
            "and its isosurface; tank: a liquid block at 1 cm spacing, 200 particles a layer, in a 40 x 40 x "
            "10 cm tank (DFSPH, frames of 1/60 s split by its CFL condition); CPU, f32",
            "run time": f"ms per frame of {args.frames} frames after 1 warm-up frame, ti.sync() before each "
            f"clock read; median of {args.reps} repetition(s), each a fresh process per mode, modes "
            "alternating (off-on, on-off, ...), offline cache warmed by one run per mode and size",
            "compile": f"{COMPILE_FRAMES} frames per size; each table's run starts on an empty cache folder",
            "Taichi compile s": "prog.get_total_compilation_time() delta over build + frames",
            "clock s": "CompileClock around the frames: kernels first compiled or loaded in them",
            "new kernel instances": "CompileClock.kernels: instances Taichi turned into IR in the frames (an "
            "in-memory or offline cache hit counts too; its compile s does not)",
            "wall s": "build + frames, in the process (imports and ti.init not included)",
            "kernels in cache": "*.tic files in TI_OFFLINE_CACHE_FILE_PATH after the process exits",
            "particle bytes": "Taichi fields of model, state, integrator and stepper with one row per "
            "particle slot (rows = count off, capacity on)",
        },
    )
    run_time_table(page, timing)
    compile_tables(page, procs, single)
    memory_table(page, timing)
    page.write({"run_time": timing, "across_processes": procs, "one_process": single})


def main(argv=None) -> int:
    def options(p):
        p.add_argument("--reps", type=int, default=None, help="repetitions per mode (default 5; quick 1)")
        p.add_argument("--frames", type=int, default=None, help="timed frames (default 30; quick 3)")
        p.add_argument("--scenes", nargs="+", choices=sorted(RUN_SIZES), default=None,
                       help="only these scenes (the page is then size_buckets_SCENES...)")  # fmt: skip
        # internal: the parent hands a measurement's spec (JSON) to a worker process
        p.add_argument("--worker", default=None, help=argparse.SUPPRESS)

    args = parse_args(__doc__, argv, options)
    if args.worker:
        worker(json.loads(args.worker))
        return 0
    args.reps = args.reps or (1 if args.quick else 5)
    args.frames = args.frames or (3 if args.quick else 30)
    sizes = QUICK_RUN_SIZES if args.quick else RUN_SIZES
    chosen = args.scenes or list(RUN_SIZES)
    sizes = {k: v for k, v in sizes.items() if k in chosen}
    pairs = [k for k in PAIRS if k in chosen]
    with tempfile.TemporaryDirectory(prefix="size_buckets_") as tmp_name:
        tmp = Path(tmp_name)
        caches = {mode: Path(tempfile.mkdtemp(prefix=f"run_{mode}_", dir=tmp)) for mode in MODES}
        timing = [run_times(sc, n, args.reps, args.frames, caches) for sc in sizes for n in sizes[sc]]
        procs = [across_processes(sc, on, tmp) for sc in pairs for on in MODES.values()]
        single = [one_process(sc, on, tmp) for sc in pairs for on in MODES.values()]
    write_page(args, timing, procs, single)
    return 0


if __name__ == "__main__":
    sys.exit(main())
