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
