"""Filling many fields from NumPy in one launch, and reading many into NumPy in one.

Taichi's `field.from_numpy` is a kernel templated on the field: each field filled is a kernel of its own,
compiled (about 60 ms here with an empty offline cache) or loaded from the cache (about 17 ms) before it
runs. A model of rigid bodies fills some forty fields at `finalize()`: 2.7 s of a six-body scene's
first build, 0.7 s of every later one. `fill` writes them all with one kernel over the fields' tuple,
the same values (the arrays are converted to each field's type first, as from_numpy wants them).

`read` is the other way: the first rows of several fields in one launch, serial for a small model. Each
`field.to_numpy()` is a kernel of its own too, and a parallel loop: 0.1-0.2 ms of thread-pool wake-up
each on this CPU, so a snapshot of four fields cost more than a small scene's frame (the pile demo's
bodies: 0.93 ms against a 0.27 ms frame)."""

import contextlib
import math

import numpy as np
import taichi as ti
from taichi.lang.matrix import MatrixField

from .runtime import compile_with, np_float, serial_loops


def _element_shape(field) -> tuple:
    """() for a scalar field, (n,) for a vector field, (n, m) for a matrix field."""
    if isinstance(field, MatrixField):
        return (field.n,) if field.ndim == 1 else (field.n, field.m)
    return ()


GROUP = 16  # fields per loop: Taichi warns of static loops unrolled more than 32 times


@ti.func
def _copy_row(f: ti.template(), data: ti.template(), start: ti.template(), shape: ti.template(), i):
    size = ti.static(int(np.prod(shape, dtype=int)))  # values per element
    at = start + i * size
    if ti.static(len(shape) == 0):
        f[i] = data[at]
    elif ti.static(len(shape) == 1):
        for c in ti.static(range(shape[0])):
            f[i][c] = data[at + c]
    else:
        for r, c in ti.static(ti.ndrange(shape[0], shape[1])):
            f[i][r, c] = data[at + r * shape[1] + c]


# One parallel loop per run of fields of one length, not per field: every top-level loop is a task of its
# own, which the first launch of each new Taichi program generates machine code for. A rigid model's
# forty-odd fields, mostly of the bodies' length, took 0.76 s of the pile demo's warm start as forty loops.
# Copies only, run once per scene: compiled without Taichi's CFG passes and advanced optimisation (the same
# bits; the pour demo's four fills 0.67 -> 0.61 s of its cold start, medians of 3).
@compile_with(cfg_optimization=False, advanced_optimization=False)
@ti.kernel
def _fill_kernel(
    fields: ti.template(),
    layout: ti.template(),
    loops: ti.template(),
    floats: ti.types.ndarray(),
    ints: ti.types.ndarray(),
):
    for g in ti.static(range(len(loops))):
        n, members = ti.static(loops[g])
        for i in range(n):
            for k in ti.static(members):
                start, is_int, shape = ti.static(layout[k])
                if ti.static(is_int):
                    _copy_row(fields[k], ints, start, shape, i)
                else:
                    _copy_row(fields[k], floats, start, shape, i)


def _loops(lengths: list[int]) -> tuple:
    """((length, field indices), ...): the fields grouped by length, in order, at most GROUP a loop."""
    by_length: dict[int, list[int]] = {}
    for k, n in enumerate(lengths):
        by_length.setdefault(n, []).append(k)
    return tuple(
        (n, tuple(ks[a : a + GROUP])) for n, ks in by_length.items() for a in range(0, len(ks), GROUP)
    )


_collecting: list | None = None  # the entries of the open batch() (None: none open)


@contextlib.contextmanager
def batch():
    """Inside it, fill() only checks and collects its arrays; leaving it writes them all in one launch
    (Model.state: every kind's start is one kernel, not one per kind and per field). Nothing inside may
    read a field it fills. A batch opened inside another joins it; one left by an error writes nothing."""
    global _collecting
    if _collecting is not None:
        yield
        return
    _collecting = entries = []
    try:
        yield
    finally:
        _collecting = None
    _launch(entries)


def fill(pairs) -> None:
    """Write each array into its field, [(field, array)]: one-dimensional fields of scalars, vectors or
    matrices of i32 or the program's float, each array of the field's full shape. One launch for all (or
    for all of the open batch())."""
    entries = []
    for field, array in pairs:
        is_int = field.dtype == ti.i32
        shape = _element_shape(field)
        flat = np.ascontiguousarray(array, dtype=np.int32 if is_int else np_float()).reshape(-1)
        if len(field.shape) != 1 or flat.size != field.shape[0] * int(np.prod(shape, dtype=int)):
            raise ValueError(
                f"bulk.fill: an array of shape {np.shape(array)} for a field of {field.shape} x {shape}"
            )
        entries.append((field, flat, is_int, shape))
    if _collecting is not None:
        _collecting.extend(entries)
    else:
        _launch(entries)


def _launch(entries) -> None:
    if not entries:
        return
    chunks, used, layout = {False: [], True: []}, {False: 0, True: 0}, []
    for _, flat, is_int, shape in entries:
        layout.append((used[is_int], is_int, shape))
        chunks[is_int].append(flat)
        used[is_int] += flat.size
    floats = np.concatenate(chunks[False]) if chunks[False] else np.zeros(1, np_float())
    ints = np.concatenate(chunks[True]) if chunks[True] else np.zeros(1, np.int32)
    fields = tuple(e[0] for e in entries)
    _fill_kernel(fields, tuple(layout), _loops([f.shape[0] for f in fields]), floats, ints)


@ti.func
def _read_row(f: ti.template(), data: ti.template(), at, shape: ti.template(), i):
    if ti.static(len(shape) == 0):
        data[at] = f[i]
    elif ti.static(len(shape) == 1):
        for c in ti.static(range(shape[0])):
            data[at + c] = f[i][c]
    else:
        for r, c in ti.static(ti.ndrange(shape[0], shape[1])):
            data[at + r * shape[1] + c] = f[i][r, c]


@ti.func
def _read_rows(
    fields: ti.template(),
    layout: ti.template(),
    serial: ti.template(),
    rows,
    floats: ti.template(),
    ints: ti.template(),
):
    ti.loop_config(serialize=serial)
    for i in range(rows):
        for k in ti.static(range(len(fields))):
            offset, is_int, shape = ti.static(layout[k])  # offset: values per row of the fields before
            size = ti.static(math.prod(shape))
            if ti.static(is_int):
                _read_row(fields[k], ints, offset * rows + i * size, shape, i)
            else:
                _read_row(fields[k], floats, offset * rows + i * size, shape, i)


@ti.kernel
def _read_kernel(
    fields: ti.template(),
    layout: ti.template(),
    serial: ti.template(),
    rows: ti.i32,
    floats: ti.types.ndarray(),
    ints: ti.types.ndarray(),
):
    _read_rows(fields, layout, serial, rows, floats, ints)


# Fields of floats only (positions, velocities): one array argument, not two. Each array a launch takes
# costs about 13 us here (a positions read of 4,096 particles: 65 against 43 us for the launch).
@ti.kernel
def _read_floats_kernel(
    fields: ti.template(),
    layout: ti.template(),
    serial: ti.template(),
    rows: ti.i32,
    floats: ti.types.ndarray(),
):
    _read_rows(fields, layout, serial, rows, floats, floats)


def read(fields, rows: int) -> list:
    """The first `rows` rows of each field, as NumPy arrays of shape (rows, *element shape) and the
    field's type (i32 or the program's float), read in one launch: one-dimensional fields of scalars,
    vectors or matrices with at least `rows` rows. Serial below runtime.CPU_SERIAL_BELOW rows of
    capacity (the first field's), as the model's loops."""
    layout, used, sizes = [], {False: 0, True: 0}, []
    for field in fields:
        is_int = field.dtype == ti.i32
        shape = _element_shape(field)
        if len(field.shape) != 1 or not 0 <= rows <= field.shape[0]:
            raise ValueError(f"bulk.read: {rows} rows of a field of shape {field.shape}")
        layout.append((used[is_int], is_int, shape))
        sizes.append(math.prod(shape))  # math.prod: np.prod costs ~2 us a call, a read made a dozen
        used[is_int] += sizes[-1]
    floats = np.empty(max(used[False] * rows, 1), np_float())
    ints = np.empty(max(used[True] * rows, 1), np.int32) if used[True] else None
    if rows:
        serial = serial_loops(fields[0].shape[0])
        if ints is None:
            _read_floats_kernel(tuple(fields), tuple(layout), serial, rows, floats)
        else:
            _read_kernel(tuple(fields), tuple(layout), serial, rows, floats, ints)
    out = []
    for (offset, is_int, shape), size in zip(layout, sizes, strict=True):
        data = ints if is_int else floats
        out.append(data[offset * rows : (offset + size) * rows].reshape((rows, *shape)))
    return out
