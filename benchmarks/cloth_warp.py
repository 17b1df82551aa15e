"""Mass-spring cloth: taichi_anim against NVIDIA Warp's cross-framework cloth benchmark
(warp/examples/benchmarks/benchmark_cloth.py, shipped with warp-lang) and its Warp, Taichi and NumPy
modes, on the same scene, in the same process.

Scene (Warp's `Cloth` class, executed from its source by benchmarks/peers/warp_cloth.py; the parameters
are read from its `run_benchmark`): a dim x dim grid of vertices in the XZ plane (y = 0), spacing 0.1 m,
0.1 kg per vertex; the two corners of the row z = 0 pinned (inverse mass 0); structural, shear (both
diagonals) and bend (two apart) springs, all of stiffness 1000 N/m and damping 10 kg/s, rest length the
initial distance; gravity (0, -9.81, 0) m/s^2 on the free vertices. 60 frames of 1/60 s, each 16 substeps
of symplectic Euler (v += h (f/m + g), x += h v); a frame's time includes copying the positions to a
NumPy array (`positions.to_numpy()`), as Warp's benchmark does. Grids 32^2, 64^2, 128^2 (Warp's script)
and 256^2. float32 everywhere.

Implementations, each in its own block per size, from its own copy of the cloth:
- warp_cpu: benchmark_cloth_warp.WpIntegrator (a scatter kernel over springs with atomics, then an
  integration kernel; Warp runs a CPU kernel on one thread);
- taichi_cpu: benchmark_cloth_taichi.TiIntegrator (the same two kernels in Taichi, default threads; it
  calls `ti.init` itself);
- numpy: benchmark_cloth_numpy.NpIntegrator (`np.add.at` scatter; gravity 9.8 m/s^2 in its source);
- taichi_anim: `Builder.add_particles` (mass 0 pins the two corners) + `add_springs` (the cloth's spring
  list, stiffness and damping; rest length = current distance, checked equal to Warp's) +
  `add_force_gravity`, `make_integrator("symplectic_euler", check_every=16)` (the divergence counter read
  once per frame), after a fresh `ta.init` (their taichi mode re-initialised Taichi).

Measured per size and implementation: construction time; the first frame (JIT compile or kernel-cache load
included; Warp compiles its module once per process, in the first size's first frame, because
benchmark_cloth_warp clears the kernel cache at import); WARMUP - 1 more frames; then the frames timed one
by one (`time.perf_counter`, after `ti.sync()` for taichi_anim; every mode's frame ends in a host copy,
which synchronises): mean, median, standard deviation, min and max ms per frame, and the cores the process
kept busy. Speed-up = the peer's median ms per frame / taichi_anim's. A run is cut short after BUDGET_S
seconds of timed frames (NumPy at 256^2), and says so. The engine's JIT compile is also timed in fresh
`ta.init`s under the three offline-cache conditions (common.compile_times).

Equivalence: after the same number of frames (warm-up included), every implementation's positions against
warp_cpu's: largest and RMS |x - x_warp| per vertex, next to the largest displacement of the cloth and
its size (0.1 (dim - 1) m).

    .venv/bin/python benchmarks/cloth_warp.py              # full run: benchmarks/results/cloth_warp.*
    .venv/bin/python benchmarks/cloth_warp.py --quick      # smoke (32^2, 64^2, 10 frames): benchmarks/out/
    .venv/bin/python benchmarks/cloth_warp.py --arch cuda  # CUDA machine: ours on ta.init("cuda") against
                                                           # warp_gpu and taichi_gpu (cloth_warp_cuda.*)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from importlib import metadata

import numpy as np
import taichi as ti
from common import (
    COMPILE_HEADERS,
    OtherLoad,
    clock,
    command_line,
    compile_rows,
    compile_times,
    engine_fingerprint,
    engine_row,
    fmt_s,
    load_average,
    log,
    machine_info,
    machine_table,
    md_table,
    output_paths,
    parse_args,
    write_section,
)

import taichi_anim as ta

GRAVITY = (0.0, -9.81, 0.0)  # [m/s^2] as benchmark_cloth_warp's kernel
SIZES = (32, 64, 128, 256)
QUICK_SIZES = (32, 64)
QUICK_FRAMES = 10
WARMUP = 2  # frames before the timed ones (the first holds the compile)
BUDGET_S = 120.0  # [s] of timed frames per run at most (NumPy at 256^2); --quick: QUICK_BUDGET_S
QUICK_BUDGET_S = 20.0
MIN_FRAMES = 5  # a run cut by the budget still times at least this many frames
GOAL_SIZES = (64, 128, 256)
GOALS = {"warp_cpu": 2.0, "taichi_cpu": 3.0}  # speed-up over the peer set as the goal
OURS = "taichi_anim"


# ---------------------------------------------------------------------------------------------------------
# command line


def parse(argv=None) -> tuple[argparse.Namespace, str]:
    """common.parse_args (--quick, --out) plus --arch {cpu, cuda}."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--arch", choices=("cpu", "cuda"), default="cpu")
    known, rest = p.parse_known_args(argv)
    args = parse_args(
        __doc__.splitlines()[0]
        + " Also: --arch {cpu,cuda} (cuda: taichi_anim on ta.init('cuda') against warp_gpu and taichi_gpu).",
        rest,
    )
    return args, known.arch


def versions() -> dict[str, str]:
    out = {}
    for pkg in ("warp-lang", "usd-core", "taichi", "numpy"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


# ---------------------------------------------------------------------------------------------------------
# the engine's side


def engine_init(arch: str, **options) -> str:
    options.setdefault("log_level", ti.ERROR)
    return ta.init(arch, **options)


def build_engine(cloth):
    """The cloth as taichi_anim particles + springs (module docstring); checks the spring list and rest
    lengths against Warp's. Returns (model, state, integrator, check)."""
    b = ta.Builder()
    b.add_particles(cloth.positions.astype(np.float64), mass=np.where(cloth.inv_masses > 0, 0.1, 0.0))
    pairs = cloth.spring_indices.reshape(-1, 2)
    b.add_springs(pairs, stiffness=cloth.spring_stiffness, damping=cloth.spring_damping)
    b.add_force_gravity(GRAVITY)
    model = b.finalize()
    springs = model.springs
    # The engine stores each spring with its lower index first, sorted by its ends (memory order).
    ends = np.sort(pairs.astype(np.int64), axis=1)
    order = np.lexsort((ends[:, 1], ends[:, 0]))
    if not np.array_equal(springs.pairs, ends[order]):
        raise AssertionError("the engine's spring list differs from Warp's")
    warp_rest = cloth.spring_lengths.astype(np.float64)[order]
    rest_diff = float(np.abs(springs.rest_length - warp_rest).max())
    # Warp's rest lengths are the float64 grid's distances rounded to float32; ours are the distances of
    # the float32 positions, whose rounding is relative to the coordinates (up to 0.1 (dim - 1) m).
    tol = 4 * float(np.finfo(np.float32).eps) * float(np.abs(cloth.positions).max() + 1.0)
    if rest_diff > tol:
        raise AssertionError(f"rest lengths differ from Warp's by {rest_diff:.3g} m (> {tol:.3g} m)")
    integ = ta.make_integrator("symplectic_euler", check_every=16)
    check = {"springs_equal": True, "rest_length_max_abs_diff": rest_diff, "serial": bool(model.serial)}
    return model, model.state(), integ, check


class EngineRun:
    """simulate(dt, substeps) for taichi_anim with the interface of Warp's integrators."""

    def __init__(self, cloth):
        self.model, self.state, self.integ, self.check = build_engine(cloth)

    def simulate(self, dt: float, substeps: int) -> np.ndarray:
        self.integ.step(self.model, self.state, dt, substeps)  # one frame (Stepper.frame_mode)
        return self.state.particle_x.to_numpy()


# ---------------------------------------------------------------------------------------------------------
# timing


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system


def run_mode(mode, make, dt, substeps, frames, budget_s, sync) -> dict:
    """Construct (make()), first frame, WARMUP - 1 frames, then up to `frames` timed frames."""
    t0 = time.perf_counter()
    integ = make()
    construct = time.perf_counter() - t0
    a = sync()
    x = integ.simulate(dt, substeps)
    first = sync() - a
    warm = []
    for _ in range(WARMUP - 1):
        a = sync()
        x = integ.simulate(dt, substeps)
        warm.append(sync() - a)
    times = []
    c0 = cpu_seconds()
    start = sync()
    for _ in range(frames):
        a = sync()
        x = integ.simulate(dt, substeps)
        times.append(sync() - a)
        if sum(times) > budget_s and len(times) >= MIN_FRAMES:
            break
    wall = sync() - start
    busy = (cpu_seconds() - c0) / wall
    t = np.asarray(times)
    out = {
        "mode": mode,
        "construct": construct,
        "first_frame": first,
        "warm_frames": warm,
        "frames": len(times),
        "frames_asked": frames,
        "cut_by_budget": len(times) < frames,
        "frame_times": times,
        "mean": float(t.mean()),
        "median": float(np.median(t)),
        "std": float(t.std(ddof=1)) if len(t) > 1 else 0.0,
        "min": float(t.min()),
        "max": float(t.max()),
        "cores_busy": busy,
        "finite": bool(np.isfinite(x).all()),
        "simulated_frames": 1 + len(warm) + len(times),
    }
    out["x"] = np.array(x, dtype=np.float32, copy=True)
    if isinstance(integ, EngineRun):
        out["check"] = integ.check
    return out


def perf() -> float:
    return time.perf_counter()


def run_size(dim, modes, arch, frames, budget_s) -> dict:
    from peers import warp_cloth

    sc = warp_cloth.scene(dim)["constants"]
    dt, substeps = float(sc["sim_dt"]), int(sc["sim_substeps"])
    t0 = time.perf_counter()
    cloth = warp_cloth.make_cloth(dim)
    build = time.perf_counter() - t0
    log(
        f"{dim}^2: {cloth.num_particles} vertices, {cloth.num_springs} springs "
        f"(Warp's Cloth built in {fmt_s(build)})"
    )
    runs = {}
    for mode in modes:
        r = run_mode(
            mode,
            lambda mode=mode: warp_cloth.make_integrator(mode, warp_cloth.fresh(cloth)),
            dt,
            substeps,
            frames,
            budget_s,
            perf,
        )
        runs[mode] = r
        log_run(dim, r)

    def make_ours():
        engine_init(arch)  # after their taichi mode's ti.init
        return EngineRun(warp_cloth.fresh(cloth))

    r = run_mode(OURS, make_ours, dt, substeps, frames, budget_s, clock)
    runs[OURS] = r
    log_run(dim, r)
    ref = next((m for m in ("warp_cpu", "warp_gpu", "taichi_cpu", "taichi_gpu") if m in runs), None)
    size = 0.1 * (dim - 1)
    eq = {"reference": ref, "cloth_size": size}
    if ref is not None:
        xr = runs[ref]["x"].astype(np.float64)
        eq["max_displacement"] = float(np.linalg.norm(xr - cloth.positions, axis=1).max())
        for m, r in runs.items():
            if m == ref:
                continue
            if r["simulated_frames"] != runs[ref]["simulated_frames"]:
                eq[m] = None  # cut by the budget: a different time
                continue
            d = np.linalg.norm(r["x"].astype(np.float64) - xr, axis=1)
            eq[m] = {"max": float(d.max()), "rms": float(np.sqrt((d**2).mean()))}
        e = eq.get(OURS)
        if e:
            log(
                f"{dim}^2: |x_{OURS} - x_{ref}| max {e['max']:.2e} m, rms {e['rms']:.2e} m after "
                f"{runs[ref]['simulated_frames']} frames (cloth {size:.1f} m, moved up to "
                f"{eq['max_displacement']:.2f} m)"
            )
    for r in runs.values():
        r["x"] = None  # not into the json
    return {
        "dim": dim,
        "vertices": int(cloth.num_particles),
        "springs": int(cloth.num_springs),
        "spring_damping": sorted({float(d) for d in cloth.spring_damping}),
        "spring_stiffness": sorted({float(k) for k in cloth.spring_stiffness}),
        "cloth_build": build,
        "dt": dt,
        "substeps": substeps,
        "runs": runs,
        "equivalence": eq,
    }


def log_run(dim, r) -> None:
    cut = f" (cut by the budget at {r['frames']} of {r['frames_asked']})" if r["cut_by_budget"] else ""
    log(
        f"{dim}^2 {r['mode']:12s}: median {r['median'] * 1e3:8.2f} ms/frame, mean {r['mean'] * 1e3:8.2f}, "
        f"min {r['min'] * 1e3:8.2f}, max {r['max'] * 1e3:8.2f}, {r['frames']} frames{cut}; first frame "
        f"{fmt_s(r['first_frame'])}, construct {fmt_s(r['construct'])}, {r['cores_busy']:.2f} cores busy"
    )


def engine_compile(dim: int) -> dict:
    """The engine's JIT compile for the cloth of `dim`, under the three offline-cache conditions."""
    from peers import warp_cloth

    cloth = warp_cloth.make_cloth(dim)
    sc = warp_cloth.scene(dim)["constants"]
    dt, substeps = float(sc["sim_dt"]), int(sc["sim_substeps"])

    def first_and_steady():
        run = EngineRun(warp_cloth.fresh(cloth))
        a = clock()
        run.simulate(dt, substeps)
        first = clock() - a
        a = clock()
        run.simulate(dt, substeps)
        return first, clock() - a

    return compile_times(first_and_steady, precision="f32")


# ---------------------------------------------------------------------------------------------------------
# main


def main(argv=None) -> int:
    args, arch = parse(argv)
    md_path, fig_dir = output_paths(args)
    fig_dir.mkdir(parents=True, exist_ok=True)
    try:
        from peers import warp_cloth

        warp_cloth.benchmark_folder()
    except (ImportError, FileNotFoundError) as e:
        log(f"cloth_warp: Warp's cloth benchmark is not available ({e}); install the bench extra: "
            ".venv/bin/python -m pip install -e '.[bench]'")  # fmt: skip
        return 1
    import warp as wp

    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)  # no greeting, no per-module load lines
    if arch == "cuda":
        why = warp_cloth.cuda_available()
        if why["taichi"] is not None:
            log(
                f"cloth_warp --arch cuda: CUDA is not available to Taichi ({why['taichi']}); nothing "
                f"measured. Warp: {why['warp'] or 'CUDA available'}. Run it on a machine with an NVIDIA GPU "
                "and its driver, or without --arch cuda."
            )
            return 1
        modes = [m for m in warp_cloth.MODES_CUDA if m != "warp_gpu" or why["warp"] is None]
        if why["warp"] is not None:
            log(f"cloth_warp --arch cuda: warp_gpu skipped ({why['warp']})")
        gpu = wp.get_device("cuda").name if why["warp"] is None else "?"
    else:
        why = {}
        modes = list(warp_cloth.MODES_CPU)
        gpu = None
    sizes = QUICK_SIZES if args.quick else SIZES
    frames = QUICK_FRAMES if args.quick else int(warp_cloth.scene(32)["constants"]["sim_frames"])
    budget = QUICK_BUDGET_S if args.quick else BUDGET_S
    wp.init()
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()
    rows = [run_size(dim, modes, arch, frames, budget) for dim in sizes]
    compile_result = None
    if arch == "cpu":
        compile_result = engine_compile(QUICK_SIZES[-1])
        for mode, r in compile_result.items():
            log(f"taichi_anim compile at {QUICK_SIZES[-1]}^2, {mode}: {fmt_s(r['compile'])}")
    from taichi.lang import impl

    threads = impl.current_cfg().cpu_max_num_threads
    total = time.perf_counter() - started
    load_end = load_average()
    settings = {
        "arch": arch,
        "sizes": list(sizes),
        "frames": frames,
        "warmup_frames": WARMUP,
        "budget_s": budget,
        "scene": warp_cloth.scene(sizes[0])["constants"] | {"dim": "per size"},
        "cloth_kwargs": {
            k: v for k, v in warp_cloth.scene(sizes[0])["cloth_kwargs"].items() if k not in ("dx", "dy")
        },
        "spring_damping": rows[0]["spring_damping"],
        "spring_stiffness": rows[0]["spring_stiffness"],
        "gravity": GRAVITY,
        "check_every": 16,
        "precision": "f32",
        "taichi_cpu_threads": threads,
        "versions": versions(),
        "pxr_imported": warp_cloth.pxr_imported(),
        "warp_benchmark_folder": warp_cloth.benchmark_folder()
        .relative_to(warp_cloth.benchmark_folder().parents[2])
        .as_posix(),
        "modes": modes,
        "gpu": gpu,
        "cuda_check": why,
    }
    write_outputs(args, arch, md_path, fig_dir, rows, compile_result, settings, total, load_start, load_end,
                  date, engine, other)  # fmt: skip
    return 0


# ---------------------------------------------------------------------------------------------------------
# output


def _ms(x: float) -> str:
    return f"{x * 1e3:.3g}" if x >= 1e-3 else f"{x * 1e3:.2g}"


def speedup(row, peer) -> float | None:
    runs = row["runs"]
    if peer not in runs or OURS not in runs:
        return None
    return runs[peer]["median"] / runs[OURS]["median"]


def write_outputs(args, arch, md_path, fig_dir, rows, compile_result, settings, total, load_start, load_end,
                  date, engine, other) -> None:  # fmt: skip
    stem = "cloth_warp" if arch == "cpu" else "cloth_warp_cuda"
    modes = settings["modes"]
    peers = [m for m in modes if m != "numpy"] + (["numpy"] if "numpy" in modes else [])
    time_rows = []
    for r in rows:
        for m in [*modes, OURS]:
            x = r["runs"][m]
            s = speedup(r, m) if m != OURS else None
            cut = f" (**cut**: {x['frames']} of {x['frames_asked']})" if x["cut_by_budget"] else ""
            time_rows.append(
                [
                    f"{r['dim']}²",
                    f"**{m}**" if m == OURS else m,
                    f"{x['frames']}{cut}",
                    f"**{_ms(x['median'])}**",
                    _ms(x["mean"]),
                    _ms(x["std"]),
                    f"{_ms(x['min'])} – {_ms(x['max'])}",
                    f"{x['cores_busy']:.2f}",
                    fmt_s(x["first_frame"]),
                    fmt_s(x["construct"]),
                    "–" if s is None else f"{s:.2f}x",
                ]
            )
    ratio_rows = []
    goal_notes = []
    for r in rows:
        cells = [f"{r['dim']}²", f"{r['vertices']}", f"{r['springs']}"]
        for p in peers:
            s = speedup(r, p)
            mean_s = r["runs"][p]["mean"] / r["runs"][OURS]["mean"]
            cells.append(f"**{s:.2f}x** ({mean_s:.2f}x)")
            goal = GOALS.get(p)
            if goal and r["dim"] in GOAL_SIZES:
                goal_notes.append(
                    f"{r['dim']}² vs {p}: {s:.2f}x (goal >= {goal:g}x: {'met' if s >= goal else 'MISSED'})"
                )
        ratio_rows.append(cells)
    eq_rows = []
    for r in rows:
        eq = r["equivalence"]
        ref = eq["reference"]
        for m in [*modes, OURS]:
            if m == ref:
                continue
            e = eq.get(m)
            eq_rows.append(
                [
                    f"{r['dim']}²",
                    f"{m} vs {ref}",
                    r["runs"][ref]["simulated_frames"],
                    "–" if e is None else f"{e['max']:.2e}",
                    "–" if e is None else f"{e['rms']:.2e}",
                    f"{eq['cloth_size']:.1f}",
                    f"{eq.get('max_displacement', float('nan')):.3f}",
                    "–" if e is None else f"{e['max'] / eq['cloth_size']:.1e}",
                    "yes" if r["runs"][m]["finite"] else "**NO**",
                ]
            )
    info = machine_info()
    info["Taichi arch / threads"] = (
        f"cpu (x64), {settings['taichi_cpu_threads']} threads (taichi_anim and taichi_cpu)"
        if arch == "cpu"
        else f"cuda ({settings['gpu']})"
    )
    info["warp-lang"] = settings["versions"]["warp-lang"]
    info["usd-core (pxr)"] = settings["versions"]["usd-core"] + (
        "" if settings["pxr_imported"] else " (pxr not importable: Cloth class executed without it)"
    )
    info["Warp threads"] = "1 (Warp runs a CPU kernel on one thread)" if arch == "cpu" else "CUDA"
    sc = settings["scene"]
    ck = settings["cloth_kwargs"]
    cut_any = [f"{r['dim']}² {m}" for r in rows for m, x in r["runs"].items() if x["cut_by_budget"]]
    checks = [(r["dim"], r["runs"][OURS]["check"]) for r in rows]
    engine_checks = "; ".join(
        f"{d}²: spring list equal to Warp's, rest lengths within {c['rest_length_max_abs_diff']:.1e} m "
        f"of Warp's, engine loops {'serial' if c['serial'] else 'parallel'}"
        for d, c in checks
    )
    settings_text = (
        f"Scene: Warp's `Cloth` (`{settings['warp_benchmark_folder']}/benchmark_cloth.py`, warp-lang "
        f"{settings['versions']['warp-lang']}), dim x dim vertices in the XZ plane, spacing {ck['radius']} "
        f"m, mass {ck['mass']} kg per vertex, corners (0, 0) and (dim - 1, 0) pinned; springs structural + "
        f"shear + bend, k = {ck['stretch_stiffness']:g} / {ck['shear_stiffness']:g} / "
        f"{ck['bend_stiffness']:g} N/m, "
        f"damping {', '.join(f'{d:g}' for d in settings['spring_damping'])} kg/s; gravity {GRAVITY} m/s² "
        f"(numpy mode: 9.8, as in its source). {settings['frames']} timed frames of dt = "
        f"1/{round(1 / sc['sim_dt'])} s, "
        f"{sc['sim_substeps']} substeps each (symplectic Euler, h = dt/{sc['sim_substeps']}); every frame "
        f"returns the positions as a NumPy array, inside the timing. Each implementation: constructed "
        '("construct"), one first frame (compile / kernel-cache load included), '
        f"{WARMUP - 1} warm-up frame(s), "
        f"then the timed frames; a run stops after {settings['budget_s']:g} s of timed frames (at least "
        f"{MIN_FRAMES}). Peers: `benchmark_cloth_warp.WpIntegrator`, `benchmark_cloth_taichi.TiIntegrator`, "
        f"`benchmark_cloth_numpy.NpIntegrator` from that folder, unchanged. taichi_anim: `ta.init({arch!r})` "
        "(f32, offline cache on, Taichi's default thread count), `Builder.add_particles` (mass 0 pins) + "
        "`add_springs` (Warp's spring list; rest length = current distance) + `add_force_gravity`, "
        "`make_integrator('symplectic_euler', check_every=16)`. Checks: " + engine_checks + ". "
        "Speed-up = the peer's median ms per frame / taichi_anim's (in brackets: from the means). "
        "Cores busy = process CPU time / wall time over the timed frames. First frame: Warp compiles its "
        "module once per process (benchmark_cloth_warp clears the kernel cache at import), so only the first "
        "size's warp first frame holds it; both Taichi runs use Taichi's default offline cache "
        "(~/.cache/taichi), so theirs and ours may load kernels compiled by an earlier run."
    )
    load_note = (
        "Read the ratios (every implementation timed in the same process, minutes apart) together with "
        "the load figures in the machine table: absolute times move with other work on the machine."
    )
    text = (
        f"# Cloth: taichi_anim against Warp's cloth benchmark ({arch})\n\n"
        f"Regenerate: `{command_line(args, 'cloth_warp.py')}{' --arch cuda' if arch == 'cuda' else ''}` "
        f"(took {total / 60:.1f} min).\n\n"
        + settings_text
        + "\n\n"
        + load_note
        + "\n\n"
        + machine_table(info, load_start=load_start, load_end=load_end, date=date, engine=engine, other=other)
        + f"\n\n![{stem}]({stem}.png)\n\n## Speed-up of taichi_anim\n\n"
        + md_table(["grid", "vertices", "springs", *[f"over {p}" for p in peers]], ratio_rows)
        + ("\n\n**Goals.** " + "; ".join(goal_notes) + "." if goal_notes else "")
        + ("\n\nCut by the time budget: " + ", ".join(cut_any) + "." if cut_any else "")
        + "\n\n## ms per frame\n\n"
        + md_table(
            [
                "grid",
                "implementation",
                "frames timed",
                "median",
                "mean",
                "std",
                "min – max",
                "cores busy",
                "first frame",
                "construct",
                "speed-up of taichi_anim",
            ],
            time_rows,
        )
        + "\n\n## Same scene: positions against the reference\n\n"
        "Distance per vertex between each implementation's positions and the reference's after the same "
        "frames (warm-up included), next to the cloth's size and its largest displacement from the start. "
        "All run float32 with the same formulas; the peers scatter spring forces with float atomics, "
        "taichi_anim gathers them per vertex, so sums differ in rounding order. numpy uses g = 9.8.\n\n"
        + md_table(
            [
                "grid",
                "pair",
                "frames",
                "max |dx| [m]",
                "rms |dx| [m]",
                "cloth size [m]",
                "max displacement [m]",
                "max |dx| / size",
                "finite",
            ],
            eq_rows,
        )
    )
    if compile_result:
        text += (
            f"\n\n## taichi_anim JIT compile ({QUICK_SIZES[-1]}² cloth, fresh `ta.init` each)\n\n"
            "First frame minus a second frame, under each offline-cache condition (an empty cache folder "
            "for cold, the same folder after re-initialising for warm).\n\n"
            + md_table(COMPILE_HEADERS, compile_rows(f"{QUICK_SIZES[-1]}² cloth frame", compile_result))
        )
    text += "\n"
    page = fig_dir / f"{stem}.md"
    page.write_text(text)
    (fig_dir / f"{stem}.json").write_text(
        json.dumps(
            {
                "settings": settings,
                "machine": info,
                "load": [load_start, load_end],
                "rows": rows,
                "compile": compile_result,
                "total_s": total,
            },
            indent=1,
            default=str,
        )
    )
    plot(rows, modes, arch, fig_dir / f"{stem}.png")
    link = os.path.relpath(page, md_path.parent)
    summary = (
        f"## Cloth against Warp's cloth benchmark ({arch})\n\n"
        f"`benchmarks/cloth_warp.py{' --arch cuda' if arch == 'cuda' else ''}`; full page "
        f"[`{link}`]({link}). "
        f"Warp's `benchmark_cloth.py` scene (dim² vertices, 0.1 m spacing, k = 1000 N/m, damping 10, two "
        f"corners pinned), {settings['frames']} frames of 1/60 s × 16 substeps of symplectic Euler, "
        f"positions copied to NumPy every frame, f32, in one process. {date}, load average {load_start} "
        f"at start and {load_end} at end; taichi_anim sources {engine_row(engine)[1]}.\n\n"
        "Median ms per frame (speed-up of taichi_anim = peer / ours):\n\n"
        + md_table(
            ["grid", *[*modes, OURS], *[f"speed-up over {p}" for p in peers]],
            [
                [f"{r['dim']}²"]
                + [
                    _ms(r["runs"][m]["median"]) + ("*" if r["runs"][m]["cut_by_budget"] else "")
                    for m in [*modes, OURS]
                ]
                + [f"{speedup(r, p):.2f}x" for p in peers]
                for r in rows
            ],
        )
        + ("\n\n" + "; ".join(goal_notes) + "." if goal_notes else "")
        + ("\n\n\\* fewer frames (time budget)." if cut_any else "")
        + "\n"
    )
    write_section(md_path, stem, summary)
    log(f"wrote {page}, .json, .png and the {stem} section of {md_path} in {total / 60:.1f} min")


def plot(rows, modes, arch, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    ax = axes[0]
    dims = np.array([r["dim"] for r in rows])
    styles = {"warp_cpu": "s", "warp_gpu": "s", "taichi_cpu": "^", "taichi_gpu": "^", "numpy": "v", OURS: "o"}
    for k, m in enumerate([*modes, OURS]):
        med = np.array([r["runs"][m]["median"] for r in rows]) * 1e3
        lo = med - np.array([r["runs"][m]["min"] for r in rows]) * 1e3
        hi = np.array([r["runs"][m]["max"] for r in rows]) * 1e3 - med
        ax.errorbar(
            dims**2,
            med,
            yerr=[lo, hi],
            fmt="-" + styles.get(m, "o"),
            color="C0" if m == OURS else f"C{k + 1}",
            lw=2 if m == OURS else 1,
            capsize=3,
            label=m,
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xticks(dims**2, [f"{d}²" for d in dims])
    ax.minorticks_off()
    ax.set_xlabel("vertices")
    ax.set_ylabel("ms per frame (median; bars min – max)")
    ax.set_title("time per frame (16 substeps + copy to NumPy)", fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8)

    ax = axes[1]
    peers = [m for m in modes if m != "numpy"]
    width = 0.8 / max(len(peers), 1)
    xs = np.arange(len(rows))
    for k, p in enumerate(peers):
        vals = [speedup(r, p) for r in rows]
        ax.bar(
            xs + (k - (len(peers) - 1) / 2) * width,
            vals,
            width,
            color=f"C{modes.index(p) + 1}",
            label=f"over {p}",
        )
        if p in GOALS:
            ax.axhline(
                GOALS[p], color=f"C{modes.index(p) + 1}", ls="--", lw=1, label=f"goal {GOALS[p]:g}x over {p}"
            )
    ax.axhline(1.0, color="grey", lw=0.8)
    top = max([speedup(r, p) or 0.0 for r in rows for p in peers] + [GOALS.get(p, 1.0) for p in peers])
    ax.set_ylim(0.0, 1.45 * top)  # room for the legend above the bars
    ax.set_xticks(xs, [f"{r['dim']}²" for r in rows])
    ax.set_ylabel("speed-up of taichi_anim (peer median / ours)")
    ax.set_title("speed-up", fontsize=10)
    ax.legend(fontsize=8, ncol=2, loc="upper left")
    fig.suptitle(
        f"Warp's cloth benchmark scene, f32, {arch}"
        + (", shared 2-core CPU (Warp: 1 thread, Taichi: 2)" if arch == "cpu" else ""),
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
