"""Run manifest: `run.json` with the settings, timings and software/hardware environment of a run."""

from __future__ import annotations

import dataclasses
import datetime as _dt
import enum
import json
import math
import os
import platform
import sys
from importlib import metadata
from pathlib import Path, PurePath

import numpy as np

from .export import atomic_path

MANIFEST_NAME = "run.json"
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
    if "taichi" not in sys.modules:  # not even imported, so certainly not initialised; skip the import cost
        return {"initialized": False, "arch": None}
    try:
        from .. import runtime

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
    out_dir: str | os.PathLike, settings: dict, timings: dict, *, name: str = MANIFEST_NAME
) -> Path:
    """Write `<out_dir>/run.json` atomically and return its path.

    settings: what the run was asked to do (scene, resolution, dt [s], solver options, ...);
    timings: what it measured (seconds, steps per second, compile time [s], ...). Values may be NumPy
    scalars or arrays, tuples, Enums, dataclasses or paths; see `jsonable`. The file also records
    `environment()` and a `schema` version.
    """
    doc = {
        "schema": 1,
        "settings": jsonable(settings),
        "timings": jsonable(timings),
        "environment": environment(),
    }
    text = json.dumps(doc, indent=2, allow_nan=False, sort_keys=False) + "\n"
    path = Path(out_dir) / name
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def read_manifest(path: str | os.PathLike) -> dict:
    """Read a manifest written by write_manifest (a folder is taken to hold `run.json`)."""
    path = Path(path)
    if path.is_dir():
        path = path / MANIFEST_NAME
    return json.loads(path.read_text(encoding="utf-8"))
