"""Taichi initialisation: `init(arch=...)` for convenience; the library never calls `ti.init` on import.

"gpu" and "auto" do not hand Taichi its own `ti.gpu` list: Taichi checks each GPU backend in that list in
the calling process, and on a machine without a GPU its OpenGL check calls a null function pointer
(`initialize_opengl`, after cuda, metal and vulkan were found missing), killing the process with SIGSEGV.
Instead each candidate backend is started once in a child process (`probe_arch`), and only a backend that
started there, and ran a kernel, is started here; otherwise the CPU runs, with a warning.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import warnings

import taichi as ti
from taichi.lang import impl

from . import capacity, frontend, tensor_ops, validate
from .errors import ParameterError

frontend.install()  # Taichi's front end builds every kernel on every run; see frontend.py
tensor_ops.install()  # and inlines its vector operations as functions at every call; see tensor_ops.py

ARCHS = ("cpu", "gpu", "cuda", "vulkan", "auto")
PRECISIONS = ("f32", "f64")

# The GPU backends "gpu" and "auto" try, in order: those the engine is tested on (tests/test_backends.py),
# and Metal on macOS. OpenGL is left out: Taichi's OpenGL check is the one that crashes (see above).
GPU_CANDIDATES = ("cuda", "vulkan", "metal") if sys.platform == "darwin" else ("cuda", "vulkan")
# Vulkan drivers that run on the CPU (Mesa's lavapipe reports itself as "llvmpipe"): ~10x slower than
# Taichi's own CPU backend on a cloth step, so "gpu"/"auto" do not count them as a GPU.
SOFTWARE_VULKAN = ("llvmpipe", "lavapipe", "swiftshader")
PROBE_TIMEOUT_S = 60.0
# Taichi's offline cache holds 100 MB by default and, past that, deletes a quarter of its files (least
# recently used) whenever a program ends. The engine's kernels outgrow it: the test suite's take 334 MB
# (10,500 kernels), so a run evicted what later runs compiled again, and a sweep over many sizes or
# scenes does the same. 1 GiB holds them with room to spare (Taichi keeps the size in a signed 32-bit
# integer); TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES or init's `offline_cache_max_size_of_files` sets another.
OFFLINE_CACHE_BYTES = 1024**3

_PROBE_SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "device_probe.py")

_probes: dict[str, dict] = {}
_choice: dict | None = None


def probe_arch(arch: str, *, timeout: float = PROBE_TIMEOUT_S) -> dict:
    """Whether Taichi can start `arch` ("cuda", "vulkan", "metal", ...) and run a kernel on it, tried in a
    child process so that a crash cannot take this one down. Returns {"arch", "ok", "detail",
    "seconds"}; the answer is cached for the life of the process."""
    if arch in _probes:
        return _probes[arch]
    t0 = time.perf_counter()
    try:
        run = subprocess.run(
            [sys.executable, _PROBE_SCRIPT, arch],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        ok, detail = _probe_verdict(arch, run.returncode, run.stdout + run.stderr)
    except subprocess.TimeoutExpired:
        ok, detail = False, f"no answer within {timeout:g} s"
    except OSError as e:
        ok, detail = False, f"could not start the probe: {e}"
    result = {"arch": arch, "ok": ok, "detail": detail, "seconds": round(time.perf_counter() - t0, 3)}
    _probes[arch] = result
    return result


def _probe_verdict(arch: str, returncode: int, output: str) -> tuple[bool, str]:
    """(ok, detail) from the probe's exit status and output (see device_probe.py)."""
    if returncode < 0:
        return False, f"Taichi crashed while starting {arch} (signal {-returncode})"
    marks = [line.split()[1:] for line in output.splitlines() if line.startswith("TAICHI_ANIM_PROBE ")]
    started = [m[1] for m in marks if m[0] == "started"]
    if returncode != 0 or not started:
        errors = [line.strip() for line in output.splitlines() if "Error" in line or "error" in line]
        why = (errors or ["no output"])[-1][:200]
        return False, f"Taichi could not start {arch} (exit status {returncode}: {why})"
    if started[0] != arch:
        # Taichi's own warning says why (e.g. "libcuda.so lib not found."); its fallback notice does not.
        said = [
            line.split("] ", 2)[-1].strip()
            for line in output.splitlines()
            if line.startswith("[W ") and "adaptive_arch_select" not in line
        ]
        why = f": {said[0]}" if said else ""
        return False, f"Taichi found no {arch} device{why}"
    if ["kernel", "ok"] not in marks:
        return False, f"{arch} started but a test kernel gave a wrong result"
    if arch == "vulkan":
        low = output.lower()
        software = next((name for name in SOFTWARE_VULKAN if name in low), None)
        if software:
            return False, f"the only Vulkan device is a software renderer on the CPU ({software})"
    return True, f"{arch} started and ran a kernel"


def _pick_gpu(requested: str) -> tuple[str, str]:
    """The first GPU backend that passes its probe, else "cpu"; and why."""
    failures = []
    for arch in GPU_CANDIDATES:
        probe = probe_arch(arch)
        if probe["ok"]:
            return arch, f"{arch} found by probe ({probe['seconds']:.1f} s)"
        failures.append(f"{arch}: {probe['detail']}")
    return "cpu", "no GPU found (" + "; ".join(failures) + ")"


def arch_choice() -> dict:
    """How the running backend was chosen: {"requested": the arch asked of `init` (None if the
    application initialised Taichi itself), "chosen": the backend running now, "reason": why, "probes":
    the device probes run in this process (arch, ok, detail, seconds)}. For run records."""
    base = _choice or {"requested": None, "reason": "Taichi was initialised by the application"}
    running = backend_name() if is_initialized() else None
    return {**base, "chosen": running, "probes": [dict(p) for p in _probes.values()]}


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
    size_buckets: bool | None = None,
    **taichi_options,
) -> str:
    """Initialise Taichi and return the name of the backend that actually runs.

    arch: "cpu" (default), "cuda", "vulkan", or "gpu" / "auto" (the first of CUDA and Vulkan, and Metal on
    macOS, that starts and runs a kernel in a child process, ~1-2 s once per process; else the CPU,
    with a RuntimeWarning saying why; a Vulkan driver that runs on the CPU does not count as a GPU).
    `arch_choice()` records what was asked, what runs and why. precision: "f32" or "f64" for every
    float field the engine allocates. cpu_threads pins the CPU thread count (1 makes float atomics
    reproducible run to run). size_buckets: allocate the models finalised from now on in capacity
    buckets, so that another size of a scene compiles nothing new (capacity.py; None: the environment's
    TAICHI_ANIM_SIZE_BUCKETS, off if unset). The offline cache may hold OFFLINE_CACHE_BYTES (Taichi's
    own cap, 100 MB, is below what the engine's kernels take) unless `offline_cache_max_size_of_files`
    or TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES says otherwise. Calling it again resets Taichi: fields
    allocated before become invalid.
    """
    global _choice
    validate.choice("arch", arch, ARCHS)
    capacity.set_enabled(size_buckets)
    validate.choice("precision", precision, PRECISIONS)
    if arch in ("gpu", "auto"):
        chosen, reason = _pick_gpu(arch)
        if chosen == "cpu":
            warnings.warn(f"arch={arch!r}: running on the CPU: {reason}", RuntimeWarning, stacklevel=2)
    else:
        chosen, reason = arch, "requested"
    target = {"cpu": ti.cpu, "cuda": ti.cuda, "vulkan": ti.vulkan, "metal": ti.metal}[chosen]
    opts = dict(
        arch=target,
        default_fp=ti.f64 if precision == "f64" else ti.f32,
        debug=debug,
        offline_cache=offline_cache,
        log_level=ti.WARN,
    )
    if "TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES" not in os.environ:  # the user's choice stands
        opts["offline_cache_max_size_of_files"] = OFFLINE_CACHE_BYTES
    if cpu_threads is not None:
        opts["cpu_max_num_threads"] = validate.count("cpu_threads", cpu_threads, 1)
    opts.update(taichi_options)
    try:
        ti.init(**opts)
    except KeyError as e:  # Taichi's answer to an option it does not know
        raise ParameterError(f"init: {e.args[0] if e.args else e}") from None
    running = backend_name()
    _choice = {"requested": arch, "reason": reason}
    if running != chosen:
        if arch in ("cuda", "vulkan"):
            raise RuntimeError(
                f"arch={arch!r} was requested but Taichi could not start it (running on {running})"
            )
        _choice["reason"] = f"{reason}, but Taichi could not start {chosen} here"
        warnings.warn(
            f"arch={arch!r}: running on {running}: {_choice['reason']}", RuntimeWarning, stacklevel=2
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
# benchmarks/results/particles_study.md, "serial threshold").
CPU_SERIAL_BELOW = 20_000


def cpu_threads() -> int:
    """Taichi's CPU thread count in the running program (cpu_max_num_threads)."""
    return int(impl.current_cfg().cpu_max_num_threads)


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


# The CompileConfig switches a kernel may turn off for itself (`compile_with`). Taichi's offline cache
# key includes the config a kernel was compiled with, so each kernel's cache entry stays its own.
COMPILE_SWITCHES = ("cfg_optimization", "advanced_optimization")


def compile_with(**switches):
    """Decorator, above `@ti.kernel`: compile that kernel with Taichi's CompileConfig switches set as given
    (COMPILE_SWITCHES), the rest of the program unchanged.

    Taichi's IR passes grow faster than linearly with a kernel's size: the largest kernels (a solver's
    unrolled iterations, the fused step with every collider's swept test) spent most of a cold start in
    them. Each use names the compile time it saves and the run time it costs, measured
    (docs/guide/performance.md, "Compile time").

    Only the launch that compiles an instance runs with the switches (Taichi keeps an instance's cache
    key once computed, so later launches find it under any config): other launches pay one set lookup.
    The hook sits on Taichi's private `Kernel.launch_kernel`, so it is on only for the Taichi versions
    the fast data_oriented path is verified for; elsewhere the kernel compiles as before."""
    unknown = sorted(set(switches) - set(COMPILE_SWITCHES))
    if unknown:
        raise ParameterError(f"compile_with: unknown switch {unknown[0]!r}; choose from {COMPILE_SWITCHES}")

    def mark(kernel):
        primal = getattr(kernel, "_primal", None)
        if tuple(ti.__version__) in FAST_DATA_ORIENTED_VERSIONS and primal is not None:
            _switch_compiling_launches(primal, dict(switches))
        return kernel

    return mark


def _switch_compiling_launches(primal, switches: dict) -> None:
    """Make the Taichi Kernel `primal` compile each of its instances with `switches` set."""
    # ids of the instances compiled in this program. Forgotten when Taichi resets the kernel (ti.init,
    # ti.reset drop its instances): a new instance may then get an old one's id, and it compiled without
    # the switches. The switches change the bits (the integrator's step with Taichi's CFG passes moved a
    # 1,024-sphere pile by 1e-4 m in 100 steps), so a run in a process that had run others drifted from
    # the same run alone, as two tests saw under the full suite.
    compiled: set[int] = set()
    reset = primal.reset

    def forget_and_reset():
        compiled.clear()
        reset()

    primal.reset = forget_and_reset  # impl.reset() calls it on every kernel, from ti.init and ti.reset

    def launch_kernel(t_kernel, *args):
        # Looked up on the class at each call, so a wrapper installed there (CompileClock) still runs.
        launch = type(primal).launch_kernel
        if id(t_kernel) in compiled:
            return launch(primal, t_kernel, *args)
        cfg = impl.current_cfg()
        saved = {name: getattr(cfg, name) for name in switches}
        for name, value in switches.items():
            setattr(cfg, name, value)
        try:
            out = launch(primal, t_kernel, *args)
        finally:
            for name, value in saved.items():
                setattr(cfg, name, value)
        compiled.add(id(t_kernel))
        return out

    primal.launch_kernel = launch_kernel  # this kernel only: an attribute of the instance


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
