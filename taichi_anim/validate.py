"""Input checks that raise ParameterError naming the parameter and the offending value."""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping

import numpy as np

from .errors import ParameterError

# Counters and indices run in 32-bit integers in the kernels (Taichi's default_ip).
INT32_MAX = 2**31 - 1
# cgroup files that bound a container's memory below what the machine has (v2, then v1).
_CGROUP_LIMITS = (
    ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
    ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"),
)


def number(name: str, value) -> float:
    """`value` as a float if it is a real number (not a bool, string or None), else raise. NaN and inf
    pass: the callers say which range they accept."""
    if value is None or isinstance(value, str | bytes | bool | np.bool_):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {value!r}") from None


def finite(name: str, value: float) -> float:
    """Return `value` as float if it is a finite number, else raise."""
    v = number(name, value)
    if not math.isfinite(v):
        raise ParameterError(f"{name} must be a finite number, got {value!r}")
    return v


def positive(name: str, value: float) -> float:
    """Return `value` as float if it is finite and > 0, else raise."""
    v = number(name, value)
    if not math.isfinite(v) or v <= 0.0:
        raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def non_negative(name: str, value: float) -> float:
    """Return `value` as float if it is finite and >= 0, else raise."""
    v = number(name, value)
    if not math.isfinite(v) or v < 0.0:
        raise ParameterError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def in_range(name: str, value: float, lo: float, hi: float) -> float:
    """Return `value` as float if lo <= value <= hi, else raise."""
    v = number(name, value)
    if not (lo <= v <= hi):
        raise ParameterError(f"{name} must lie in [{lo}, {hi}], got {value!r}")
    return v


def count(name: str, value: int, minimum: int = 0, maximum: int = INT32_MAX) -> int:
    """Return `value` as int if it is an integer in [minimum, maximum] (a whole float such as 3.0
    counts), else raise."""
    ok = value is not None and not isinstance(value, str | bytes | bool | np.bool_)
    if ok:
        try:
            ok = math.isfinite(value) and int(value) == value and minimum <= value <= maximum
        except (TypeError, ValueError, OverflowError):
            ok = False
    if not ok:
        bound = f"in [{minimum}, {maximum}]" if maximum != INT32_MAX else f">= {minimum}"
        shown = value.item() if isinstance(value, np.generic) else value
        raise ParameterError(f"{name} must be an integer {bound}, got {shown!r}")
    return int(value)


def flag(name: str, value) -> bool:
    """Return `value` as a bool if it is one (or 0 / 1), else raise: "no" or "False" as strings would
    otherwise read as True."""
    if isinstance(value, bool | np.bool_) or (isinstance(value, int | np.integer) and value in (0, 1)):
        return bool(value)
    raise ParameterError(f"{name} must be True or False, got {value!r}")


def real_array(name: str, value) -> np.ndarray:
    """`value` as a float64 array if it holds real numbers (not bools, strings or None), else raise."""
    try:
        raw = np.asarray(value)
    except ValueError:  # ragged nested lists
        raise ParameterError(f"{name} must be an array of numbers, got {value!r}") from None
    if raw.dtype.kind not in "iuf":
        raise ParameterError(f"{name} must hold numbers, got {value!r} (dtype {raw.dtype})")
    return raw.astype(np.float64)


def per_element(name: str, value, n: int, what: str = "particle") -> np.ndarray:
    """A scalar or one value per element as a (n,) float64 array; any other shape raises naming the
    expected and the given shape."""
    a = real_array(name, value)
    if a.ndim > 1 or (a.ndim == 1 and len(a) != n):
        raise ParameterError(
            f"{name} must be a scalar or one value per {what} (shape ({n},)), got shape {a.shape}"
        )
    return np.broadcast_to(a, (n,)).copy()


def index_list(name: str, value, n: int, what: str = "particles") -> np.ndarray:
    """A 1-D list of element indices in [0, n) as int64: whole numbers only (1.7 is not index 1),
    no bools, no NaN."""
    a = np.asarray(value if value is not None else [], dtype=object).reshape(-1)
    for v in a:
        v = v.item() if isinstance(v, np.generic) else v
        if isinstance(v, str | bytes | bool | np.bool_) or v is None:
            raise ParameterError(f"{name} must hold integer indices of {what}, got {v!r} in {value!r}")
        try:
            whole = math.isfinite(v) and int(v) == v
        except (TypeError, ValueError):
            whole = False
        if not whole:
            raise ParameterError(f"{name} must hold integer indices of {what}, got {v!r} in {value!r}")
    idx = a.astype(np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        bad = int(idx[(idx < 0) | (idx >= n)][0])
        raise ParameterError(f"{name} must hold indices in [0, {n}) (the number of {what}), got {bad}")
    return idx


def vec3(name: str, value: Iterable[float]) -> tuple[float, float, float]:
    """Return a finite 3-vector as a tuple, else raise."""
    try:
        a = real_array(name, value).reshape(-1)
    except ParameterError:
        a = np.zeros(0)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be 3 finite numbers, got {value!r}")
    return float(a[0]), float(a[1]), float(a[2])


def box(name: str, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of an axis-aligned box [m] as float arrays; ParameterError naming `name` unless both are
    finite 3-vectors with hi > lo on every axis."""
    lo = np.asarray(vec3(f"{name} lo", lo))
    hi = np.asarray(vec3(f"{name} hi", hi))
    if np.any(hi <= lo):
        raise ParameterError(
            f"{name}: hi must exceed lo on every axis, got lo={lo.tolist()}, hi={hi.tolist()}"
        )
    return lo, hi


def unit3(name: str, value: Iterable[float]) -> tuple[float, float, float]:
    """Return the normalised 3-vector, raising on a zero or non-finite vector."""
    v = np.asarray(vec3(name, value))
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise ParameterError(f"{name} must be a non-zero vector, got {value!r}")
    return tuple(float(c) for c in v / n)  # type: ignore[return-value]


def finite_array(name: str, value, shape_tail: tuple[int, ...] = ()) -> np.ndarray:
    """Return `value` as a float64 array whose trailing shape is `shape_tail`, with no NaN or inf."""
    a = real_array(name, value)
    if shape_tail and (a.ndim != len(shape_tail) + 1 or a.shape[1:] != shape_tail):
        raise ParameterError(f"{name} must have shape (N, {', '.join(map(str, shape_tail))}), got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ParameterError(
            f"{name} contains {int(bad.sum())} non-finite values (first at index {first}: {a[first]})"
        )
    return a


def choice(name: str, value, options: Iterable[str]) -> str:
    """Return `value` if it is one of `options` (strings), else raise listing them."""
    opts = list(options)
    if value not in opts:
        raise ParameterError(f"unknown {name} {value!r}; choose one of: {', '.join(opts)}")
    return value


def colors(name: str, value, n: int) -> np.ndarray:
    """(n,3) colours in [0,1] as float64 (uint8 input is taken as 0..255)."""
    a = np.asarray(value)
    if a.dtype == np.uint8:
        a = a.astype(np.float64) / 255.0
    a = finite_array(name, a, (3,))
    if a.shape[0] != n:
        raise ParameterError(f"{name} must have one row per element ({n}), got {a.shape[0]} rows")
    if a.size and (a.min() < 0.0 or a.max() > 1.0):
        raise ParameterError(f"{name} must lie in [0, 1], got values in [{a.min():g}, {a.max():g}]")
    return a


def indices(name: str, value, width: int, vertex_count: int, vertex_name: str) -> np.ndarray:
    """(M,width) integer indices, each in [0, vertex_count), as int32 (Open3D's index type)."""
    a = np.asarray(value)
    if a.size == 0:
        a = a.reshape(0, width)
    if a.ndim != 2 or a.shape[1] != width:
        raise ParameterError(f"{name} must have shape (M, {width}), got {a.shape}")
    if a.dtype.kind not in "iuf":
        raise ParameterError(f"{name} must hold integer vertex indices, got dtype {a.dtype}")
    if a.dtype.kind == "f":
        whole = np.isfinite(a) & (a == np.round(a))
        if not whole.all():
            row = int(np.argwhere(~whole)[0][0])
            raise ParameterError(
                f"{name} must hold integer vertex indices, got {float(a[~whole][0])!r} "
                f"(row {row}: {a[row].tolist()})"
            )
    if a.size:
        bad = (a < 0) | (a >= vertex_count)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise ParameterError(
                f"{name} holds {int(bad.sum())} indices outside [0, {vertex_count}) (the number of "
                f"{vertex_name}); first bad row {row}: {a[row].tolist()}"
            )
    return a.astype(np.int32)


def options(name: str, given: Mapping, allowed: Iterable[str]) -> None:
    """Raise if `given` (keyword options) has a key outside `allowed`, listing the allowed ones."""
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        raise ParameterError(
            f"unknown {name} option {unknown[0]!r}; choose from: {', '.join(sorted(allowed))}"
        )


def fits_float(values: Mapping, dtype, *, path: str = "") -> None:
    """Raise if a float in `values` would overflow `dtype` (np.float32 or np.float64, the precision
    the fields are allocated in) to inf: a position of 1e300 is finite in float64 but inf in float32.
    `values` maps names to numbers, arrays, nested dicts / lists / tuples of them, or the package's
    own scene objects (colliders, motions, force terms), whose public attributes are read. The message
    names the parameter, the value and where it sits."""
    big = float(np.finfo(dtype).max)
    for key, value in values.items():
        _fits(f"{path}{key}", value, big, np.dtype(dtype).name)


def _fits(name: str, value, big: float, dtype_name: str, depth: int = 0) -> None:
    if isinstance(value, Mapping):
        for key, v in value.items():
            _fits(f"{name}.{key}", v, big, dtype_name, depth + 1)
        return
    if isinstance(value, str | bytes | bool | np.bool_) or value is None:
        return
    if isinstance(value, list | tuple) and any(not isinstance(v, int | float | np.number) for v in value):
        for k, v in enumerate(value):
            _fits(f"{name}[{k}]", v, big, dtype_name, depth + 1)
        return
    if type(value).__module__.startswith("taichi_anim.") and hasattr(value, "__dict__") and depth < 4:
        # A scene object (collider, motion, force term): every public attribute it will copy to fields.
        for key, v in vars(value).items():
            if not key.startswith("_"):
                _fits(f"{name}.{key}", v, big, dtype_name, depth + 1)
        return
    if not isinstance(value, np.ndarray | list | tuple | int | float | np.number):
        return
    a = np.asarray(value)
    if a.dtype.kind != "f" or a.size == 0:
        return
    # Only finite values: NaN and inf are rejected where they are given, and inf is a sentinel inside.
    over = np.isfinite(a) & (np.abs(a) > big)
    if over.any():
        where = tuple(int(i) for i in np.argwhere(over)[0]) if a.ndim else ()
        at = f" at index {where if len(where) > 1 else where[0]}" if where else ""
        raise ParameterError(
            f"{name} = {float(a[where] if where else a):g}{at} does not fit in {dtype_name} (largest "
            f"magnitude {big:.3g}): it would become inf; rescale the scene or use precision='f64'"
        )


def mass_fits(name: str, mass: np.ndarray, dtype) -> None:
    """Raise if a non-zero mass would round to 0 in `dtype` (pinning the particle) or its inverse
    overflow to inf: non-zero masses must be at least float's smallest normal number."""
    tiny = float(np.finfo(dtype).tiny)
    small = (mass != 0.0) & (np.abs(mass) < tiny)
    if small.any():
        i = int(np.argmax(small))
        raise ParameterError(
            f"{name} = {mass[i]:g} at particle {i} is below {np.dtype(dtype).name}'s smallest normal "
            f"number ({tiny:.3g}): it would round to 0 (a pinned particle) or its inverse overflow; "
            f"rescale the scene or use precision='f64'"
        )


# ------------------------------------------------------------------------------------------- capacities


def available_memory() -> int | None:
    """Bytes the process can still allocate without swapping: the kernel's MemAvailable (/proc/meminfo;
    elsewhere free physical pages, sysconf SC_AVPHYS_PAGES), capped by what an address-space limit
    (RLIMIT_AS) and a container's cgroup limit leave. None where nothing can be read (no check is made)."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, OSError, ValueError):
            return None
    try:  # an address-space limit (ulimit -v) fails allocations beyond it, whatever the machine has
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY:
            avail = min(avail, max(soft - _virtual_size(), 0))
    except (ImportError, OSError, ValueError):
        pass
    for limit_file, usage_file in _CGROUP_LIMITS:
        try:
            with open(limit_file, encoding="ascii") as f, open(usage_file, encoding="ascii") as g:
                limit, usage = f.read().strip(), g.read().strip()
            if limit.isdigit() and usage.isdigit():
                avail = min(avail, max(int(limit) - int(usage), 0))
                break
        except OSError:
            continue
    return avail


def _virtual_size() -> int:
    """The process's virtual memory size [bytes] (VmSize), 0 where unknown."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def human_bytes(n: float) -> str:
    """`n` bytes in binary units: 1536 -> '1.5 KiB'."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024.0 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n} B"  # not reached


def memory_fits(name: str, need: int, what: str) -> None:
    """Raise if `need` bytes (for `what`, which `name` asked for) exceed the memory available now."""
    avail = available_memory()
    if avail is not None and need > avail:
        raise ParameterError(
            f"{name}: {what} need about {human_bytes(need)} ({need} bytes), but only {human_bytes(avail)} "
            f"({avail} bytes) of memory are available"
        )


def capacity(
    name: str,
    value,
    *,
    bytes_each: float,
    limit: int = INT32_MAX,
    unit: str = "elements",
    why: str = f"that 32-bit Taichi indices (int32, at most {INT32_MAX}) can address",
) -> int:
    """`value` as an int if it is a whole count >= 0 that fits `limit` (by default the int32 range of
    Taichi indices; `why` says where a smaller limit comes from) and whose `bytes_each` per element fit
    in the available memory, else raise ParameterError naming `name`, the count, the bytes needed and
    the bytes available. Call it before allocating anything sized by the count."""
    n = count(name, value, 0, 2**63 - 1)
    if n > limit:
        raise ParameterError(f"{name}: {n} {unit} exceed {limit}, the most {why}")
    memory_fits(name, int(math.ceil(n * bytes_each)), f"{n} {unit} (~{bytes_each:.0f} bytes each)")
    return n
