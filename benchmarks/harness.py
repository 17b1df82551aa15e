"""The benchmark harness: a case runs scenes (from the catalogue, or a small builder for a peer's scene),
times them and writes one results page.

- `Run`: one implementation of a scene (ours or a peer's) as `make() -> frame callable`; `time_run` builds
  it, times the first frame apart (it holds the JIT compile), warms up, then times frames one by one with
  a sync before every clock read and reports the median. Peers run in the same process, on the same scene.
- `compile_times`: the engine's compile in fresh `ta.init`s, offline cache cold (empty folder) and warm.
- `peer(module)`: a peer's adapter from benchmarks/peers/, or None with a message when its package is
  missing (the case goes on without it).
- `Page`: tables, settings and the machine record (CPU, cores, load average at start and end, package
  versions, the commit and whether the tree was clean) written as `results/<name>.md` + `.json`;
  `--quick` writes to benchmarks/out/ (git-ignored) so a smoke run never overwrites recorded results.

Not a test module: pytest never collects benchmarks/.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import taichi as ti

import taichi_anim as ta
from taichi_anim.io.manifest import environment, jsonable

BENCH_DIR = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH_DIR))  # so cases import `peers.*`
RESULTS_DIR = BENCH_DIR / "results"
QUICK_DIR = BENCH_DIR / "out"


def parse_args(
    doc: str, argv: Sequence[str] | None = None, extra: Callable | None = None
) -> argparse.Namespace:
    """`--quick` (small sizes, into benchmarks/out/) and `--out DIR`; `extra(parser)` adds a case's own."""
    p = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smoke run: small sizes, into benchmarks/out/")
    p.add_argument("--out", type=Path, default=None, help="folder for the page (default results/ or out/)")
    if extra:
        extra(p)
    args = p.parse_args(argv)
    args.dir = args.out or (QUICK_DIR if args.quick else RESULTS_DIR)
    args.started = time.perf_counter()
    args.load_start = load_average()
    return args


def init(precision: str = "f32", arch: str = "cpu", **options) -> str:
    """A fresh Taichi for one measurement (quiet: benchmarks print their own progress)."""
    options.setdefault("log_level", ti.ERROR)
    return ta.init(arch, precision=precision, **options)


def clock() -> float:
    """Seconds, after every launched kernel finished."""
    ti.sync()
    return time.perf_counter()


def host_clock() -> float:
    """Seconds, for peers whose frame ends in a host copy or their own sync (no Taichi call)."""
    return time.perf_counter()


def log(*parts: object) -> None:
    print(*parts, file=sys.stderr, flush=True)


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system


# ---------------------------------------------------------------------------------------------------------
# timing


@dataclass
class Run:
    """One implementation of a scene: make() builds it and returns a callable that advances one frame
    (and returns what the case compares, e.g. positions); sync waits for its device."""

    name: str
    make: Callable[[], Callable[[], object]]
    sync: Callable[[], float] = clock
    result: object = field(default=None, repr=False)


def time_run(run: Run, *, frames: int, warmup: int = 2, budget_s: float = 60.0, min_frames: int = 5) -> dict:
    """Build, first frame (compile included), warmup - 1 more, then up to `frames` frames timed one by one
    (cut after budget_s seconds, but at least min_frames). Times in seconds; cores = CPU time / wall."""
    t0 = time.perf_counter()
    frame = run.make()
    build = time.perf_counter() - t0
    a = run.sync()
    out = frame()
    first = run.sync() - a
    for _ in range(warmup - 1):
        out = frame()
    times: list[float] = []
    c0, w0 = cpu_seconds(), run.sync()
    while len(times) < frames and (sum(times) < budget_s or len(times) < min_frames):
        a = run.sync()
        out = frame()
        times.append(run.sync() - a)
    cores = (cpu_seconds() - c0) / max(run.sync() - w0, 1e-12)
    run.result = out
    r = {
        "name": run.name,
        "build": build,
        "first": first,
        "median": statistics.median(times),
        "min": min(times),
        "frames": len(times),
        "cut": len(times) < frames,
        "cores": cores,
    }
    log(
        f"  {run.name:14s} median {fmt_s(r['median'])}, first {fmt_s(first)}, {r['frames']} frames, "
        f"{cores:.2f} cores"
    )
    return r


def median_time(fn: Callable[[], object], *, repeats: int = 5, warmup: int = 1, sync=clock) -> float:
    """Median seconds of fn() over `repeats` calls after `warmup` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        a = sync()
        fn()
        times.append(sync() - a)
    return statistics.median(times)


def compile_times(
    first_and_steady: Callable[[], tuple[float, float]], *, precision: str = "f32", arch: str = "cpu"
) -> dict:
    """Compile = first run - steady run of a scene, in a fresh ta.init with the offline cache on an empty
    folder (cold) and again on that folder (warm), so nothing depends on what ~/.cache/taichi holds."""
    folder = tempfile.mkdtemp(prefix="taichi_anim_bench_cache_")
    out = {}
    try:
        for mode in ("cold", "warm"):
            init(precision, arch, offline_cache=True, offline_cache_file_path=folder)
            first, steady = first_and_steady()
            out[mode] = {"first": first, "steady": steady, "compile": max(first - steady, 0.0)}
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out


def peer(module: str, extra: str = "bench"):
    """benchmarks/peers/<module>, or None (said on stderr) when its package is not installed."""
    try:
        return importlib.import_module(f"peers.{module}")
    except ImportError as e:
        log(f"peer {module} skipped: {e} (install it with `.venv/bin/pip install -e .[{extra}]`)")
        return None


# ---------------------------------------------------------------------------------------------------------
# machine record


def load_average() -> str:
    try:
        return ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "?"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "?"


def git_commit() -> str:
    """HEAD's short sha, with "+ local changes" when the tree differs from it."""
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=BENCH_DIR
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "taichi_anim"],
            capture_output=True,
            text=True,
            cwd=BENCH_DIR.parent,
        )
    except OSError:
        return "?"
    return sha.stdout.strip() + (" + local changes" if dirty.stdout.strip() else "")


def versions(*packages: str) -> dict[str, str]:
    from importlib import metadata

    out = {}
    for p in packages:
        try:
            out[p] = metadata.version(p)
        except metadata.PackageNotFoundError:
            out[p] = "not installed"
    return out


def machine(args) -> dict:
    env = environment()
    return {
        "CPU": f"{cpu_model()}, {os.cpu_count()} logical CPUs ({env['cpu_count_usable']} usable)",
        "OS / Python": f"{env['platform']} / {env['python']}",
        "packages": ", ".join(f"{k} {v}" for k, v in env["packages"].items() if v),
        "commit": git_commit(),
        "load average (1/5/15 min) at start / end": f"{args.load_start} / {load_average()}",
        "date (UTC)": env["date"],
    }


# ---------------------------------------------------------------------------------------------------------
# output


def fmt_s(seconds: float | None) -> str:
    if seconds is None or seconds != seconds:
        return "–"
    if seconds >= 1.0:
        return f"{seconds:.2f} s"
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds * 1e6:.3g} µs"


def ratio(a: float | None, b: float | None) -> str:
    """a / b as "2.1x", or a dash when either is missing."""
    return f"{a / b:.2f}x" if a and b else "–"


def md_table(headers: Sequence[object], rows: Sequence[Sequence[object]]) -> str:
    lines = ["| " + " | ".join(map(str, headers)) + " |", "|" + "---|" * len(headers)]
    return "\n".join(lines + ["| " + " | ".join(map(str, r)) + " |" for r in rows])


class Page:
    """A results page: title, settings, tables; `write(data)` adds the machine record and the command
    and writes `<dir>/<name>.md` and `<name>.json` (the raw figures)."""

    def __init__(self, name: str, title: str, args: argparse.Namespace, settings: dict | None = None):
        self.name, self.title, self.args = name, title, args
        self.settings = dict(settings or {})
        self.parts: list[str] = []

    def table(self, heading: str, headers, rows, note: str = "") -> None:
        self.parts.append(f"## {heading}\n\n{md_table(headers, rows)}" + (f"\n\n{note}" if note else ""))

    def text(self, text: str) -> None:
        self.parts.append(text)

    def write(self, data: object = None) -> Path:
        a = self.args
        cmd = " ".join([".venv/bin/python", f"benchmarks/{Path(sys.argv[0]).name}", *sys.argv[1:]])
        minutes = (time.perf_counter() - a.started) / 60
        settings = md_table(["setting", "value"], [[k, v] for k, v in self.settings.items()])
        mach = machine(a)
        head = (
            f"# {self.title}\n\n`{cmd}` ({minutes:.1f} min). Timings are medians; read ratios within a run."
        )
        text = "\n\n".join(
            [
                head,
                *self.parts,
                "## Settings\n\n" + settings,
                "## Machine\n\n" + md_table(["", ""], mach.items()),
            ]
        )
        a.dir.mkdir(parents=True, exist_ok=True)
        md = a.dir / f"{self.name}.md"
        md.write_text(text + "\n")
        raw = {"settings": self.settings, "machine": mach, "data": data}
        (a.dir / f"{self.name}.json").write_text(json.dumps(jsonable(raw), indent=1) + "\n")
        log(f"wrote {md}")
        return md

    def plot(
        self, series: dict[str, tuple[Sequence[float], Sequence[float]]], *, xlabel: str, ylabel: str
    ) -> None:
        """A log-log line plot `<dir>/<name>.png` of {label: (xs, ys)}; skipped without matplotlib."""
        try:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            log("matplotlib missing: no plot")
            return
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        for label, (xs, ys) in series.items():
            ax.loglog(xs, ys, "o-", label=label)
        ax.set(xlabel=xlabel, ylabel=ylabel, title=self.title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        self.args.dir.mkdir(parents=True, exist_ok=True)
        fig.savefig(self.args.dir / f"{self.name}.png", dpi=110, bbox_inches="tight")
        plt.close(fig)
