"""What a sweep may vary, and the runs it expands to: the accepted parameter names of a scene, the product
or zipped rows of the value lists, a readable folder name per run, and command-line values parsed to
numbers, booleans and strings."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import itertools
import json
import re
import sys
from collections.abc import Callable, Mapping
from pathlib import Path

from .. import scenes
from ..errors import ParameterError

# Options of a demo run that are not the scene's build options: how run_scene runs and exports it
# (frames, export, export_format, video, color_by) and how Taichi starts (arch, precision).
RUN_OPTIONS = ("frames", "export", "export_format", "video", "color_by", "arch", "precision", "size_buckets")
MODES = ("product", "list")
ID_MAX_CHARS = 120  # file names stay well under every file system's 255-byte limit
_UNSAFE = re.compile(r"[^A-Za-z0-9_.,+-]+")


def scene_spec(scene) -> str:
    """The scene as a worker process can find it again: a catalogue name (taichi_anim.scenes.SCENES),
    "module:function", or "path/to/file.py:function" for a function of a script run as __main__.
    ParameterError for a function another process cannot import (a lambda, a nested function)."""
    if isinstance(scene, str):
        path, colon, name = scene.rpartition(":")
        if colon and path.endswith(".py"):  # the same file for workers started elsewhere
            scene = f"{Path(path).resolve()}:{name}"
        load_build(scene)  # a wrong name fails here, before any run starts
        return scene
    if not callable(scene):
        raise ParameterError(
            f"scene must be a catalogue name, 'module:function' or a function, got {scene!r}"
        )
    module, name = getattr(scene, "__module__", None), getattr(scene, "__qualname__", "")
    if not module or "<" in name:
        raise ParameterError(
            f"scene {scene!r} cannot be imported by another process: define it at the top level of a module"
        )
    if module == "__main__":
        path = getattr(sys.modules["__main__"], "__file__", None)
        if not path:
            raise ParameterError("scene: a function typed at the interpreter cannot reach worker processes")
        module = str(Path(path).resolve())
    spec = f"{module}:{name}"
    if load_build(spec) is not scene:
        raise ParameterError(f"scene {spec!r} does not name the function given")
    return spec


def load_build(spec: str) -> Callable:
    """The build function `spec` names (see scene_spec)."""
    if ":" not in spec:
        module = scenes.SCENES.get(spec)
        if module is None:
            raise ParameterError(
                f"unknown scene {spec!r}; choose one of: {', '.join(scenes.SCENES)}, or 'module:function'"
            )
        return module.build
    module_name, _, attr = spec.rpartition(":")
    try:
        if module_name.endswith(".py"):
            module = _script(Path(module_name).resolve())
        else:
            module = importlib.import_module(module_name)
        build = module
        for part in attr.split("."):
            build = getattr(build, part)
    except (ImportError, AttributeError, OSError) as e:
        raise ParameterError(f"scene {spec!r} cannot be loaded: {e}") from None
    if not callable(build):
        raise ParameterError(f"scene {spec!r} is not a function")
    return build


def _script(path: Path):
    """The module of the Python file `path`: the running script itself, or the file loaded as a module
    (its `if __name__ == "__main__":` block does not run)."""
    main = sys.modules.get("__main__")
    if getattr(main, "__file__", None) and Path(main.__file__).resolve() == path:
        return main
    loader = importlib.util.spec_from_file_location("_taichi_anim_sweep_scene", path)
    if loader is None or loader.loader is None:
        raise ImportError(f"no Python file {path}")
    module = importlib.util.module_from_spec(loader)
    sys.modules[loader.name] = module  # dataclasses and Taichi look a module up by name
    loader.loader.exec_module(module)
    return module


def build_names(build: Callable) -> list[str] | None:
    """The keyword names the build function takes, or None when it takes **kwargs (any name)."""
    names = []
    for p in inspect.signature(build).parameters.values():
        if p.kind is p.VAR_KEYWORD:
            return None
        if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD):
            names.append(p.name)
    return names


def check_names(names, accepted: list[str] | None, what: str = "parameter") -> None:
    """ParameterError naming the first of `names` that neither the scene's build (its names `accepted`,
    None: any) nor a run (RUN_OPTIONS) takes, with the names they take."""
    if accepted is None:
        return
    for name in names:
        if name not in accepted and name not in RUN_OPTIONS:
            raise ParameterError(
                f"unknown {what} {name!r}; this scene takes: {', '.join(accepted) or 'none'}; every run "
                f"takes: {', '.join(RUN_OPTIONS)}"
            )


def check_value(name: str, value) -> None:
    """Values travel to worker processes as JSON: numbers, strings, booleans, None and lists of them."""
    try:
        json.dumps(value, allow_nan=False)
    except (TypeError, ValueError):
        raise ParameterError(
            f"parameter {name!r}: value {value!r} is not a number, string, boolean, None or a list of them"
        ) from None


def expand(params: Mapping[str, list], mode: str = "product") -> list[dict]:
    """The runs of a sweep, one dict of values each: every combination of the lists (mode "product",
    the last name varying fastest) or the i-th value of every list (mode "list", equal lengths)."""
    if mode not in MODES:
        raise ParameterError(f"unknown mode {mode!r}; choose one of: {', '.join(MODES)}")
    names = list(params)
    lists = []
    for name in names:
        values = params[name]
        if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
            raise ParameterError(f"parameter {name!r}: give a list of values, got {values!r}")
        values = list(values)
        if not values:
            raise ParameterError(f"parameter {name!r}: the list of values is empty")
        for v in values:
            check_value(name, v)
        lists.append(values)
    if mode == "list":
        lengths = {len(v) for v in lists}
        if len(lengths) > 1:
            sizes = ", ".join(f"{n} {len(v)}" for n, v in zip(names, lists, strict=True))
            raise ParameterError(f"mode 'list' needs lists of one length, got {sizes}")
        rows = [dict(zip(names, row, strict=True)) for row in zip(*lists, strict=True)]
    else:
        rows = [dict(zip(names, row, strict=True)) for row in itertools.product(*lists)]
    seen: dict[str, int] = {}
    for k, row in enumerate(rows):
        key = json.dumps(row, sort_keys=True)
        if key in seen:
            raise ParameterError(f"run {k} repeats run {seen[key]} ({row}): each run must differ")
        seen[key] = k
    return rows


def _text(value) -> str:
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return ",".join(_text(v) for v in value)
    return str(value)


def run_id(values: Mapping) -> str:
    """A folder name from the values, e.g. "substeps=4_seed=1": characters other than letters, digits
    and _ . , + - become "-"; a long one is cut and ends in a hash of all values."""
    if not values:
        return "run"
    text = "_".join(f"{_UNSAFE.sub('-', str(k))}={_UNSAFE.sub('-', _text(v))}" for k, v in values.items())
    text = text.lstrip(".") or "run"
    if len(text) > ID_MAX_CHARS:
        text = text[: ID_MAX_CHARS - 9] + "-" + _digest(values)
    return text


def _digest(values: Mapping) -> str:
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:8]


def unique_ids(runs: list[Mapping]) -> list[str]:
    """run_id of each run; runs whose ids collide (different values, one folder name) get a hash."""
    ids = [run_id(r) for r in runs]
    for k, i in enumerate(ids):
        if ids.count(i) > 1:
            ids[k] = f"{i[: ID_MAX_CHARS - 9]}-{_digest(runs[k])}"
    return ids


def parse_value(text: str):
    """A command-line value: int, then float, then true/false, none, else the string itself."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_param(text: str) -> tuple[str, list]:
    """`name=v1,v2,...` (or `name=[...]`, a JSON list, for values that hold commas) -> (name, values)."""
    name, eq, values = text.partition("=")
    name = name.strip()
    if not eq or not name or not values.strip():
        raise ParameterError(f"--param must read NAME=V1,V2,..., got {text!r}")
    if values.lstrip().startswith("["):
        try:
            parsed = json.loads(values)
        except ValueError as e:
            raise ParameterError(f"--param {name}: not a JSON list: {e}") from None
        if not isinstance(parsed, list):
            raise ParameterError(f"--param {name}: not a JSON list: {values!r}")
        return name, parsed
    return name, [parse_value(v) for v in values.split(",")]
