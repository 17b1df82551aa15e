"""A parameter sweep against the same runs one after another: 16 runs of the `cloth` demo (4 seeds x 4
frame counts, no export) through `taichi_anim.sweep.sweep` (the cores' worth of runs at a time, one
Taichi thread each, its warm-up run included) and as 16 `taichi-anim demo` commands run in turn (each
on every core). Both start from a warm kernel cache (one demo run first); the total wall time of each
and their ratio are the figures, with the steady ms per frame of the runs on each side.

    .venv/bin/python benchmarks/sweep_speed.py [--quick]
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from harness import Page, fmt_s, log, parse_args

from taichi_anim.sweep import sweep

SEEDS = [0, 1, 2, 3]
FRAMES = [30, 60, 90, 120]  # the cloth demo: ~20 ms per frame on one core of a 2-core Xeon
QUICK_SEEDS, QUICK_FRAMES = [0, 1], [2, 3]


def demo(seed: int, frames: int, out: Path) -> float:
    """One `taichi-anim demo cloth` command; its steady ms per frame from its run.json."""
    cmd = [sys.executable, "-m", "taichi_anim", "demo", "cloth", "--seed", str(seed), "--frames", str(frames)]
    subprocess.run([*cmd, "--no-export", "--quiet", "--out", str(out)], check=True, capture_output=True)
    return json.loads((out / "run.json").read_text())["timings"]["ms_per_frame"]


def one_after_another(configs, folder: Path) -> dict:
    t0 = time.perf_counter()
    ms = [demo(s, f, folder / f"cli_seed{s}_frames{f}") for s, f in configs]
    return {"total_s": time.perf_counter() - t0, "ms_per_frame": statistics.median(ms)}


def swept(seeds, frames, folder: Path) -> dict:
    t0 = time.perf_counter()
    result = sweep(
        "cloth", {"seed": seeds, "frames": frames}, export=False, out=folder / "sweep", progress=False
    )
    total = time.perf_counter() - t0
    bad = [r["run_id"] for r in result.rows if r["status"] != "complete"]
    if bad:
        raise RuntimeError(f"runs that did not complete: {bad} (see {result.out})")
    ms = statistics.median(r["wall_ms_per_frame"] for r in result.rows)
    cpu = statistics.median(r["cpu_ms_per_frame"] for r in result.rows)
    warm = result.warmup["seconds"] if result.warmup else None
    return {"total_s": total, "ms_per_frame": ms, "cpu_ms_per_frame": cpu, "warmup_s": warm}


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    seeds, frames = (QUICK_SEEDS, QUICK_FRAMES) if args.quick else (SEEDS, FRAMES)
    configs = [(s, f) for s in seeds for f in frames]
    with tempfile.TemporaryDirectory(prefix="taichi_anim_sweep_speed_") as tmp:
        folder = Path(tmp)
        demo(0, 1, folder / "warm")  # both sides start with the cloth's kernels in the offline cache
        log(f"{len(configs)} runs one after another ...")
        cli = one_after_another(configs, folder)
        log(f"  {fmt_s(cli['total_s'])}")
        log(f"{len(configs)} runs as a sweep ...")
        par = swept(seeds, frames, folder)
        log(f"  {fmt_s(par['total_s'])} (warm-up {fmt_s(par['warmup_s'])})")
    page = Page(
        "sweep_speed",
        "Parameter sweep against the same runs one after another",
        args,
        {
            "runs": f"cloth demo, seeds {seeds} x frames {frames} = {len(configs)} runs, no export",
            "sweep": f"taichi_anim.sweep.sweep, {os.cpu_count()} runs at a time, 1 Taichi thread each, "
            "with its 1-frame warm-up run",
            "one after another": "`python -m taichi_anim demo cloth --seed S --frames F --no-export "
            "--quiet`, Taichi on every core",
            "kernel cache": "warm on both sides (one demo run before either)",
        },
    )
    page.table(
        "Total wall time",
        [
            "runs",
            "one after another",
            "sweep",
            "ratio",
            "sweep warm-up",
            "ms/frame (one after another)",
            "ms/frame (sweep; CPU ms)",
        ],
        [
            [
                len(configs),
                fmt_s(cli["total_s"]),
                fmt_s(par["total_s"]),
                f"{cli['total_s'] / par['total_s']:.2f}x",
                fmt_s(par["warmup_s"]),
                f"{cli['ms_per_frame']:.1f}",
                f"{par['ms_per_frame']:.1f} ({par['cpu_ms_per_frame']:.1f})",
            ]
        ],
        note="ms/frame: the median over the runs of each run's steady frame (run.json's ms_per_frame).",
    )
    page.write({"one_after_another": cli, "sweep": par, "configs": configs})


if __name__ == "__main__":
    main()
