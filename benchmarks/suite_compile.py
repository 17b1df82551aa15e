"""Where the default test run's time goes: compiling kernels against running them, per kernel name.

Runs the default test suite (the README's command: `pytest -q -n 2`) with a plugin
(suite_compile_plugin.py) that times Taichi's front end and each kernel instance's first launch, per
test and per kernel name. The first run starts from an empty offline-cache folder (as CI, on a clean
machine), the next ones on the cache it filled ("warm"). After the first run the page counts the kernels
the cache holds (one file each) by name: how many variants each kernel was compiled in.

    .venv/bin/python benchmarks/suite_compile.py [--runs 2] [--quick] [-- pytest arguments]
"""

import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from harness import Page, log, parse_args  # noqa: E402

QUICK_TESTS = ["tests/test_rigid_contacts.py", "tests/test_cloth_solvers.py"]
TOP = 15


def _run(tests: list[str], cache: Path, out: Path, workers: int) -> dict:
    out.mkdir(parents=True)
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=str(cache), SUITE_COMPILE_OUT=str(out))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "benchmarks"), env.get("PYTHONPATH", "")])
    cmd = [sys.executable, "-m", "pytest", "-q", "-n", str(workers), "-p", "suite_compile_plugin"]
    cmd += ["-p", "no:cacheprovider", *tests]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    summary = [line for line in done.stdout.splitlines() if re.search(r"\d+ (passed|failed)", line)]
    if not summary:
        raise RuntimeError(f"pytest gave no result: {(done.stdout + done.stderr)[-2000:]}")
    front, load, instances = collections.Counter(), collections.Counter(), collections.Counter()
    tests_wall = compiling = 0.0
    for part in out.glob("*.json"):
        d = json.loads(part.read_text())
        front.update(d["front"])
        load.update(d["load"])
        instances.update(d["instances"])
        for key, s in d["per_test"].items():
            if key.endswith("::wall"):
                tests_wall += s
            else:
                compiling += s
    return {
        "wall_s": wall,
        "result": summary[-1] if summary else done.stdout[-300:],
        "tests_s": tests_wall,
        "compile_s": compiling,
        "front_s": sum(front.values()),
        "load_s": sum(load.values()),
        "kernels": {k: [front[k], load[k], instances[k]] for k in instances},
    }


def _variants(cache: Path) -> tuple[int, int, collections.Counter]:
    """(files, bytes, files per kernel name) of an offline-cache folder: one file per compiled kernel."""
    names: collections.Counter = collections.Counter()
    files = list(cache.rglob("*.tic"))
    for f in files:
        head = f.read_bytes()[:200_000]
        m = re.search(rb'"name":"([A-Za-z_0-9]+?)_(?:c\d+_)?\d+_kernel_', head)
        names[m.group(1).decode() if m else "?"] += 1
    return len(files), sum(f.stat().st_size for f in files), names


def main():
    def extra(p):
        p.add_argument("--runs", type=int, default=2, help="runs on one cache folder, the first cold")
        p.add_argument("--workers", type=int, default=2)
        p.add_argument("tests", nargs="*", help="pytest arguments (default: the default suite)")

    args = parse_args(__doc__, extra=extra)
    tests = args.tests or (QUICK_TESTS if args.quick else [])
    runs, variants = [], None
    with tempfile.TemporaryDirectory(prefix="suite_compile_") as tmp:
        cache = Path(tmp) / "cache"
        for k in range(args.runs):
            log(f"run {k + 1} of {args.runs} ({'cold' if k == 0 else 'warm'} cache)")
            runs.append(_run(tests, cache, Path(tmp) / f"run{k}", args.workers))
            log(runs[-1]["result"], f"{runs[-1]['wall_s']:.0f} s")
            if k == 0:
                variants = _variants(cache)
    page = Page(
        "suite_compile" + ("_quick" if args.quick else ""),
        "Where the test run's time goes: compiling against running",
        args,
        {
            "command run": f"pytest -q -n {args.workers} {' '.join(tests) or '(default suite)'}",
            "cache": "run 1: an empty offline-cache folder; later runs: the folder run 1 filled",
            "compile": "Taichi's front end per kernel instance + each instance's first launch (load or "
            "compile to machine code, and that launch's run); subprocesses the tests start are not counted",
        },
    )
    page.table(
        "Runs",
        [
            "run",
            "cache",
            "result",
            "wall s",
            "tests' s (both workers)",
            "compiling s",
            "share",
            "front end s",
            "first launches s",
        ],  # fmt: skip
        [
            [
                k + 1,
                "cold" if k == 0 else "warm",
                r["result"],
                f"{r['wall_s']:.0f}",
                f"{r['tests_s']:.0f}",
                f"{r['compile_s']:.0f}",
                f"{r['compile_s'] / max(r['tests_s'], 1e-9):.0%}",
                f"{r['front_s']:.0f}",
                f"{r['load_s']:.0f}",
            ]  # fmt: skip
            for k, r in enumerate(runs)
        ],
    )
    last = runs[-1]["kernels"]
    top = sorted(last.items(), key=lambda kv: -(kv[1][0] + kv[1][1]))[:TOP]
    page.table(
        f"Kernels that compile longest, run {len(runs)}",
        ["kernel", "instances", "front end s", "first launches s", "s per instance"],
        [[f"`{k}`", n, f"{fe:.1f}", f"{ld:.1f}", f"{(fe + ld) / n:.3f}"] for k, (fe, ld, n) in top],
    )
    files, size, names = variants
    page.table(
        "Kernels compiled in the cold run, by name",
        ["kernel", "variants (cache files)"],
        [[f"`{k}`", n] for k, n in names.most_common(TOP)],
        note=f"{files} kernels, {size / 2**20:.0f} MiB of cached IR in all.",
    )
    page.write({"runs": runs, "variants": {"files": files, "bytes": size, "names": dict(names)}})


if __name__ == "__main__":
    main()
