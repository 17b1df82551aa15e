"""Where a frame's time goes on this CPU: kernel time (per task, serial or parallel), memory traffic
against a copy's bandwidth, launch and thread-pool cost, and the host side (Python, arguments, launches,
syncs), for three scenes of the other benchmarks, imported from them:

- particles (particles.py): the fountain at 10^4 ... 10^7, a frame of STEPS substeps stepped two ways:
  `stepper_for(model).advance(state, DT, STEPS)` (the blocked frame) and `integ.step` STEPS times;
- cloth (cloth_warp.py): Warp's benchmark cloth at 32^2 ... 256^2, `integ.step(model, state, dt, substeps)`;
- spheres (spheres.py): the settled pile at 10^4 ... 10^6, `integ.step` k times a frame.

Each size runs twice, each in a fresh `init`: without the kernel profiler for the wall time per frame,
then with it for the split (the profiler adds its own cost to every launch). Taichi names a kernel's
offloaded tasks `<kernel>_c<id>_<n>_kernel_<k>_<range_for|serial|...>`: records ending in
`_kernel_0_...` count the launches, the others the extra tasks a kernel with several top-level loops has.

    .venv/bin/python benchmarks/step_breakdown.py [--quick] [--arch cuda]

With `--arch cuda` the scenes run on the GPU (page `step_breakdown_cuda`): particles at 10^5 and 10^7,
spheres at 10^5 and 10^6, the cloth at every size, about 1 s of frames per mode; the kernel profiler
then times each task on the device.
"""

import math
import re
import statistics
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass

import cloth_warp
import flops
import particles
import spheres
import taichi as ti
from harness import Page, clock, init, log, parse_args, peer
from taichi.lang import impl

TASK = re.compile(r"^(?P<kernel>.+?)(?:_c\d+_\d+)?_kernel_(?P<task>\d+)_(?P<kind>\w+)$")
MAX_FRAMES = 3000  # the smallest scenes take ~1 ms a frame: enough frames for ~3 s, not more records
SPHERE_STEPS = {10**4: 50, 10**5: 10, 10**6: 3}  # steps per frame, as spheres.py's plan
# Bytes a blocked frame moves per particle slot and frame (particles.FRAME_BYTES per particle-step).
BLOCKED_FRAME_BYTES = particles.FRAME_BYTES * particles.STEPS
# Cloth, per substep (f32): the spring pass reads each spring's pair and parameters (8 + 12 B) and
# writes its force (12 B); the gather reads per vertex its adjacency start (4 B) and per spring end an
# entry and that force (2 x 16 B); per vertex x and v are read by the spring pass (24 B, the neighbours'
# reads hitting cache) and read and written by the update (48 B), with the mass (4 B).
CLOTH_VERTEX_BYTES, CLOTH_SPRING_BYTES = 24 + 4 + 48 + 4, 8 + 12 + 12 + 2 * 16


@dataclass
class Case:
    """One built scene: its frame callables by mode (the first also warms up), warm-up frames, the
    elements the memory model counts (particles, vertices), and what to read off it after the timing:
    per mode how a frame launches (the stepper's frame mode, or step() calls), and counts."""

    modes: dict
    warmup: int
    elements: int
    info: Callable[[], dict]


def particle_case(n: int) -> Case:
    model, state, integ = particles.build(n)
    stepper = integ.stepper_for(model)
    dt, steps = particles.DT, particles.STEPS

    def step_by_step():
        for _ in range(steps):
            integ.step(model, state, dt)

    def info():
        how = {"frame (blocked)": stepper.frame_mode()["mode"], "step by step": f"step() x{steps}"}
        return {"alive": int(state.alive_mask().sum()), "how": how}

    # The fill frames run blocked: the same state as step by step, in less time.
    modes = {"frame (blocked)": lambda: stepper.advance(state, dt, steps), "step by step": step_by_step}
    return Case(modes, particles.FILL_FRAMES, n, info)


def cloth_case(cloth, dt: float, substeps: int) -> Case:
    model, state, integ = cloth_warp.build_ours(cloth)
    stepper = integ.stepper_for(model)
    springs = len(cloth.spring_indices) // 2
    info = lambda: {"how": {"frame": stepper.frame_mode()["mode"]}, "springs": springs}  # noqa: E731
    return Case({"frame": lambda: integ.step(model, state, dt, substeps)}, 3, len(cloth.positions), info)


def sphere_case(start: dict, steps: int) -> Case:
    model, state, integ = spheres.build(start["x"], start["v"], start["lo"], start["hi"])

    def frame():
        for _ in range(steps):
            integ.step(model, state, spheres.DT)

    return Case({"frame": frame}, 2, len(start["x"]), lambda: {"how": {"frame": f"step() x{steps}"}})


# ---------------------------------------------------------------------------------------------------------
# measuring


def task_records() -> list[tuple[str, float]]:
    """(task name, ms) of every task launched since the last clear. Taichi 1.7.4 has no public call
    for the records: these are the three calls its KernelProfiler._update_records makes."""
    prog = impl.get_runtime().prog
    prog.sync_kernel_profiler()
    prog.update_kernel_profiler()
    return [(r.name, r.kernel_time) for r in prog.get_kernel_profiler_records()]


def task_split(records, frames: int) -> dict:
    """Per frame: kernel ms, launches, tasks (serial / parallel), and per task (kernel, index, kind)
    its ms and calls; instances of one kernel (template arguments) are added together."""
    tasks: dict = defaultdict(lambda: [0.0, 0])
    for name, ms in records:
        m = TASK.match(name)
        key = (m["kernel"], int(m["task"]), m["kind"]) if m else (name, 0, "?")
        if key[0].startswith(("snode_reader", "snode_writer")):  # one element read or written from Python
            key = ("field access from Python (snode_reader/writer)", 0, key[2])
        tasks[key][0] += ms / frames
        tasks[key][1] += 1 / frames
    calls = lambda pick: sum(c for k, (_, c) in tasks.items() if pick(k))  # noqa: E731
    return {
        "kernel_ms": sum(ms for ms, _ in tasks.values()),
        "launches": calls(lambda k: k[1] == 0),
        "tasks": calls(lambda k: True),
        "serial": calls(lambda k: k[2] == "serial"),
        "tasks_by_name": {f"{k[0]}#{k[1]} {k[2]}": v for k, v in tasks.items()},
    }


def frame_times(frame, frames: int) -> list[float]:
    times = []
    for _ in range(frames):
        a = clock()
        frame()
        times.append(clock() - a)
    return times


def run_size(make, budget_s: float, frames: dict | None = None, arch: str = "cpu") -> dict:
    """Build in a fresh init (the profiler on when `frames` is given: the unprofiled run chose them),
    warm up, then per mode: one untimed frame (its compile), one to size the run to budget_s, the
    timed frames (the profiled run takes the sizing frame too, so both runs time the same frames)."""
    profiled = frames is not None
    init("f32", arch, kernel_profiler=profiled)
    case = make()
    first = next(iter(case.modes.values()))
    for _ in range(case.warmup):
        first()
    out = {}
    for mode, frame in case.modes.items():
        frame()
        one = frame_times(frame, 1)[0]
        count = frames[mode] if profiled else max(3, min(MAX_FRAMES, math.ceil(budget_s / one)))
        if profiled:
            ti.profiler.clear_kernel_profiler_info()
        times = frame_times(frame, count)
        out[mode] = {"frames": count, "wall_ms": 1e3 * statistics.median(times)}
        if profiled:
            out[mode].update(task_split(task_records(), count))
    return {"modes": out, "info": case.info(), "elements": case.elements}


def measure(scene: str, n: int, make, budget_s: float, arch: str = "cpu") -> list[dict]:
    log(f"{scene} {n}")
    plain = run_size(make, budget_s, arch=arch)
    prof = run_size(make, budget_s, {m: r["frames"] for m, r in plain["modes"].items()}, arch)
    rows = []
    for mode, r in prof["modes"].items():
        wall = plain["modes"][mode]["wall_ms"]
        row = {"scene": scene, "n": n, "mode": mode, "info": plain["info"], "elements": plain["elements"]}
        rows.append({**row, **r, "profiled_wall_ms": r["wall_ms"], "wall_ms": wall})
        log(f"  {mode}: {wall:.3g} ms/frame, kernels {r['kernel_ms']:.3g} ms, {r['tasks']:.1f} tasks")
    return rows


def median_launch(kernel, repeats: int) -> float:
    for _ in range(20):
        kernel()
    return 1e6 * statistics.median(frame_times(kernel, repeats))


def launch_costs(profiled: bool, repeats: int, arch: str = "cpu") -> dict:
    """Median µs of (launch, ti.sync) for an empty serial kernel and a 2-iteration parallel loop (the
    thread pool waking for almost no work), and of ti.sync alone; with the profiler, also the task
    time it records for each (is the pool's wake-up inside a task's time?)."""
    init("f32", arch, kernel_profiler=profiled)
    flag = ti.field(ti.i32, shape=2)

    @ti.kernel
    def empty_serial():
        flag[0] = 1

    @ti.kernel
    def two_parallel():
        for i in range(2):
            flag[i] = i

    out = {"sync alone": median_launch(lambda: None, repeats)}
    for name, kernel in (("empty serial kernel", empty_serial), ("2-iteration parallel loop", two_parallel)):
        if profiled:
            ti.profiler.clear_kernel_profiler_info()
        out[name] = median_launch(kernel, repeats)
        if profiled:
            out[name + " (task)"] = 1e3 * statistics.median(ms for _, ms in task_records())
    return out


# ---------------------------------------------------------------------------------------------------------
# memory model and tables


def frame_bytes(r: dict, cloth_substeps: int) -> tuple[float, float] | None:
    """(bytes per frame, bytes per element-step) of the model in the module's constants, or None."""
    if r["scene"] == "particles":
        if r["mode"].startswith("frame"):
            return r["elements"] * BLOCKED_FRAME_BYTES, BLOCKED_FRAME_BYTES / particles.STEPS
        return r["info"]["alive"] * particles.BYTES * particles.STEPS, particles.BYTES
    if r["scene"] == "cloth":
        per = r["elements"] * CLOTH_VERTEX_BYTES + r["info"]["springs"] * CLOTH_SPRING_BYTES
        return per * cloth_substeps, per / r["elements"]
    return None


def size(r: dict) -> str:
    return f"{r['n']}²" if r["scene"] == "cloth" else f"{r['n']:.0e}"


BREAKDOWN = "scene|size|mode|launched as|frames|wall|wall profiled|kernels|host (share)|host profiled"
BREAKDOWN += "|launches|tasks (serial)|launch est."
ARITHMETIC = "scene|size|mode|flops|GFLOP/s|of Taichi's scalar peak|of the f32 vector peak"


def breakdown_rows(rows, launch: dict) -> list[list]:
    per_launch_ms = (launch["empty serial kernel"] - launch["sync alone"]) / 1e3
    out = []
    for r in rows:
        host, wall, kernel = r["wall_ms"] - r["kernel_ms"], r["wall_ms"], r["kernel_ms"]
        out.append(
            [r["scene"], size(r), r["mode"], r["info"]["how"][r["mode"]], r["frames"], f"{wall:.3g}"]
            + [f"{r['profiled_wall_ms']:.3g}", f"{kernel:.3g}", f"{host:.3g} ({host / wall:.0%})"]
            + [f"{r['profiled_wall_ms'] - kernel:.3g}", f"{r['launches']:.1f}"]
            + [f"{r['tasks']:.1f} ({r['serial']:.1f})", f"{r['launches'] * per_launch_ms:.3g}"]
        )
    return out


def memory_rows(rows, bandwidth: float, substeps: int) -> list[list]:
    out = []
    for r in rows:
        model = frame_bytes(r, substeps)
        if model is None:
            out.append([r["scene"], size(r), r["mode"], "not estimated", "–", "–", "–"])
            continue
        total, per = model
        wall, kernel = total / r["wall_ms"] / 1e6, total / r["kernel_ms"] / 1e6
        out.append([r["scene"], size(r), r["mode"], f"{per:.3g}", f"{wall:.3g}", f"{kernel:.3g}"])
        out[-1].append(f"{wall / bandwidth:.2f}")
    return out


def arithmetic_rows(rows, peaks: dict, substeps: int) -> list[list]:
    out = []
    for r in rows:
        model = flops.frame_flops(r, particles.STEPS, substeps)
        if model is None:
            out.append([r["scene"], size(r), r["mode"], "not estimated", "–", "–", "–"])
            continue
        total, per = model
        gflops = total / r["wall_ms"] / 1e6
        out.append([r["scene"], size(r), r["mode"], per, f"{gflops:.3g}"])
        out[-1] += [f"{gflops / peaks['taichi scalar']:.2f}", f"{gflops / peaks['sgemm']:.3f}"]
    return out


def task_us(costs: dict, name: str) -> str:
    return f"{costs[name + ' (task)']:.3g}" if name + " (task)" in costs else "–"


def launch_rows(launch: dict) -> list[list]:
    plain, prof = launch["plain"], launch["profiled"]
    rows = [[k, f"{plain[k]:.3g}", f"{prof[k]:.3g}", task_us(prof, k)] for k in plain]
    wake = plain["2-iteration parallel loop"] - plain["empty serial kernel"]
    return rows + [["pool wake-up (parallel - serial)", f"{wake:.3g}", "", ""]]


def task_table(page: Page, r: dict, top: int = 8) -> None:
    tasks = sorted(r["tasks_by_name"].items(), key=lambda kv: -kv[1][0])
    share = lambda ms: f"{ms / r['kernel_ms']:.0%}" if r["kernel_ms"] else "–"  # noqa: E731
    rows = [[name, f"{ms:.3g}", f"{calls:.2g}", share(ms)] for name, (ms, calls) in tasks[:top]]
    page.table(
        f"Tasks: {r['scene']} {size(r)}, {r['mode']}",
        ["task (kernel#index kind)", "ms/frame", "calls/frame", "of kernel time"],
        rows,
        f"{len(tasks) - top} more tasks, together {sum(v[0] for _, v in tasks[top:]):.3g} ms/frame"
        if len(tasks) > top
        else "",
    )


def measure_all(sizes: dict, quick: bool, budget: float, arch: str) -> tuple[list, float | None, int | None]:
    rows = []
    for n in sizes["particles"]:
        rows += measure("particles", n, lambda n=n: particle_case(n), budget, arch)
    wc = peer("warp_cloth")
    dt = substeps = None
    if wc is not None:  # Warp's scene: without warp-lang the cloth rows are left out
        consts = wc.scene(32)["constants"]
        dt, substeps = float(consts["sim_dt"]), int(consts["sim_substeps"])
        for dim in sizes["cloth"]:
            cloth = wc.make_cloth(dim)
            make = lambda c=cloth: cloth_case(wc.fresh(c), dt, substeps)  # noqa: E731
            rows += measure("cloth", dim, make, budget, arch)
    for n in sizes["spheres"]:
        start = spheres.settle(n, 60 if quick else spheres.SETTLE, arch)
        rows += measure("spheres", n, lambda s=start, n=n: sphere_case(s, SPHERE_STEPS[n]), budget, arch)
    return rows, dt, substeps


def settings(sizes, budget, threads, bandwidth, dt, substeps) -> dict:
    return {
        "scenes": "particles.py's fountain, cloth_warp.py's Warp cloth, spheres.py's settled pile",
        "sizes": str(sizes),
        "steps": f"particles: {particles.STEPS} steps of {particles.DT:.4g} s a frame; cloth: "
        f"{substeps} substeps of a {dt} s frame; spheres: {SPHERE_STEPS} steps of {spheres.DT:.4g} s",
        "frames": f"after the warm-up (particles: {particles.FILL_FRAMES} fill frames; cloth 3, spheres 2) "
        f"and two untimed frames per mode, as many as take ~{budget} s (3 to {MAX_FRAMES}), a sync "
        "before every clock read; medians",
        "profiler": "wall from a fresh init without the kernel profiler; kernel time, tasks and launches "
        "from a second fresh init with it, same frames (its wall shown apart: the profiler's own cost)",
        "host": "wall (unprofiled) - kernel time (profiled): Python, arguments, launches, syncs; "
        "negative where the two runs differ by more than the host time",
        "threads": threads,
        "copy bandwidth": f"{bandwidth:.1f} GB/s (NumPy copy, read + write)",
        "bytes, particles": f"step by step {particles.BYTES} B per alive particle-step (particles.py); "
        f"blocked frame {BLOCKED_FRAME_BYTES:.3g} B per slot per frame (x, v, birth, death read and "
        "written, free bits, free_from and birth_head scratch written and read)",
        "bytes, cloth": f"per substep {CLOTH_VERTEX_BYTES} B per vertex (x, v read by the spring pass, "
        f"read and written by the update, adjacency start, mass) + {CLOTH_SPRING_BYTES} B per spring "
        "(pair, parameters, force written, force and entry read at both ends)",
        "bytes, spheres": "not estimated",
        "caches": "the byte counts assume every byte from DRAM: where the state fits in cache the GB/s "
        "and its fraction of the copy bandwidth are only nominal",
    }


def main(argv=None) -> None:
    args = parse_args(
        __doc__, argv, lambda p: p.add_argument("--arch", choices=("cpu", "cuda"), default="cpu")
    )
    arch, gpu = args.arch, args.arch != "cpu"
    quick, budget, repeats = (
        args.quick,
        0.5 if args.quick else (1.0 if gpu else 3.0),
        500 if args.quick else 2000,
    )
    sizes = {
        "particles": [10**4, 10**5] if quick else ([10**5, 10**7] if gpu else [10**4, 10**5, 10**6, 10**7]),
        "cloth": list(cloth_warp.QUICK_SIZES if quick else cloth_warp.SIZES),
        "spheres": [10**4] if quick else ([10**5, 10**6] if gpu else [10**4, 10**5, 10**6]),
    }
    bandwidth = particles.copy_bandwidth(2**26 if quick else 2**29)
    log(f"copy bandwidth {bandwidth:.1f} GB/s")
    launch = {"plain": launch_costs(False, repeats, arch), "profiled": launch_costs(True, repeats, arch)}
    threads = impl.current_cfg().cpu_max_num_threads if not gpu else arch
    peaks = {}
    if not gpu:
        init("f32")
        peaks = {"sgemm": flops.sgemm_peak(), "taichi scalar": flops.taichi_scalar_peak()}
        log(f"arithmetic peaks (GFLOP/s): {peaks}")
    rows, dt, substeps = measure_all(sizes, quick, budget, arch)

    page = Page(
        "step_breakdown" + ("_cuda" if gpu else ""),
        "Where a frame's time goes: kernels, memory, launches, host",
        args,
        settings(sizes, budget, threads, bandwidth, dt, substeps),
    )
    page.table(
        f"Launch and thread-pool cost (µs, median of {repeats}, each with its ti.sync)",
        ["", "without profiler", "with profiler", "task time (profiler)"],
        launch_rows(launch),
    )
    page.table(
        "Where a frame's time goes (ms per frame)",
        BREAKDOWN.split("|"),
        breakdown_rows(rows, launch["plain"]),
        "host profiled = wall profiled - kernels (one run). launch est. = launches x (empty serial kernel "
        "- sync alone), unprofiled: the launches' part of the host time. The thread pool's wake-up is "
        "inside a parallel task's time (the task column above).",
    )
    page.table(
        "Memory traffic (model bytes / time)",
        "scene|size|mode|B per element-step|GB/s at wall|GB/s at kernel time|of copy bandwidth".split("|"),
        memory_rows(rows, bandwidth, substeps or 1),
    )
    if peaks:
        page.table(
            "Arithmetic (model flops / wall time)",
            ARITHMETIC.split("|"),
            arithmetic_rows(rows, peaks, substeps or 1),
            f"Peaks measured here: {peaks['taichi scalar']:.1f} GFLOP/s for Taichi code of independent "
            f"multiply-adds on every core (flops.taichi_scalar_peak: Taichi does not vectorise it), "
            f"{peaks['sgemm']:.0f} GFLOP/s for NumPy's float32 matrix product (flops.sgemm_peak: every core, "
            "AVX-512). Flop counts per element-step: benchmarks/flops.py, on the path that hits nothing.",
        )
    for scene, ns in sizes.items():  # the smallest and largest size of each scene
        for r in rows:
            if r["scene"] == scene and r["n"] in (ns[0], ns[-1]):
                task_table(page, r)
    page.write({"bandwidth": bandwidth, "launch": launch, "peaks": peaks, "rows": rows})


if __name__ == "__main__":
    main()
