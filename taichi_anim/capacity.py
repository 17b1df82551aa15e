"""Capacity buckets: fields that serve every size up to a power of two, so that a scene of another size
compiles nothing new.

Taichi keys a compiled kernel (in memory and in its offline cache) on the kernel's IR, which names every
field it touches by SNode id, and on the layout of those fields' SNode trees, shapes included. An exactly
sized field therefore makes every kernel that touches it compile again for each new size. With buckets on,
a body kind allocates its arrays at `bucket(n)` elements (the next power of two, at least MIN_CAPACITY)
and its kernels loop to the live count read from a 0-d field at run time, so:

- across processes, two sizes in one bucket build the same trees in the same order (same ids, same
  shapes): the second run finds every kernel in the offline cache;
- in one process, new fields get new SNode ids, so the same kernel would compile again. The pool below
  hands a dropped owner's fields (a State or Model that was garbage-collected) to the next owner that asks
  for the same role, dtype and shape: the IR is then identical and Taichi's in-memory cache answers.

Buckets are off by default (`init(size_buckets=True)`, TAICHI_ANIM_SIZE_BUCKETS=1, `taichi-anim demo
--size-buckets`; sweeps turn them on): with them a kind's public fields (`state.particle_x`, ...) hold
capacity rows, of which the first `particle_count` are the scene's. The NumPy accessors (positions(),
snapshot(), ...) return the live rows in both modes.
"""

import gc
import heapq
import itertools
import os
import weakref

import numpy as np
import taichi as ti
from taichi.lang import impl

from .errors import ParameterError

MIN_CAPACITY = 64  # below this the doubling's memory is nothing and small scenes share one bucket

_setting: dict = {"on": None}  # None: the environment decides (TAICHI_ANIM_SIZE_BUCKETS)


def set_enabled(on: bool | None) -> None:
    """Turn buckets on or off for models finalised from now on (None: back to the environment)."""
    if on is not None and not isinstance(on, bool):
        raise ParameterError(f"size_buckets must be True, False or None, got {on!r}")
    _setting["on"] = on


def enabled() -> bool:
    """Whether models finalised now allocate their arrays in capacity buckets."""
    if _setting["on"] is not None:
        return _setting["on"]
    return os.environ.get("TAICHI_ANIM_SIZE_BUCKETS", "") not in ("", "0")


def padded(a, rows: int, dtype) -> np.ndarray:
    """`a` with zero rows up to `rows` (a bucket's rows past the live count), as dtype: what from_numpy
    of a bucketed field takes."""
    a = np.asarray(a)
    out = np.zeros((rows, *a.shape[1:]), dtype=dtype)
    out[: len(a)] = a
    return out


def bucket(n: int) -> int:
    """The capacity for n elements: the next power of two, at least MIN_CAPACITY."""
    n = max(int(n), MIN_CAPACITY)
    return 1 << (n - 1).bit_length()


def _absent(counts) -> bool:
    return counts is None  # (`is` is not allowed in Taichi scope, even static)


@ti.func
def live(counts: ti.template(), slot: ti.template(), exact: ti.template()):
    """A live count inside a kernel: slot `slot` of `counts`, a 0-d vector field of live counts (buckets
    on: read at run time), or the compile-time constant `exact` when counts is None (exact sizes)."""
    if ti.static(_absent(counts)):
        return exact
    else:
        return counts[None][slot]


# ------------------------------------------------------------------------------------- the field pool

_pool: dict = {"prog": None, "free": {}}  # free: key -> heap of (creation serial, field)
_serials = itertools.count()


def _free_lists() -> dict:
    prog = impl.get_runtime().prog
    if _pool["prog"] is not prog:  # ti.init / ti.reset made a new program: the old fields are gone
        _pool["prog"], _pool["free"] = prog, {}
    return _pool["free"]


def make(dtype, shape, dims: tuple = ()):
    """A new field of `shape` with elements of `dims` (() scalar, (n,) vector, (n, m) matrix)."""
    if len(dims) == 0:
        return ti.field(dtype, shape)
    if len(dims) == 1:
        return ti.Vector.field(dims[0], dtype, shape)
    return ti.Matrix.field(dims[0], dims[1], dtype, shape)


def plain(owner, role: str, dtype, shape, dims: tuple = ()):
    """take()'s signature without the pool: a new field (exact sizes)."""
    return make(dtype, shape, dims)


def take(owner, role: str, dtype, shape, dims: tuple = ()):
    """A field of `shape` (elements of `dims`: () scalar, (n,) vector, (n, m) matrix) for `owner`: a
    field a dropped owner used in the same `role` if one is free, else a new one. It returns to the pool
    when `owner` is garbage-collected (weakref.finalize), so hold the owner as long as the field.

    A field from the pool holds what its last owner left: the owner writes every element it reads before
    reading it (zeroing here would compile Taichi's fill kernel for each field, in the next scene).

    The oldest free field of a role goes first: owners made in the same order as before (a run State,
    then the Stepper's rollback copy) get the same fields back, whatever order they were collected in."""
    shape = tuple(shape) if isinstance(shape, (tuple, list)) else (shape,)
    key = (role, str(dtype), shape, tuple(dims))  # `float` means the program's default_fp: one per pool
    free = _free_lists().setdefault(key, [])
    if free:
        serial, f = heapq.heappop(free)
    else:
        serial, f = next(_serials), make(dtype, shape, dims)
    weakref.finalize(owner, _give_back, _pool["prog"], key, serial, f)
    return f


def _give_back(prog, key, serial: int, f) -> None:
    if _pool["prog"] is prog:  # fields of an earlier program are invalid: drop them
        heapq.heappush(_pool["free"].setdefault(key, []), (serial, f))


def collect_dropped() -> None:
    """Run Python's cycle collector, so that owners dropped in reference cycles (a model and its terms, a
    stepper and its integrator) give their fields back before a new scene allocates (13-21 ms measured
    after building two demo scenes)."""
    gc.collect()


def pooled_count() -> int:
    """Fields waiting in the pool (tests)."""
    return sum(len(v) for v in _pool["free"].values()) if _pool["prog"] is impl.get_runtime().prog else 0
