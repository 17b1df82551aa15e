"""NVIDIA Warp's cross-framework cloth benchmark (warp/examples/benchmarks/benchmark_cloth.py, shipped with
warp-lang) as a library: the peer side of benchmarks/cloth_warp.py.

Importing benchmark_cloth.py runs its benchmark at module level (three grid sizes, then it appends to a
benchmark.csv in the working folder), so this module reads its source instead: the module's imports and
its `Cloth` class are executed as written (the imports include usd-core's `pxr`, as in the original;
without usd-core the class alone is executed, which needs only NumPy), and the scene parameters are read
from the literal assignments and the `Cloth(...)` call of its `run_benchmark`, so a Warp release that
changed the scene would show here instead of being silently benchmarked against an older copy. The
integrators of each mode come from the sibling modules of that folder (benchmark_cloth_warp.WpIntegrator,
benchmark_cloth_taichi.TiIntegrator, benchmark_cloth_numpy.NpIntegrator), imported unchanged.

Facts about those integrators that matter when reading the figures:
- `benchmark_cloth_warp` calls `wp.clear_kernel_cache()` when first imported: the first frame of the first
  Warp run in a process holds the compile of its kernels; later runs reuse the loaded module.
- `TiIntegrator.__init__` calls `ti.init(arch=ti.cpu)` (or `ti.gpu`) itself, which resets Taichi: fields
  allocated before (the engine's) become invalid.
- `NpIntegrator` steps the cloth's own arrays in place (`cloth.positions` moves), and uses gravity 9.8 m/s^2
  where the Warp and Taichi modes use 9.81.
- Every mode's `simulate(dt, substeps)` returns the positions as a NumPy array (a device-to-host copy on a
  GPU), which the benchmark times with the frame.
"""

from __future__ import annotations

import ast
import copy
import importlib
import sys
from pathlib import Path

import numpy as np

MODES_CPU = ("warp_cpu", "taichi_cpu", "numpy")
MODES_CUDA = ("warp_gpu", "taichi_gpu")


def benchmark_folder() -> Path:
    """warp/examples/benchmarks of the installed warp-lang (raises ImportError without warp-lang)."""
    import warp

    folder = Path(warp.__file__).resolve().parent / "examples" / "benchmarks"
    if not (folder / "benchmark_cloth.py").is_file():
        raise FileNotFoundError(f"{folder}/benchmark_cloth.py is missing from this warp-lang install")
    return folder


def _source() -> tuple[Path, ast.Module]:
    path = benchmark_folder() / "benchmark_cloth.py"
    return path, ast.parse(path.read_text(), filename=str(path))


_CLOTH_CLASS = None
_PXR_IMPORTED = False


def cloth_class():
    """Warp's `Cloth` class, executed from benchmark_cloth.py's source with the module's own imports."""
    global _CLOTH_CLASS, _PXR_IMPORTED
    if _CLOTH_CLASS is not None:
        return _CLOTH_CLASS
    path, tree = _source()
    imports = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Cloth"]
    if len(classes) != 1:
        raise RuntimeError(f"{path}: expected one class Cloth, found {len(classes)}")
    namespace: dict = {"__name__": "benchmark_cloth_source", "__file__": str(path)}
    try:
        exec(compile(ast.Module(body=imports, type_ignores=[]), str(path), "exec"), namespace)
        _PXR_IMPORTED = True
    except ImportError as e:  # usd-core missing: the class needs only NumPy
        print(f"warp_cloth: {e}; executing the Cloth class without the module's imports", file=sys.stderr)
        namespace = {"__name__": "benchmark_cloth_source", "__file__": str(path), "np": np}
    exec(compile(ast.Module(body=classes, type_ignores=[]), str(path), "exec"), namespace)
    _CLOTH_CLASS = namespace["Cloth"]
    return _CLOTH_CLASS


def pxr_imported() -> bool:
    """Whether the module's imports (usd-core's pxr among them) ran for real."""
    cloth_class()
    return _PXR_IMPORTED


def scene(dim: int) -> dict:
    """The scene of `run_benchmark(mode, dim, ...)`, read from its source: the literal assignments
    (sim_fps, sim_substeps, sim_duration, k_stretch, ...) and the keyword arguments of its Cloth(...)
    call evaluated with them. Returns {"constants": {...}, "cloth_kwargs": {...}}."""
    path, tree = _source()
    funcs = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "run_benchmark"]
    if len(funcs) != 1:
        raise RuntimeError(f"{path}: expected one function run_benchmark")
    env: dict = {"dim": dim, "np": np}
    constants: dict = {}
    call = None
    for node in ast.walk(funcs[0]):
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            name = node.targets[0].id
            if isinstance(node.value, ast.Call) and getattr(node.value.func, "id", None) == "Cloth":
                call = node.value
                continue
            try:  # literals and expressions of earlier ones (sim_dt = 1.0 / sim_fps)
                value = eval(compile(ast.Expression(node.value), str(path), "eval"), {}, dict(env))
            except Exception:
                continue
            if isinstance(value, int | float | bool):
                env[name] = value
                constants[name] = value
    if call is None:
        raise RuntimeError(f"{path}: run_benchmark builds no Cloth(...)")
    kwargs = {
        kw.arg: eval(compile(ast.Expression(kw.value), str(path), "eval"), {}, dict(env))
        for kw in call.keywords
    }
    return {"constants": constants, "cloth_kwargs": kwargs}


def make_cloth(dim: int):
    """Warp's Cloth for a dim x dim grid, with the arguments its run_benchmark passes."""
    return cloth_class()(**scene(dim)["cloth_kwargs"])


def fresh(cloth):
    """A deep copy: NpIntegrator moves the cloth's own arrays, so every mode starts from its own copy."""
    return copy.deepcopy(cloth)


def _module(name: str):
    folder = str(benchmark_folder())
    if folder not in sys.path:
        sys.path.insert(0, folder)
    return importlib.import_module(name)


def make_integrator(mode: str, cloth):
    """The integrator run_benchmark builds for `mode` (warp_cpu, warp_gpu, taichi_cpu, taichi_gpu, numpy)."""
    if mode in ("warp_cpu", "warp_gpu"):
        return _module("benchmark_cloth_warp").WpIntegrator(cloth, "cpu" if mode == "warp_cpu" else "cuda")
    if mode in ("taichi_cpu", "taichi_gpu"):
        return _module("benchmark_cloth_taichi").TiIntegrator(
            cloth, "cpu" if mode == "taichi_cpu" else "cuda"
        )
    if mode == "numpy":
        return _module("benchmark_cloth_numpy").NpIntegrator(cloth)
    raise ValueError(f"unknown mode {mode!r}")


def cuda_available() -> dict[str, str | None]:
    """Per framework, None if CUDA is usable, else why not. Taichi's `ti.gpu` falls back to the CPU
    silently, so its check initialises `ti.cuda` and reads back the arch (this resets Taichi)."""
    out: dict[str, str | None] = {}
    try:
        import warp as wp

        wp.config.quiet = True
        wp.init()
        out["warp"] = None if wp.is_cuda_available() else "Warp finds no CUDA device"
    except Exception as e:  # noqa: BLE001 (any failure means: not usable)
        out["warp"] = f"{type(e).__name__}: {e}"
    try:
        import taichi as ti
        from taichi.lang import impl

        ti.init(arch=ti.cuda, log_level=ti.ERROR)
        arch = impl.current_cfg().arch
        out["taichi"] = None if arch == ti.cuda else f"ti.init(arch=ti.cuda) fell back to {arch.name}"
    except Exception as e:  # noqa: BLE001
        out["taichi"] = f"{type(e).__name__}: {e}"
    return out
