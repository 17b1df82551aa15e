"""Run manifest and run folder: `run.json` with the status, settings, timings, health, files and
software/hardware environment of a run, and the rule that keeps an output folder consistent.

Folder policy: a run owns its output folder, and re-running into the same folder replaces the previous
run's output, as a simulation cache does in Blender or Houdini. When a run starts (prepare_run_folder) it
removes what the previous run wrote there: every file its run.json lists, plus the files named after the
previous and the current scene (`NAME_0042.ply`, `NAME_trails_0042.ply`, `NAME_last.png`, `NAME.usd`,
`NAME.mp4`, ...: a run killed before its final run.json listed nothing) and the hidden temporaries
killed runs leave. Other files (a user's notes, other scenes' caches) are never touched. A fresh folder
per run would keep old runs, but then every consumer (a Blender import, a viewer) must be pointed at a
new folder each time; keeping old runs is a matter of choosing another `--out`.

One run per folder: a run holds an advisory lock on the folder (io/lock.py, `.taichi-anim.lock`) from
before it removes anything until run.json is final; a second run into a busy folder stops with
FolderBusyError (an OutputError naming the folder and the other run's process id) and touches nothing.
The lock of a killed run is released by the kernel, so the next run takes the folder over.

run.json is written (atomically) when the run starts, with status "running", and rewritten at the end
with "complete", "diverged" (DivergenceError: the step, particle, quantity and value under "error"),
"interrupted" (a signal, SIGINT, SIGTERM or SIGHUP, stopped the run between frames: the signal's name
and number under "error"; the frames before it were saved) or "failed" (any other exception, also an
output error), and lists every file the run wrote with its size [bytes] and SHA-256. A status still
"running" means the run was killed (SIGKILL, a crash, a power cut).

The previous run.json is read only if it is a regular file (or a link to one) of at most
MANIFEST_MAX_BYTES: a FIFO would block the reader for ever and a link to /dev/zero would be read without
end. Anything else under that name was not written by a run, so the run refuses to start (OutputError
naming it) rather than delete it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import enum
import json
import math
import os
import platform
import re
import stat
import sys
from collections.abc import Iterable, Iterator
from importlib import metadata
from pathlib import Path, PurePath

import numpy as np

from .. import runtime
from ..errors import OutputError
from .atomic import atomic_path, file_record, output_error, remove_file, remove_stale_temporaries
from .lock import LOCK_NAME, check_not_busy, hold_lock

MANIFEST_NAME = "run.json"
SCHEMA = 2
STATUSES = ("running", "complete", "diverged", "interrupted", "failed")
MANIFEST_MAX_BYTES = 64 << 20  # a run.json lists a few hundred bytes per file: millions of files fit
FRAME_EXTENSIONS = ("ply", "obj", "pcd", "xyz")
# Distribution names per reported package; open3d-cpu is the same `import open3d` (see pyproject.toml).
_DISTRIBUTIONS = {
    "taichi": ("taichi",),
    "numpy": ("numpy",),
    "open3d": ("open3d-cpu", "open3d"),
    "taichi_anim": ("taichi_anim", "taichi-anim"),
}


def jsonable(obj):
    """Convert `obj` recursively into plain JSON types.

    NumPy scalars and arrays become numbers and lists, tuples and sets lists, Enums their name,
    dataclasses dicts, paths strings, dates ISO strings. Non-finite floats become the strings "NaN",
    "Infinity", "-Infinity", so the file stays strict JSON (json.dumps would write bare NaN, which most
    non-Python readers reject). Anything else is written as its repr().
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, enum.Enum):  # before int: an IntEnum is an int too
        return obj.name
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        if math.isfinite(x):
            return x
        return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, dict):
        return {_key(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return sorted((jsonable(v) for v in obj), key=repr)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        # Not dataclasses.asdict on the whole tree: it deep-copies fields, which fails on Taichi fields.
        return {f.name: jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, (_dt.datetime, _dt.date, _dt.time)):
        return obj.isoformat()
    if isinstance(obj, complex):
        return [obj.real, obj.imag]
    return repr(obj)


def _key(k) -> str:
    if isinstance(k, enum.Enum):
        return k.name
    return k if isinstance(k, str) else str(jsonable(k))


def _version(names: tuple[str, ...]) -> str | None:
    for name in names:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return None


def environment() -> dict:
    """What the figures of a run depend on: Python, OS, CPU, package versions, Taichi backend, date (UTC)."""
    try:
        usable_cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on macOS / Windows
        usable_cpus = os.cpu_count()
    env = {
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "python_implementation": platform.python_implementation(),
        "executable": sys.executable,
        "platform": platform.platform(),
        "system": platform.system(),
        "machine": platform.machine(),
        "processor": platform.processor() or None,
        "cpu_count": os.cpu_count(),
        "cpu_count_usable": usable_cpus,
        "packages": {pkg: _version(dists) for pkg, dists in _DISTRIBUTIONS.items()},
        "open3d_distribution": next((d for d in _DISTRIBUTIONS["open3d"] if _version((d,))), None),
        "taichi": _taichi_state(),
    }
    return env


def _taichi_state() -> dict:
    # Only read the state: initialising Taichi here would change what the caller measured.
    try:
        if not runtime.is_initialized():
            return {"initialized": False, "arch": None}
        from taichi.lang import impl

        cfg = impl.current_cfg()
        return {
            "initialized": True,
            "arch": runtime.backend_name(),
            "default_fp": str(runtime.float_dtype()),
            "cpu_max_num_threads": getattr(cfg, "cpu_max_num_threads", None),
            "debug": getattr(cfg, "debug", None),
        }
    except Exception as e:  # a manifest must not make a finished run fail
        return {"initialized": None, "arch": None, "error": repr(e)}


def write_manifest(
    out_dir: str | os.PathLike,
    settings: dict,
    timings: dict,
    *,
    status: str = "complete",
    files: Iterable = (),
    health: dict | None = None,
    error: dict | None = None,
    name: str = MANIFEST_NAME,
) -> Path:
    """Write `<out_dir>/run.json` atomically and return its path.

    settings: what the run was asked to do (scene, resolution, dt [s], solver options, ...);
    timings: what it measured (seconds, steps per second, compile time [s], ...). Values may be NumPy
    scalars or arrays, tuples, Enums, dataclasses or paths; see `jsonable`. status: one of STATUSES;
    files: what the run wrote, as file_record dicts or paths (recorded now); health: the run's
    Health.to_dict(); error: what stopped the run (see error_record). The file also records
    `environment()` and a `schema` version.
    """
    if status not in STATUSES:
        raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
    out = Path(out_dir)
    doc = {
        "schema": SCHEMA,
        "status": status,
        "settings": jsonable(settings),
        "timings": jsonable(timings),
        "health": jsonable(health),
        "error": jsonable(error),
        "files": _unique_files(f if isinstance(f, dict) else file_record(f, out) for f in files),
        "environment": environment(),
    }
    text = json.dumps(doc, indent=2, allow_nan=False, sort_keys=False) + "\n"
    path = out / name
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def _unique_files(records) -> list[dict]:
    # A file written twice by one run is listed once, as it is now.
    last = {r["path"]: r for r in records}
    return list(last.values())


def read_manifest(path: str | os.PathLike) -> dict:
    """Read a manifest written by write_manifest (a folder is taken to hold `run.json`).

    Raises OSError if it cannot be opened, ValueError if it is not a regular file (a FIFO, a device), is
    larger than MANIFEST_MAX_BYTES or is not JSON; never blocks on a FIFO."""
    path = Path(path)
    if path.is_dir():
        path = path / MANIFEST_NAME
    # O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer for ever.
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb") as f:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ValueError(f"{path} is {_file_kind(info.st_mode)}, not a regular file")
        data = f.read(MANIFEST_MAX_BYTES + 1)
    if len(data) > MANIFEST_MAX_BYTES:
        raise ValueError(f"{path} is larger than {MANIFEST_MAX_BYTES >> 20} MiB: not a run manifest")
    return json.loads(data.decode("utf-8"))


def _file_kind(mode: int) -> str:
    kinds = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))
    kinds += ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))
    return next((what for test, what in kinds if test(mode)), "a special file")


def error_record(error: BaseException) -> dict:
    """What stopped a run: {"type", "message"}, plus "step", "particle", "quantity", "value" for a
    DivergenceError (None where not known), and "signal" (its name), "signal_number" and "forced" for
    RunInterrupted."""
    doc = {"type": type(error).__name__, "message": str(error)}
    for key in ("step", "particle", "quantity", "value", "signal", "signal_number", "forced"):
        if hasattr(error, key):
            doc[key] = getattr(error, key)
    return doc


# ------------------------------------------------------------------------------------------ run folder


def frame_file_pattern(name: str) -> re.Pattern:
    """The names a scene `name` writes: `name_NNNN.ext` and `name_word_NNNN.ext` (4 or more digits,
    ext in FRAME_EXTENSIONS), the picture `name_last.png`, the USD stage `name.usd` and the video
    `name.mp4` or `name.gif` (the default video path)."""
    stem = re.escape(name)
    ext = "|".join(FRAME_EXTENSIONS)
    return re.compile(rf"{stem}(?:_[a-z]+)?_\d{{4,}}\.(?:{ext})|{stem}_last\.png|{stem}\.(?:usd|mp4|gif)")


def check_output_folder(out_dir: str | os.PathLike, *, what: str = "the output folder") -> Path:
    """Raise OutputError unless `out_dir` is a writable folder or can be created as one (nothing is
    created here, so a run that fails later for another reason leaves no empty folder behind); the
    message calls `out_dir` `what`."""
    out = Path(out_dir)
    probe = out
    while not probe.exists() and probe != probe.parent:
        if probe.is_symlink():  # a dangling link: mkdir would fail on it
            raise OutputError(f"cannot write to {out}: {probe} is a broken symbolic link")
        probe = probe.parent
    if not probe.is_dir():
        where = what if probe == out else f"{probe}, on the way to it,"
        raise OutputError(f"cannot write to {out}: {where} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write to {out}: permission denied ({probe} is read-only)")
    return out


def check_run_folder(out_dir: str | os.PathLike) -> Path:
    """check_output_folder, and also: a run.json there is a regular file (or a link to one), and no other
    run holds the folder (FolderBusyError). Creates nothing: the command line calls it before the scene
    compiles, so a run that cannot start says so at once."""
    out = check_output_folder(out_dir)
    _check_previous_manifest(out)
    check_not_busy(out / LOCK_NAME, what=f"the output folder {out}")
    return out


@contextlib.contextmanager
def locked_run_folder(out_dir: str | os.PathLike) -> Iterator[Path]:
    """Create `out_dir` if missing and hold its run lock (io/lock.py) for the block; FolderBusyError if
    another run holds it. Nothing in the folder is touched before the lock is held."""
    out = check_output_folder(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise output_error(out, e) from e
    with hold_lock(out / LOCK_NAME, what=f"the output folder {out}"):
        yield out


def _check_previous_manifest(out: Path) -> None:
    path = out / MANIFEST_NAME
    try:
        info = os.stat(path)  # follows a link; stat never opens, so a FIFO cannot block it
    except FileNotFoundError:  # none, or a dangling link: the new run.json replaces it
        return
    except OSError as e:
        raise OutputError(f"cannot use {out} as the output folder: {path}: {e.strerror}") from e
    if not stat.S_ISREG(info.st_mode):
        raise OutputError(
            f"cannot use {out} as the output folder: {path} is {_file_kind(info.st_mode)}, not a run "
            "manifest; remove or rename it, or choose another output folder"
        )


def prepare_run_folder(out_dir: str | os.PathLike, *, names: Iterable[str] = ()) -> list[Path]:
    """Make `out_dir` ready for a new run of the scenes `names` (created if missing) and return the
    files removed: stale temporaries, every file the previous run.json lists, and the frame files of
    the previous run's scene and of `names` (frame_file_pattern). See the module docstring for why.

    Call it inside locked_run_folder: the files of a run that is still going on must not be removed.
    A run.json that is not a regular file (a FIFO, a device, a folder) is an OutputError naming it,
    raised before anything is removed."""
    out = check_output_folder(out_dir)
    _check_previous_manifest(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise output_error(out, e) from e
    removed = remove_stale_temporaries(out)
    listed, names = set(), set(names)
    try:
        previous = read_manifest(out / MANIFEST_NAME)
    except (OSError, ValueError):  # none, or unreadable: the name patterns still apply
        previous = {}
    if isinstance(previous, dict):
        for entry in previous.get("files") or ():
            rel = entry.get("path") if isinstance(entry, dict) else None
            # Only plain names inside this folder: a tampered run.json must not reach elsewhere.
            if isinstance(rel, str) and rel and Path(rel).name == rel and rel not in (".", ".."):
                listed.add(rel)
        settings = previous.get("settings")
        scene = settings.get("scene") if isinstance(settings, dict) else None
        if isinstance(scene, str) and scene:
            names.add(scene)
    patterns = [frame_file_pattern(n) for n in sorted(names)]
    for entry in sorted(out.iterdir()):
        # Never the run's own lock (nor a video's), even if a tampered run.json lists it.
        ours = entry.name == MANIFEST_NAME or entry.name.endswith(LOCK_NAME)
        if ours or not (entry.is_file() or entry.is_symlink()):
            continue
        if (entry.name in listed or any(p.fullmatch(entry.name) for p in patterns)) and remove_file(entry):
            removed.append(entry)
    return removed
