"""Taichi initialisation: `init(arch=...)` for convenience; the library never calls `ti.init` on import."""

from __future__ import annotations

import os

import taichi as ti
from taichi.lang import impl

from . import validate

ARCHS = ("cpu", "gpu", "cuda", "vulkan", "auto")
PRECISIONS = ("f32", "f64")


def is_initialized() -> bool:
    """True once the application (or `init`) has initialised Taichi."""
    return impl.get_runtime().prog is not None


def init(
    arch: str = "cpu",
    *,
    precision: str = "f32",
    debug: bool = False,
    cpu_threads: int | None = None,
    offline_cache: bool = True,
    **taichi_options,
) -> str:
    """Initialise Taichi and return the name of the backend that actually runs.

    arch: "cpu" (default), "gpu" (any GPU Taichi finds, else CPU), "cuda", "vulkan", or "auto" (GPU if
    present, else CPU). precision: "f32" or "f64" for every float field the engine allocates.
    cpu_threads pins the CPU thread count (1 makes float atomics reproducible run to run).
    Calling it again resets Taichi: fields allocated before become invalid.
    """
    validate.choice("arch", arch, ARCHS)
    validate.choice("precision", precision, PRECISIONS)
    target = {"cpu": ti.cpu, "gpu": ti.gpu, "auto": ti.gpu, "cuda": ti.cuda, "vulkan": ti.vulkan}[arch]
    opts = dict(
        arch=target,
        default_fp=ti.f64 if precision == "f64" else ti.f32,
        debug=debug,
        offline_cache=offline_cache,
        log_level=ti.WARN,
    )
    if cpu_threads is not None:
        opts["cpu_max_num_threads"] = validate.count("cpu_threads", cpu_threads, 1)
    opts.update(taichi_options)
    ti.init(**opts)
    running = backend_name()
    if arch in ("cuda", "vulkan") and running != arch:
        raise RuntimeError(
            f"arch={arch!r} was requested but Taichi could not start it (running on {running})"
        )
    return running


def ensure_initialized() -> None:
    """Initialise Taichi on the CPU if the application has not done so yet."""
    if not is_initialized():
        init("cpu")


def backend_name() -> str:
    """Name of the running Taichi backend ("cpu", "cuda", "vulkan", ...)."""
    arch = impl.current_cfg().arch
    return "cpu" if arch in (ti.x64, ti.arm64) else arch.name


# Below this many elements a CPU loop runs on one thread: a parallel launch costs ~200 us more than a
# serial one on a 2-core CPU, more than small loops gain from the second core (measured in
# benchmarks/particles.py, "serial threshold").
CPU_SERIAL_BELOW = 20_000


def serial_loops(count: int) -> bool:
    """Whether kernels over `count` elements should run serially on the current backend."""
    return backend_name() == "cpu" and count < CPU_SERIAL_BELOW


def float_dtype():
    """The float type fields are allocated with (Taichi's default_fp)."""
    return impl.get_runtime().default_fp


def np_float():
    """The NumPy dtype matching the float fields (converting first avoids Taichi's f64 -> f32 warning)."""
    import numpy as np

    return np.float64 if float_dtype() == ti.f64 else np.float32


# The fast data_oriented below relies on two private names of Taichi's kernel_impl that are known to
# behave as it expects in these versions; any other version (or TAICHI_ANIM_PLAIN_DATA_ORIENTED=1) gets
# Taichi's own decorator, which is slower per launch but public.
FAST_DATA_ORIENTED_VERSIONS = {(1, 7, 4)}


def fast_data_oriented_available() -> bool:
    """Whether `data_oriented` takes the descriptor path (a known Taichi version, not disabled)."""
    if os.environ.get("TAICHI_ANIM_PLAIN_DATA_ORIENTED", "") not in ("", "0"):
        return False
    if tuple(ti.__version__) not in FAST_DATA_ORIENTED_VERSIONS:
        return False
    try:
        from taichi.lang.kernel_impl import _BoundedDifferentiableMethod  # noqa: F401
    except ImportError:
        return False
    return True


FAST_DATA_ORIENTED = fast_data_oriented_available()


class _BoundKernel:
    """A class attribute that binds a Taichi kernel to the instance it is read from (what Taichi's own
    `__getattribute__` does for data-oriented classes, as a descriptor instead)."""

    def __init__(self, kernel):
        self.kernel = kernel

    def __get__(self, obj, owner=None):
        if obj is None:
            return self.kernel
        from taichi.lang.kernel_impl import _BoundedDifferentiableMethod

        return _BoundedDifferentiableMethod(obj, self.kernel)


def data_oriented(cls):
    """`ti.data_oriented` with native attribute access (on the Taichi versions it is verified for).

    Taichi's decorator replaces `__getattribute__` on the class with a Python function (to bind kernels),
    so every attribute read, and every failed `isinstance` on an instance (it reads `__class__`), costs a
    Python call: a kernel launch with the model, the state and the solver as template arguments paid
    ~20 of them, tens of microseconds per launch (benchmarks/launch_overhead.py measures both paths).
    Here the class keeps Python's own attribute lookup and each kernel becomes a descriptor that binds
    it the way Taichi does. Elsewhere it is plain `ti.data_oriented`.
    """
    cls = ti.data_oriented(cls)
    if not FAST_DATA_ORIENTED:
        return cls
    if "__getattribute__" in vars(cls):
        del cls.__getattribute__
    for name, attr in list(vars(cls).items()):
        if hasattr(attr, "_is_wrapped_kernel") and getattr(attr, "_is_classkernel", False):
            attr._is_staticmethod = False
            setattr(cls, name, _BoundKernel(attr))
    return cls
