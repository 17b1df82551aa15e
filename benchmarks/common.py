"""Helpers shared by the benchmarks: machine description, synchronised clock, JIT compile time under the
three offline-cache conditions, memory bandwidth, markdown tables, and writing one section of
benchmarks/RESULTS.md without touching the sections other benchmarks wrote.

Not a test module (no `test_` prefix): pytest does not collect it.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import taichi as ti

import taichi_anim as ta

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_MD = BENCH_DIR / "RESULTS.md"
RESULTS_DIR = BENCH_DIR / "results"
QUICK_DIR = BENCH_DIR / "out"  # git-ignored: smoke runs never overwrite the committed results

RESULTS_HEADER = """# Benchmark results

Written by the scripts in `benchmarks/` (see `benchmarks/README.md`); each section is replaced in place
when its script runs again. Timings come from a shared 2-core virtual machine: read them as orders of
magnitude and compare ratios measured in the same run, not absolute figures across runs.
"""


# ---------------------------------------------------------------------------------------------------------
# command line and output locations


def parse_args(description: str, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """`--quick` (small smoke run, written to benchmarks/out/) and `--out DIR`."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--quick", action="store_true", help="small sizes and few runs (smoke test, ~1 min)")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder for RESULTS.md and plots (default: benchmarks/ and benchmarks/results/ for a full "
        "run, benchmarks/out/ for --quick)",
    )
    return p.parse_args(argv)


def output_paths(args: argparse.Namespace) -> tuple[Path, Path]:
    """(markdown file, folder for plots and raw data) for this run."""
    if args.out is not None:
        return args.out / "RESULTS.md", args.out
    if args.quick:
        return QUICK_DIR / "RESULTS.md", QUICK_DIR
    return RESULTS_MD, RESULTS_DIR


def command_line(args: argparse.Namespace, script: str) -> str:
    """The command that regenerates this run."""
    return f".venv/bin/python benchmarks/{script}" + (" --quick" if args.quick else "")


# ---------------------------------------------------------------------------------------------------------
# machine


def _cpuinfo() -> dict[str, str]:
    info: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if ":" in line:
                k, v = (s.strip() for s in line.split(":", 1))
                info.setdefault(k, v)
    except OSError:
        pass
    return info


def _lscpu_caches() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return "?"
    caches = [
        f"{m.group(1)} {m.group(2).strip()}" for m in re.finditer(r"^(L\d\w? cache):\s+(.*)$", out, re.M)
    ]
    return "; ".join(caches) or "?"


def _mem_total_gib() -> float:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return float("nan")


def load_average() -> str:
    """`uptime`'s load averages (1, 5, 15 min) as text."""
    try:
        a = os.getloadavg()
        return f"{a[0]:.2f}, {a[1]:.2f}, {a[2]:.2f}"
    except OSError:
        return "?"


def engine_fingerprint() -> str:
    """sha256 (12 hex digits) of every taichi_anim source file and the newest modification time: the
    engine changes under parallel edits, so results name the exact sources they measured."""
    import hashlib

    root = Path(ta.__file__).resolve().parent
    h = hashlib.sha256()
    newest = 0.0
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode())
        h.update(f.read_bytes())
        newest = max(newest, f.stat().st_mtime)
    return f"{h.hexdigest()[:12]} (newest file {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(newest))})"


def engine_row(at_start: str) -> list[str]:
    """Table row naming the engine sources; says so if they changed while the benchmark ran."""
    at_end = engine_fingerprint()
    if at_end == at_start:
        return ["taichi_anim sources (sha256)", f"{at_start}, unchanged during the run"]
    return [
        "taichi_anim sources (sha256)",
        f"**changed during the run**: {at_start} at start, {at_end} at end",
    ]


def _busy_seconds() -> float:
    """CPU seconds all processes have spent busy (user + nice + system + irq + softirq + steal)."""
    fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    ticks = [int(x) for x in fields]
    busy = ticks[0] + ticks[1] + ticks[2] + ticks[5] + ticks[6] + (ticks[7] if len(ticks) > 7 else 0)
    return busy / os.sysconf("SC_CLK_TCK")


class OtherLoad:
    """CPU used by other processes while the benchmark runs: machine-wide busy CPU time minus this
    process's own, divided by the wall time, in cores (0 = nothing else ran; 1 = a whole core taken)."""

    def __init__(self) -> None:
        self.wall0 = time.perf_counter()
        self.own0 = sum(os.times()[:4])
        try:
            self.busy0 = _busy_seconds()
        except (OSError, ValueError, IndexError):
            self.busy0 = float("nan")

    def cores(self) -> float:
        try:
            busy = _busy_seconds() - self.busy0
        except (OSError, ValueError, IndexError):
            return float("nan")
        own = sum(os.times()[:4]) - self.own0
        return max(busy - own, 0.0) / (time.perf_counter() - self.wall0)


def machine_info() -> dict[str, str]:
    """CPU model, cores, memory, library versions: what a reader needs to compare figures."""
    cpu = _cpuinfo()
    return {
        "CPU": cpu.get("model name", platform.processor() or "?"),
        "logical CPUs": str(os.cpu_count()),
        "cores per socket (cpuinfo)": cpu.get("cpu cores", "?"),
        "caches (lscpu)": _lscpu_caches(),
        "memory": f"{_mem_total_gib():.1f} GiB",
        "OS": f"{platform.system()} {platform.release()}",
        "Python": platform.python_version(),
        "taichi": ti.__version__ if isinstance(ti.__version__, str) else ".".join(map(str, ti.__version__)),
        "taichi_anim": ta.__version__,
        "numpy": np.__version__,
        "Taichi arch / threads": f"cpu (x64), default thread count = {os.cpu_count()}",
        "NumPy threads": "1 (element-wise ufuncs are single-threaded)",
    }


def machine_table(
    info: dict[str, str], *, load_start: str, load_end: str, date: str, engine: str, other: OtherLoad
) -> str:
    rows = [[k, v] for k, v in info.items()]
    rows.append(engine_row(engine))
    rows.append(["CPU used by other processes during the run (mean, in cores)", f"{other.cores():.2f}"])
    rows.append(["load average at start (1/5/15 min)", load_start])
    rows.append(["load average at end (1/5/15 min)", load_end])
    rows.append(["date", date])
    return md_table(["machine", "value"], rows)


# ---------------------------------------------------------------------------------------------------------
# Taichi and timing


def run_started() -> dict:
    """What a run's machine table needs from its start: load, date (UTC), engine sources, other load."""
    return {
        "load": load_average(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "engine": engine_fingerprint(),
        "other": OtherLoad(),
    }


def machine_section(started: dict) -> str:
    """machine_table for a run begun with run_started(), closed now."""
    return machine_table(
        machine_info(),
        load_start=started["load"],
        load_end=load_average(),
        date=started["date"],
        engine=started["engine"],
        other=started["other"],
    )


def publish(md_path: Path, out_dir: Path, name: str, text: str, data, elapsed: float) -> None:
    """Write a run's page `out_dir/<name>.md`, its raw data `<name>.json`, and its section of md_path."""
    import json

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{name}.md").write_text(text + "\n")
    (out_dir / f"{name}.json").write_text(json.dumps(data, indent=1))
    write_section(md_path, name, text)
    log(f"wrote {out_dir / (name + '.md')} and its section of {md_path} in {elapsed / 60:.1f} min")


def init(precision: str, **options) -> str:
    """Reset Taichi on the CPU with the given float precision; warnings about f64 -> f32 copies in
    `Model.state()` are silenced (they would swamp the output)."""
    options.setdefault("log_level", ti.ERROR)
    return ta.init("cpu", precision=precision, **options)


def clock() -> float:
    """Seconds, after waiting for every launched kernel to finish."""
    ti.sync()
    return time.perf_counter()


def memory_bandwidth(nbytes: int = 2**29, repeats: int = 5) -> dict[str, float]:
    """Streaming bandwidth of a NumPy copy of `nbytes` (default 512 MiB, beyond the caches), counted as
    bytes read + bytes written (the STREAM "copy" convention). Returns best and median GB/s."""
    src = np.ones(nbytes // 4, dtype=np.float32)
    dst = np.empty_like(src)
    np.copyto(dst, src)  # first touch faults the pages in; not timed
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(dst, src)
        rates.append(2 * src.nbytes / (time.perf_counter() - t0) / 1e9)
    del src, dst
    return {"best": max(rates), "median": float(np.median(rates)), "bytes": float(nbytes)}


CACHE_MODES = ("offline cache off", "offline cache on, cold", "offline cache on, warm")


def compile_times(
    first_and_steady: Callable[[], tuple[float, float]],
    *,
    precision: str,
    modes: Sequence[str] = CACHE_MODES,
) -> dict[str, dict[str, float]]:
    """JIT compile time of one scene under each offline-cache condition, each in a freshly reset Taichi.

    `first_and_steady()` builds the scene and returns (seconds of a first run, seconds of the same or
    an equivalent run once compiled); compile = first - steady. "cold" uses a new, empty cache folder,
    "warm" re-initialises Taichi on that same folder, so the result does not depend on what
    ~/.cache/taichi holds.
    """
    out: dict[str, dict[str, float]] = {}
    folder = tempfile.mkdtemp(prefix="taichi_anim_bench_cache_")
    try:
        for mode in modes:
            if mode == "offline cache off":
                init(precision, offline_cache=False)
            elif mode in ("offline cache on, cold", "offline cache on, warm"):
                init(precision, offline_cache=True, offline_cache_file_path=folder)
            else:
                raise ValueError(f"unknown cache mode {mode!r}")
            first, steady = first_and_steady()
            out[mode] = {"first": first, "steady": steady, "compile": max(first - steady, 0.0)}
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out


def compile_rows(name: str, result: dict[str, dict[str, float]]) -> list[list[str]]:
    """Table rows (name, cache mode, first call, steady call, compile) for `compile_times` output."""
    return [
        [name, mode, fmt_s(r["first"]), fmt_s(r["steady"]), fmt_s(r["compile"])] for mode, r in result.items()
    ]


COMPILE_HEADERS = [
    "scene",
    "offline cache",
    "first run (compile included)",
    "run again",
    "compile = difference",
]


# ---------------------------------------------------------------------------------------------------------
# formatting and writing


def fmt_s(seconds: float) -> str:
    """A duration with a readable unit."""
    if seconds != seconds:
        return "nan"
    if seconds >= 1.0:
        return f"{seconds:.2f} s"
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds * 1e6:.3g} µs"


def fmt_e(x: float, digits: int = 2) -> str:
    """Scientific notation, e.g. 1.2e+07."""
    if x != x:
        return "nan"
    return f"{x:.{digits - 1}e}"


def fmt_dt(dt: float) -> str:
    """A step as 1/N s where it is one."""
    inv = 1.0 / dt
    return f"1/{round(inv)}" if abs(inv - round(inv)) < 1e-9 * inv else f"{dt:.3g}"


def md_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(str(h) for h in headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def write_section(path: Path, name: str, text: str) -> None:
    """Replace the section `name` of the results file (between BEGIN/END markers), or append it."""
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    block = f"{begin}\n{text.rstrip()}\n{end}\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.read_text() if path.exists() else RESULTS_HEADER
    if begin in old and end in old:
        head, rest = old.split(begin, 1)
        _, tail = rest.split(end, 1)
        new = head + block + tail.lstrip("\n")
    else:
        new = old.rstrip() + "\n\n" + block
    path.write_text(new)


def log(*parts: object) -> None:
    """Progress to stderr, flushed (the benchmarks run for minutes)."""
    print(*parts, file=sys.stderr, flush=True)
