"""Realtime report: the largest size of each workload whose frame holds real time on this CPU (60 frames/s:
a frame of 1/60 s of simulated time in at most 1/60 s = 16.7 ms of wall time; the spheres demo has
1/30 s frames, so it is held to 30 frames/s = 33.3 ms, and whether it also holds 16.7 ms is reported).

Workloads (float32, `ta.init("cpu")`, Taichi's default thread count; existing builders, public API only):
- particles: the particle fountain of benchmarks/particles.py (`build(n, Variant(0.2))`: one disc emitter
  of capacity N, lifetime 0.5 s +-20 %, rate N / 0.5 s, gravity, container box), a frame = 10 steps of
  1/600 s (`Stepper.advance`). The pool is filled first, as particles.py does (`Variant.fill_steps` =
  380 steps = 38 frames), capped at FILL_BUDGET_S of wall time; alive / N while timed is reported.
  Sizes N from 1e4 up.
- spheres: the `spheres` demo scene (`taichi_anim.scenes.make_scene("spheres", particles=N)`: hard spheres
  of 6 mm falling as a column into a box, sphere contacts with 1 sweep), its own frame: 1/30 s of 200
  steps (`Scene.advance_frame`), from the start of the demo (the column falling and splashing). Sizes N
  from 1e3 up.
- cloth, explicit: NVIDIA Warp's cloth-benchmark layout (warp/examples/benchmarks/benchmark_cloth.py:
  n x n vertices 0.1 m apart in the XZ plane, 0.1 kg each, two corners pinned, structural, shear and
  bend springs in Warp's order from `cloth_implicit.warp_springs`) with Warp's own k = 1e3 N/m and damping
  10 kg/s, gravity; symplectic Euler, a frame = 16 substeps of 1/960 s (`integ.step(model, state, 1/60,
  16)`). Grids n from 32 up.
- cloth, implicit: `cloth_implicit.build("warp", n)` (the same layout with k = 1e4 N/m),
  `IntegratorImplicitEuler(linear_solver="pcg", tol=1e-3, max_iterations=1000, warm_start=True,
  check_every=10)`, a frame = one step of 1/60 s. Mean PCG iterations per frame are reported.

One probe = one size in a fresh `ta.init` (the offline cache on, in an empty folder made for this run,
so every size compiles from scratch): build; the first frame, timed apart (it holds the JIT compile:
compile = first frame - median frame); warm-up frames up to WARMUP (3) frames in all (particles: the
fill); then FRAMES (20) frames, each timed alone with `ti.sync()` before each clock read; ms/frame = their
median. A frame is all of its substeps and nothing else (no export, no rendering). Cores busy = the
process's CPU time / wall time over the timed frames; other load = CPU used by other processes meanwhile.
A probe whose timed frames pass PROBE_BUDGET_S stops early (at least 5 frames; marked).

Search per workload: probe the start size, then double while the frame holds its budget (up to the cap:
particles 2e7, spheres 1e6, cloth n = 512), then BISECT (3) geometric bisections between the last passing
and the first failing size (the bracket narrows to 2^(1/8), 9 %). If the start size fails, the search
halves down to start / 16 first. Reported per workload: the largest passing size, its ms/frame, the
nearest failing size above it and its ms/frame, cores busy and compile time at the size found.

    .venv/bin/python benchmarks/realtime.py          # full run (~2-3 min): benchmarks/results/
                                                     # realtime.{md,json,png} and the "realtime" section
                                                     # of benchmarks/RESULTS.md
    .venv/bin/python benchmarks/realtime.py --quick  # smoke (~1 min, small caps): benchmarks/out/
"""

import json
import math
import os
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass

import cloth_implicit
import numpy as np
import particles
from common import (
    OtherLoad,
    clock,
    command_line,
    engine_fingerprint,
    fmt_s,
    init,
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
from taichi_anim.scenes import make_scene

FRAMES = 20  # timed frames per probe (ms/frame = their median)
WARMUP = 3  # frames before the timed ones, the first (JIT compile) included
BISECT = 3  # geometric bisections after the doubling search
FLOOR_DIVISOR = 16  # a failing start size is halved down to start / 16 at most
PROBE_BUDGET_S = 10.0  # [s] of timed frames per probe at most (then >= MIN_FRAMES)
MIN_FRAMES = 5
FILL_BUDGET_S = 20.0  # [s] of wall time filling the particle pool at most
HZ60 = 1.0 / 60.0  # [s]
CLOTH_SUBSTEPS = 16
CLOTH_K_EXPLICIT = 1.0e3  # [N/m] Warp's cloth benchmark
CLOTH_DAMPING = 10.0  # [kg/s]


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system


# ---------------------------------------------------------------------------------------------------------
# workloads: each built in the current Taichi; frame() advances one frame


class Particles:
    def __init__(self, n: int):
        self.variant = particles.Variant(0.2)
        self.model, self.state, self.integ = particles.build(n, self.variant)
        self.stepper = self.integ.stepper_for(self.model)
        self.fill_frames = math.ceil(self.variant.fill_steps / particles.STEPS_PER_FRAME)
        self.elements = n

    def frame(self) -> None:
        self.stepper.advance(self.state, particles.DT, particles.STEPS_PER_FRAME)

    def notes(self) -> dict:
        return {"alive_fraction": float(self.state.alive_mask().mean())}


class Spheres:
    fill_frames = 0

    def __init__(self, n: int):
        self.scene = make_scene("spheres", particles=n)
        self.model = self.scene.model
        self.integ = self.scene.integrator
        self.elements = n

    def frame(self) -> None:
        self.scene.advance_frame()

    def notes(self) -> dict:
        return {"substeps": self.scene.substeps, "dt": self.scene.dt}


class ClothExplicit:
    fill_frames = 0

    def __init__(self, n: int):
        s = cloth_implicit.SCENES["warp"]
        j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")  # vertex j n + i at (i, 0, j) * 0.1
        x = np.stack([s["spacing"] * i.ravel(), np.zeros(n * n), s["spacing"] * j.ravel()], axis=1)
        mass = np.full(n * n, s["vertex_mass"])
        mass[[0, n - 1]] = 0.0  # pinned
        b = ta.Builder()
        b.add_particles(x, mass=mass)
        b.add_springs(cloth_implicit.warp_springs(n), stiffness=CLOTH_K_EXPLICIT, damping=CLOTH_DAMPING)
        b.add_force_gravity(cloth_implicit.GRAVITY)
        self.model = b.finalize()
        self.state = self.model.state()
        self.integ = ta.make_integrator("symplectic_euler", check_every=CLOTH_SUBSTEPS)
        self.elements = n * n

    def frame(self) -> None:
        self.integ.step(self.model, self.state, HZ60, CLOTH_SUBSTEPS)

    def notes(self) -> dict:
        return {"springs": int(self.model.spring_count)}


class ClothImplicit:
    fill_frames = 0

    def __init__(self, n: int):
        self.model, self.state = cloth_implicit.build("warp", n)
        self.integ = ta.IntegratorImplicitEuler(linear_solver="pcg", tol=1e-3, max_iterations=1000,
                                                warm_start=True, check_every=10)  # fmt: skip
        self.iterations: list[int] = []
        self.elements = n * n

    def frame(self) -> None:
        self.integ.step(self.model, self.state, HZ60)
        self.iterations.append(int(self.integ.last_solve.iterations))

    def notes(self) -> dict:
        timed = self.iterations[-FRAMES:]
        return {
            "springs": int(self.model.spring_count),
            "pcg_iterations_mean": float(np.mean(timed)),
            "pcg_iterations_max": int(max(timed)),
        }


@dataclass(frozen=True)
class Workload:
    key: str
    title: str
    frame: str  # what one frame is
    budget: float  # [s] wall time a frame may take (= its simulated time)
    start: int
    cap: int
    quick_cap: int
    make: Callable
    size_label: Callable[[int], str]
    sig3: bool  # round bisection sizes to 3 significant digits (counts) or to integers (grid sides)


def _count(n: int) -> str:
    return f"{n:.3g}" if n >= 1e4 else str(n)


WORKLOADS = [
    Workload("particles", "particles (fountain)", "10 steps of 1/600 s = 1/60 s", HZ60, 10**4, 2 * 10**7,
             4 * 10**4, Particles, lambda n: f"N = {_count(n)}", True),
    Workload("spheres", "spheres (demo scene)", "200 steps of 1/6000 s = 1/30 s", 1.0 / 30.0, 10**3, 10**6,
             2 * 10**3, Spheres, lambda n: f"N = {_count(n)}", True),
    Workload("cloth_explicit", "cloth, explicit (Warp's layout, k = 1e3)", "16 substeps of 1/960 s = 1/60 s",
             HZ60, 32, 512, 64, ClothExplicit, lambda n: f"{n}²", False),
    Workload("cloth_implicit", "cloth, implicit PCG (Warp's layout, k = 1e4)", "1 step of 1/60 s", HZ60, 32,
             512, 64, ClothImplicit, lambda n: f"{n}²", False),
]  # fmt: skip


# ---------------------------------------------------------------------------------------------------------
# measuring


def probe(w: Workload, n: int, cache: str) -> dict:
    """Build size n of workload w in a fresh Taichi and time its frames (module docstring)."""
    init("f32", offline_cache_file_path=cache)
    a = clock()
    run = w.make(n)
    build = clock() - a
    mode = run.integ.stepper_for(run.model).frame_mode()
    a = clock()
    run.frame()
    first = clock() - a
    warm, fill_cut = 1, False
    a = clock()
    while warm < max(WARMUP, run.fill_frames):
        if warm >= WARMUP and clock() - a > FILL_BUDGET_S:
            fill_cut = True
            break
        run.frame()
        warm += 1
    times = []
    other = OtherLoad()
    c0, a = cpu_seconds(), clock()
    while len(times) < FRAMES and not (len(times) >= MIN_FRAMES and sum(times) > PROBE_BUDGET_S):
        t0 = clock()
        run.frame()
        times.append(clock() - t0)
    wall = clock() - a
    busy = (cpu_seconds() - c0) / wall
    med = statistics.median(times)
    r = {
        "n": n,
        "elements": run.elements,
        "build_s": build,
        "first_frame_s": first,
        "compile_s": max(first - med, 0.0),
        "warmup_frames": warm,
        "fill_cut": fill_cut,
        "frames": len(times),
        "frame_s": med,
        "frame_min_s": min(times),
        "frame_max_s": max(times),
        "frame_times_s": times,
        "passes": med <= w.budget,
        "holds_60": med <= HZ60,
        "cores_busy": busy,
        "other_load": other.cores(),
        "frame_mode": mode,
        **run.notes(),
    }
    log(
        f"{w.key} {w.size_label(n)}: {med * 1e3:.2f} ms/frame ({'pass' if r['passes'] else 'FAIL'}), "
        f"compile {r['compile_s']:.2f} s, {busy:.2f} cores busy, {mode['mode']}"
    )
    return r


def geometric_mid(lo: int, hi: int, sig3: bool) -> int | None:
    m = math.sqrt(lo * hi)
    if sig3:
        m = float(f"{m:.3g}")
    m = int(round(m))
    return m if lo < m < hi else None


def search(w: Workload, cap: int, bisect: int, cache: str) -> dict:
    """Doubling (or halving, if the start fails) then geometric bisection; every probe kept."""
    probes: dict[int, dict] = {}

    def ok(n: int) -> bool:
        if n not in probes:
            probes[n] = probe(w, n, cache)
        return probes[n]["passes"]

    n = w.start
    if ok(n):
        while ok(n) and 2 * n <= cap:
            n *= 2
        lo, hi = (n, None) if ok(n) else (n // 2, n)
    else:
        floor = max(w.start // FLOOR_DIVISOR, 1)
        while not ok(n) and n // 2 >= floor:
            n //= 2
        lo, hi = (n, 2 * n) if ok(n) else (None, n)
    for _ in range(bisect if lo is not None and hi is not None else 0):
        m = geometric_mid(lo, hi, w.sig3)
        if m is None:
            break
        lo, hi = (m, hi) if ok(m) else (lo, m)
    return {
        "workload": w.key,
        "largest": lo,
        "next_failing": hi,
        "probes": [probes[k] for k in sorted(probes)],
    }


# ---------------------------------------------------------------------------------------------------------
# report


def ms(r: dict | None) -> str:
    return "–" if r is None else f"{r['frame_s'] * 1e3:.2f}"


def summary_rows(results: list[dict]) -> list[list[str]]:
    rows = []
    for w, res in zip(WORKLOADS, results, strict=True):
        by = {p["n"]: p for p in res["probes"]}
        lo, hi = res["largest"], res["next_failing"]
        p, q = by.get(lo), by.get(hi)
        fps = round(1.0 / w.budget)
        size = f"none down to {w.size_label(min(by))}" if lo is None else f"**{w.size_label(lo)}**"
        if lo is not None and lo == max(by) and hi is None:
            size += " (the cap: larger not tried)"
        nxt = "–" if q is None else f"{w.size_label(hi)}: {ms(q)} ms"
        note = ""
        if p is not None and "alive_fraction" in p:
            note = f"alive / N = {p['alive_fraction']:.2f}" + (" (fill cut)" if p["fill_cut"] else "")
        if p is not None and "pcg_iterations_mean" in p:
            note = f"PCG iterations {p['pcg_iterations_mean']:.1f} mean, {p['pcg_iterations_max']} max"
        if w.key == "spheres":
            r = p or q
            note = (
                f"holds 60 fps (16.7 ms): {'yes' if p is not None and p['holds_60'] else 'no'}; "
                f"{r['frame_s'] / r['substeps'] * 1e6:.0f} µs per step at {w.size_label(r['n'])}"
            )
        rows.append(
            [
                w.title,
                f"{w.frame}; real time = {w.budget * 1e3:.1f} ms ({fps} fps)",
                size,
                ms(p),
                nxt,
                "–" if p is None else f"{p['cores_busy']:.2f}",
                "–" if p is None else f"{p['compile_s']:.2f}",
                "–" if p is None else p["frame_mode"]["mode"],
                note,
            ]
        )
    return rows


SUMMARY_HEADERS = [
    "workload",
    "frame",
    "largest size holding real time (60 fps; 30 for spheres' 1/30 s frame)",
    "ms/frame there",
    "next size tried: ms/frame",
    "cores busy",
    "compile s",
    "frame launch mode",
    "notes",
]


def probe_rows(results: list[dict]) -> list[list[str]]:
    rows = []
    for w, res in zip(WORKLOADS, results, strict=True):
        for p in res["probes"]:
            extra = []
            if "alive_fraction" in p:
                extra.append(f"alive / N {p['alive_fraction']:.2f}" + (", fill cut" if p["fill_cut"] else ""))
            if "pcg_iterations_mean" in p:
                extra.append(f"PCG it {p['pcg_iterations_mean']:.1f}")
            if p["frames"] < FRAMES:
                extra.append(f"cut at {p['frames']} frames")
            rows.append(
                [
                    w.key,
                    w.size_label(p["n"]),
                    f"{p['elements']:,}",
                    f"{p['frame_s'] * 1e3:.2f}",
                    f"{p['frame_min_s'] * 1e3:.2f} / {p['frame_max_s'] * 1e3:.2f}",
                    "pass" if p["passes"] else "fail",
                    f"{p['cores_busy']:.2f}",
                    f"{p['other_load']:.2f}",
                    f"{p['compile_s']:.2f}",
                    fmt_s(p["build_s"]),
                    p["frame_mode"]["mode"],
                    "; ".join(extra),
                ]
            )
    return rows


def plot(results: list[dict], path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, NullFormatter

    fig, axes = plt.subplots(1, len(WORKLOADS), figsize=(4.0 * len(WORKLOADS), 3.8))
    for ax, w, res in zip(axes, WORKLOADS, results, strict=True):
        ps = res["probes"]
        xs = [p["elements"] for p in ps]
        ax.plot(xs, [p["frame_s"] * 1e3 for p in ps], "o-", color="C0", ms=4)
        ax.axhline(w.budget * 1e3, color="green", ls="--", lw=1, label=f"real time {w.budget * 1e3:.1f} ms")
        if w.budget != HZ60:
            ax.axhline(HZ60 * 1e3, color="orange", ls=":", lw=1, label="60 fps 16.7 ms")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("vertices" if w.key.startswith("cloth") else "particles / spheres")
        ax.set_ylabel("median ms per frame")
        ax.set_title(w.title, fontsize=9)
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Frame wall time against size, f32, shared 2-core CPU", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> None:
    args = parse_args(__doc__.splitlines()[0], argv)
    md_path, fig_dir = output_paths(args)
    fig_dir.mkdir(parents=True, exist_ok=True)
    bisect = 2 if args.quick else BISECT
    load_start, engine, other, date = (
        load_average(),
        engine_fingerprint(),
        OtherLoad(),
        time.strftime("%Y-%m-%d %H:%M %Z"),
    )
    started = time.perf_counter()
    cache = tempfile.mkdtemp(prefix="taichi_anim_realtime_cache_")
    try:
        results = [search(w, w.quick_cap if args.quick else w.cap, bisect, cache) for w in WORKLOADS]
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    total = time.perf_counter() - started
    info = machine_info()
    mtable = machine_table(info, load_start=load_start, load_end=load_average(), date=date, engine=engine,
                           other=other)  # fmt: skip
    settings = (
        f"Regenerate: `{command_line(args, 'realtime.py')}` (took {total / 60:.1f} min).\n\n"
        "The largest size of each workload whose median frame wall time is within its frame's simulated "
        "time (60 frames/s = 16.7 ms; the spheres demo's frames are 1/30 s, so 30 frames/s = 33.3 ms, and "
        "the notes say whether it also holds 16.7 ms). Float32, `ta.init('cpu')`, Taichi's default thread "
        f"count, one fresh `ta.init` per size (offline cache in an empty folder: every size compiles). Per "
        f"size: the first frame timed apart (compile = first frame - median frame), warm-up to {WARMUP} "
        f"frames (particles: the pool filled first, {particles.Variant(0.2).fill_steps} steps, at most "
        f"{FILL_BUDGET_S:g} s), then the median of {FRAMES} frames, each timed alone with `ti.sync()` "
        "before each clock read; a frame is all its substeps and nothing else (no export, no rendering). "
        f"Search: double from the start size while it holds (caps: particles 2e7, spheres 1e6, cloth "
        f"512²{'; --quick: 4e4, 2e3, 64²' if args.quick else ''}), then {bisect} geometric bisections "
        "between the last passing and the first failing size. Cores busy = process CPU time / wall time "
        "over the timed frames. Workloads: the fountain of `benchmarks/particles.py` (jitter 0.2); the "
        "`spheres` demo scene from its start (timed frames 4-23: the column falling and splashing into the "
        "box, 1 sweep); Warp's cloth-benchmark "
        f"layout (0.1 m spacing, 0.1 kg per vertex, 2 corners pinned, damping {CLOTH_DAMPING:g}) with k = "
        f"1e3, symplectic Euler, {CLOTH_SUBSTEPS} substeps per frame; the same layout with k = 1e4 "
        "(`cloth_implicit.build('warp', n)`), implicit Euler with PCG tol 1e-3, warm start, one step of "
        "1/60 s per frame. The machine is shared with other sessions: see the other-load column."
    )
    page = (
        "# Realtime: the largest sizes that hold 60 frames/s on this CPU\n\n"
        + settings
        + "\n\n"
        + mtable
        + "\n\n![realtime](realtime.png)\n\n## Largest size at real time\n\n"
        + md_table(SUMMARY_HEADERS, summary_rows(results))
        + "\n\n## Every size tried\n\n"
        + md_table(
            [
                "workload",
                "size",
                "particles / vertices",
                "median ms/frame",
                "min / max ms",
                "real time",
                "cores busy",
                "other load",
                "compile s",
                "build",
                "frame launch mode",
                "notes",
            ],
            probe_rows(results),
        )  # fmt: skip
        + "\n"
    )
    (fig_dir / "realtime.md").write_text(page)
    (fig_dir / "realtime.json").write_text(
        json.dumps(
            {
                "settings": {
                    "frames": FRAMES,
                    "warmup": WARMUP,
                    "bisect": bisect,
                    "fill_budget_s": FILL_BUDGET_S,
                    "probe_budget_s": PROBE_BUDGET_S,
                    "workloads": [
                        {
                            "key": w.key,
                            "title": w.title,
                            "frame": w.frame,
                            "budget_s": w.budget,
                            "start": w.start,
                            "cap": w.quick_cap if args.quick else w.cap,
                        }
                        for w in WORKLOADS
                    ],
                    "quick": args.quick,
                },
                "machine": info,
                "date": date,
                "engine": engine,
                "results": results,
                "total_s": total,
            },
            indent=1,
            default=str,
        )  # fmt: skip
    )
    plot(results, fig_dir / "realtime.png")
    link = os.path.relpath(fig_dir / "realtime.md", md_path.parent)
    write_section(
        md_path,
        "realtime",
        "## Realtime: largest sizes at 60 frames/s\n\n"
        f"`benchmarks/realtime.py`; full page [`{link}`]({link}) (settings, machine, every size tried). "
        f"{date}, {info['CPU']}, {info['logical CPUs']} logical CPUs, shared machine ({other.cores():.2f} "
        f"cores used by other processes on average); taichi_anim sources {engine.split()[0]}. Median of "
        f"{FRAMES} frames after warm-up, f32, default threads.\n\n"
        + md_table(SUMMARY_HEADERS, summary_rows(results)),
    )
    log(f"wrote {fig_dir / 'realtime.md'}, .json, .png and the realtime section of {md_path} ({total:.0f} s)")


if __name__ == "__main__":
    main()
