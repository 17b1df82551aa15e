"""Taichi's front end in a warm start, with Taichi's own vector and matrix operations and with the
engine's (taichi_anim/tensor_ops.py): the seconds every kernel instance's front end takes
(`Kernel.materialize`, paid in every process, cache or not) and its first launches (machine code from
the cached IR), over a whole `taichi-anim demo NAME --frames 3 --no-export` (scene build included), the
largest kernels by name, and the warm run's ms per frame (the run-time side).

Each mode (TAICHI_ANIM_PLAIN_MATRIX_OPS=1 for Taichi's operations) has its own offline cache folder,
filled by a first run that is not counted; then the modes alternate, `--reps` runs each, and the page
gives medians.

    .venv/bin/python benchmarks/front_end.py [--demos dominoes pour ...] [--reps N] [--quick]
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from harness import Page, parse_args  # noqa: E402

DEMOS = ["dominoes", "pile", "dam_break", "pour", "flag"]
MODES = {"Taichi's operations": "1", "replaced (tensor_ops)": "0"}
RUN_FRAMES = 30  # the run-time figure

# The child: the CLI's demo inside one CompileClock, which prints its per-kernel totals as JSON.
_CHILD = """
import json, sys
from taichi_anim.compile_clock import CompileClock
from taichi_anim.cli import main
with CompileClock() as clock:
    main(sys.argv[1:])
print("FRONT_END_JSON " + json.dumps(clock.by_kernel))
"""


def run(name: str, frames: int, plain: str, cache: Path, out: Path) -> dict:
    """One run of demo `name`: per-kernel [front end s, first launches s, instances] and ms per frame."""
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=str(cache), TAICHI_ANIM_PLAIN_MATRIX_OPS=plain)
    cmd = ["demo", name, "--frames", str(frames), "--no-export", "--quiet", "--out", str(out)]
    done = subprocess.run([sys.executable, "-c", _CHILD, *cmd], env=env, cwd=ROOT, capture_output=True)
    if done.returncode:
        raise RuntimeError(f"{name}: {done.stderr.decode()[-2000:]}")
    line = next(x for x in done.stdout.decode().splitlines() if x.startswith("FRONT_END_JSON "))
    kernels = json.loads(line.split(" ", 1)[1])
    timings = json.loads((out / "run.json").read_text())["timings"]
    return {"kernels": kernels, "ms_per_frame": timings["ms_per_frame"]}


def totals(r: dict) -> tuple[float, float]:
    k = r["kernels"].values()
    return sum(v[0] for v in k), sum(v[1] for v in k)


def main(argv=None) -> int:
    def options(p):
        p.add_argument("--demos", nargs="*", default=None, help=f"default: {' '.join(DEMOS)}")
        p.add_argument("--reps", type=int, default=3, help="warm runs per mode, alternating (median)")

    args = parse_args(__doc__, argv, options)
    names = args.demos or (["dominoes"] if args.quick else DEMOS)
    reps = 1 if args.quick else args.reps
    rows, top_rows, data = [], [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            work = {m: Path(tempfile.mkdtemp(dir=tmp)) for m in MODES}
            for mode, plain in MODES.items():  # fill each mode's cache; not counted
                run(name, 3, plain, work[mode] / "cache", work[mode] / "out")
            runs, ms_runs = {m: [] for m in MODES}, {m: [] for m in MODES}
            for _ in range(reps):  # the modes alternate, so a slow spell hits both
                for mode, plain in MODES.items():
                    runs[mode].append(run(name, 3, plain, work[mode] / "cache", work[mode] / "out"))
                for mode, plain in MODES.items():
                    steady = run(name, RUN_FRAMES, plain, work[mode] / "cache", work[mode] / "out")
                    ms_runs[mode].append(steady["ms_per_frame"])
            ms = {m: statistics.median(v) for m, v in ms_runs.items()}
            data[name] = {"runs": runs, "ms_per_frame_runs": ms_runs}
            for mode in MODES:
                fe = statistics.median(totals(r)[0] for r in runs[mode])
                ld = statistics.median(totals(r)[1] for r in runs[mode])
                n = sum(v[2] for v in runs[mode][0]["kernels"].values())
                rows.append([name, mode, f"{fe:.2f}", f"{ld:.2f}", n, f"{ms[mode]:.2f}"])
                print(name, rows[-1][1:], flush=True)
            first = runs[next(iter(MODES))][0]["kernels"]
            for kernel in sorted(first, key=lambda k: -first[k][0])[:3]:
                fronts = [statistics.median(r["kernels"].get(kernel, [0])[0] for r in runs[m]) for m in MODES]
                top_rows.append([name, kernel, *(f"{f:.2f}" for f in fronts)])
    page = Page(
        "front_end",
        "Warm starts' front end: Taichi's vector operations against tensor_ops",
        args,
        {
            "run": "`taichi-anim demo NAME --frames 3 --no-export` in a fresh process, inside one "
            "CompileClock (scene build and frames)",
            "front end": "Kernel.materialize of every new kernel instance (AST to IR; every process pays it)",
            "first launches": "each new instance's first launch: machine code from the cached IR, plus that "
            "launch's run time",
            "modes": "TAICHI_ANIM_PLAIN_MATRIX_OPS=1 (Taichi's operations) and 0 (replaced), each with its "
            "own offline cache, warmed by one uncounted run",
            "repetitions": f"{reps} warm runs per mode, alternating; medians",
            "ms/frame": f"run.json timings.ms_per_frame of warm {RUN_FRAMES}-frame runs, one per repetition "
            "and mode, alternating; median",
        },
    )
    page.table(
        "Per demo",
        ["demo", "mode", "front end s", "first launches s", "instances", "ms/frame"],
        rows,
    )
    page.table(
        "Front end of the largest kernels (s)",
        ["demo", "kernel", *MODES],
        top_rows,
    )
    page.write(data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
