"""Input checks that raise ParameterError naming the parameter and the offending value."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from .errors import ParameterError


def positive(name: str, value: float) -> float:
    """Return `value` as float if it is finite and > 0, else raise."""
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def non_negative(name: str, value: float) -> float:
    """Return `value` as float if it is finite and >= 0, else raise."""
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        raise ParameterError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def in_range(name: str, value: float, lo: float, hi: float) -> float:
    """Return `value` as float if lo <= value <= hi, else raise."""
    v = float(value)
    if not (lo <= v <= hi):
        raise ParameterError(f"{name} must lie in [{lo}, {hi}], got {value!r}")
    return v


def count(name: str, value: int, minimum: int = 0) -> int:
    """Return `value` as int if it is an integer >= minimum, else raise."""
    if isinstance(value, bool) or int(value) != value or value < minimum:
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def vec3(name: str, value: Iterable[float]) -> tuple[float, float, float]:
    """Return a finite 3-vector as a tuple, else raise."""
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be 3 finite numbers, got {value!r}")
    return float(a[0]), float(a[1]), float(a[2])


def unit3(name: str, value: Iterable[float]) -> tuple[float, float, float]:
    """Return the normalised 3-vector, raising on a zero or non-finite vector."""
    v = np.asarray(vec3(name, value))
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise ParameterError(f"{name} must be a non-zero vector, got {value!r}")
    return tuple(float(c) for c in v / n)  # type: ignore[return-value]


def finite_array(name: str, value, shape_tail: tuple[int, ...] = ()) -> np.ndarray:
    """Return `value` as a float64 array whose trailing shape is `shape_tail`, with no NaN or inf."""
    a = np.asarray(value, dtype=np.float64)
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
    if not (np.issubdtype(a.dtype, np.integer) or (a.dtype.kind == "f" and np.all(a == np.round(a)))):
        raise ParameterError(f"{name} must hold integer vertex indices, got dtype {a.dtype}")
    if a.size:
        bad = (a < 0) | (a >= vertex_count)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise ParameterError(
                f"{name} holds {int(bad.sum())} indices outside [0, {vertex_count}) (the number of "
                f"{vertex_name}); first bad row {row}: {a[row].tolist()}"
            )
    return a.astype(np.int32)
