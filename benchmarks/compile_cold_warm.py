"""Cold and warm starts of every demo: wall seconds of `taichi-anim demo NAME --frames 3 --no-export` with
an empty Taichi offline cache (cold) and again with the cache that run filled (warm), the compile seconds
run.json records for each, and ms per frame of a longer warm run (the run-time side of a compile change).
With `--before REV` the same figures for another commit (a `git archive` copy), demo by demo in turn.

Each run is a fresh process with its own cache folder (TI_OFFLINE_CACHE_FILE_PATH), so nothing depends on
what an earlier run left in ~/.cache/taichi.

    .venv/bin/python benchmarks/compile_cold_warm.py [--before REV] [--demos ...] [--start-reps N]
        [--run-reps N] [--quick]

With --demos the page is compile_cold_warm_subset (the full page keeps every demo), or --page NAME.
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from harness import Page, parse_args  # noqa: E402

from taichi_anim.scenes import SCENES  # noqa: E402

START_FRAMES = 3  # a first run as a new user makes it: a few frames, no files
RUN_FRAMES = 30  # the run-time figure: enough frames that the first frame's cost is small


def demo(tree: Path, name: str, frames: int, cache: Path, out: Path) -> dict:
    """One run of demo `name` from the engine in `tree`: wall seconds and run.json's timings."""
    env = dict(os.environ, PYTHONPATH=str(tree), TI_OFFLINE_CACHE_FILE_PATH=str(cache))
    cmd = [sys.executable, "-m", "taichi_anim", "demo", name, "--frames", str(frames), "--no-export"]
    t0 = time.perf_counter()
    run = subprocess.run([*cmd, "--quiet", "--out", str(out)], env=env, cwd=tree, capture_output=True)
    wall = time.perf_counter() - t0
    if run.returncode:
        raise RuntimeError(f"{name} ({tree}): {run.stderr.decode()[-2000:]}")
    timings = json.loads((out / "run.json").read_text())["timings"]
    return {"wall_s": wall, "compile_s": timings.get("compile_s"), "ms_per_frame": timings["ms_per_frame"]}


def starts(tree: Path, name: str, tmp: Path) -> dict:
    """Cold and warm start of demo `name` (engine in `tree`); the cache stays in tmp for the runs."""
    cache, out = tmp / "cache", tmp / "out"
    return {
        "cold": demo(tree, name, START_FRAMES, cache, out),
        "warm": demo(tree, name, START_FRAMES, cache, out),
    }


def medians(pairs: list[dict]) -> dict:
    """Medians of several cold/warm pairs (each its own empty cache): the starts, the compile seconds and
    the pairs' differences, with the spread of the two figures the goals are about."""
    med = statistics.median
    diffs = [p["cold"]["wall_s"] - p["warm"]["wall_s"] for p in pairs]
    warm_compile = [p["warm"]["compile_s"] for p in pairs]
    keys = ("wall_s", "compile_s")
    return {side: {key: med(p[side][key] for p in pairs) for key in keys} for side in ("cold", "warm")} | {
        "cold_minus_warm_s": med(diffs),
        "spread": f"{min(diffs):.1f}-{max(diffs):.1f}; {min(warm_compile):.2f}-{max(warm_compile):.2f}",
        "pairs": pairs,
    }


def steady(tree: Path, name: str, tmp: Path, run_frames: int) -> float:
    """ms per frame of a warm run of `run_frames` frames."""
    return demo(tree, name, run_frames, tmp / "cache", tmp / "out")["ms_per_frame"]


def git_tree(rev: str, into: Path) -> Path:
    """A copy of commit `rev`'s files in `into` (nothing in the repository changes)."""
    into.mkdir()
    archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    return into


def row(label: str, name: str, m: dict) -> list:
    cold, warm = m["cold"], m["warm"]
    return [
        name,
        label,
        f"{cold['wall_s']:.1f}",
        f"{warm['wall_s']:.1f}",
        f"{m['cold_minus_warm_s']:.1f}",
        f"{cold['compile_s']:.2f}",
        f"{warm['compile_s']:.2f}",
        m["spread"],
        f"{m['ms_per_frame']:.2f}",
    ]


def main(argv=None) -> int:
    def options(p):
        p.add_argument("--before", default=None, help="also measure this commit (a git archive copy)")
        p.add_argument("--demos", nargs="*", default=None, help="default: every demo")
        p.add_argument("--run-reps", type=int, default=1, help="warm runs per engine, alternating (median)")
        p.add_argument(
            "--start-reps", type=int, default=3, help="cold/warm pairs per engine, alternating (medians)"
        )
        p.add_argument("--page", default=None, help="results page name (default: compile_cold_warm[_subset])")

    args = parse_args(__doc__, argv, options)
    names = args.demos or (["cloth", "fountain"] if args.quick else list(SCENES))
    run_frames = 5 if args.quick else RUN_FRAMES
    res: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"after": ROOT}
        if args.before:
            trees = {"before": git_tree(args.before, Path(tmp) / "before"), "after": ROOT}
        for name in names:
            pairs: dict = {label: [] for label in trees}
            for _ in range(args.start_reps):  # each pair with an empty cache of its own, engines alternating
                work = {label: Path(tempfile.mkdtemp(dir=tmp)) for label in trees}
                for label, tree in trees.items():
                    pairs[label].append(starts(tree, name, work[label]))
            for label in trees:
                res[(name, label)] = medians(pairs[label])
            runs: dict = {label: [] for label in trees}
            for _ in range(args.run_reps):  # the engines alternate, so a slow spell hits both
                for label, tree in trees.items():
                    runs[label].append(steady(tree, name, work[label], run_frames))
            for label in trees:
                m = res[(name, label)]
                m["ms_per_frame"], m["ms_per_frame_runs"] = statistics.median(runs[label]), runs[label]
                print(f"{name} {label}: {row(label, name, m)[2:]}", flush=True)
    page = Page(
        args.page or ("compile_cold_warm" if args.demos is None else "compile_cold_warm_subset"),
        "Cold and warm starts per demo",
        args,
        {
            "start": f"`taichi-anim demo NAME --frames {START_FRAMES} --no-export`, process wall s; "
            f"medians of {args.start_reps} cold/warm pair(s) per engine, alternating engines, "
            "each pair with its own cache",
            "spread": "lowest-highest cold - warm of the pairs; lowest-highest warm compile",
            "cold": "empty offline cache (a fresh TI_OFFLINE_CACHE_FILE_PATH folder)",
            "warm": "the same command again, with the cache the cold run filled",
            "compile": "run.json timings.compile_s: kernels compiled or loaded while frames ran",
            "run time": f"median ms per frame of {args.run_reps} warm {run_frames}-frame run(s) per engine, "
            "alternating engines (run.json timings.ms_per_frame)",
            "before": args.before or "not measured",
        },
    )
    page.table(
        "Per demo",
        [
            "demo",
            "engine",
            "cold s",
            "warm s",
            "cold - warm s",
            "compile cold s",
            "compile warm s",
            "spread",
            "ms/frame",
        ],
        [row(label, name, res[(name, label)]) for name in names for label in trees],
    )
    page.write({f"{n} {label}": m for (n, label), m in res.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
