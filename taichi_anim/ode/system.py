"""An ODE system u' = F(t, u) of any dimension: F as a Taichi function (compiled into the kernel that
advances a batch) or as a vectorised NumPy function."""

from __future__ import annotations

import numpy as np

from .. import validate
from ..errors import ParameterError

BACKENDS = ("taichi", "numpy")
# The Taichi path unrolls the state vector (and, for implicit Euler, the dim x dim Newton matrix) into
# registers: beyond these sizes compile time and register pressure grow quickly; use the NumPy path.
TAICHI_MAX_DIM = 64
TAICHI_MAX_DIM_IMPLICIT = 12


class System:
    """u' = f(t, u) with a state of `dim` components.

    f: a ``@ti.func`` f(t, u) -> ``ti.Vector`` of `dim` components (u is a ``ti.Vector`` of `dim`,
    t a scalar) for the Taichi path; use ``System.numpy`` for a NumPy function.
    jacobian: optional ``@ti.func`` (t, u) -> ``ti.Matrix`` (dim, dim), dF/du, for implicit Euler
    (default: forward finite differences, `dim` extra evaluations of f per Newton iteration).
    split: number of leading components that are positions x in u = (x, v), for symplectic Euler
    (v1 = v0 + h F_v(t, x0, v0), then x1 = x0 + h F_x(t, x0, v1)); None if the system is not split.
    """

    def __init__(self, f, dim: int, *, jacobian=None, split: int | None = None):
        if not getattr(f, "_is_taichi_function", False):
            raise ParameterError(
                f"f must be a @ti.func f(t, u) returning a ti.Vector of dim components, got {f!r}; "
                f"for a NumPy function use ta.ode.System.numpy(f, dim)"
            )
        if jacobian is not None and not getattr(jacobian, "_is_taichi_function", False):
            raise ParameterError(
                f"jacobian must be a @ti.func (t, u) -> ti.Matrix(dim, dim), got {jacobian!r}"
            )
        self._setup(f, dim, jacobian, split, "taichi")
        validate.count("dim", dim, 1, TAICHI_MAX_DIM)

    @classmethod
    def numpy(cls, f, dim: int, *, jacobian=None, split: int | None = None) -> System:
        """A system whose F is a vectorised NumPy function f(t, U) -> array of U's shape: U is (m, dim)
        (m independent systems), t is (m,) (each system's own time). jacobian(t, U) -> (m, dim, dim),
        optional (finite differences otherwise); split as for the constructor."""
        if not callable(f):
            raise ParameterError(f"f must be a function f(t, U) -> (m, dim) array, got {f!r}")
        if jacobian is not None and not callable(jacobian):
            raise ParameterError(
                f"jacobian must be a function (t, U) -> (m, dim, dim) array, got {jacobian!r}"
            )
        system = cls.__new__(cls)
        system._setup(f, dim, jacobian, split, "numpy")
        return system

    def _setup(self, f, dim, jacobian, split, backend: str) -> None:
        self.f = f
        self.dim = validate.count("dim", dim, 1)
        self.jacobian = jacobian
        self.split = None if split is None else validate.count("split", split, 1, self.dim - 1)
        self.backend = backend
        self._kernels: dict = {}  # compiled advance kernels by (method, options, precision)

    def __repr__(self) -> str:
        return f"System({getattr(self.f, '__name__', self.f)!r}, dim={self.dim}, backend={self.backend!r})"

    def eval_numpy(self, t: np.ndarray, u: np.ndarray) -> np.ndarray:
        """f(t, U) for the NumPy path, checked: the result must have U's shape (m, dim)."""
        out = np.asarray(self.f(t, u), dtype=np.float64)
        if out.shape != u.shape:
            raise ParameterError(
                f"f must return an array of shape {u.shape} (the shape of U: systems x dim), "
                f"got shape {out.shape}"
            )
        return out

    def jacobian_numpy(self, t: np.ndarray, u: np.ndarray) -> np.ndarray:
        """dF/du for the NumPy path, (m, dim, dim), checked."""
        m, n = u.shape
        out = np.asarray(self.jacobian(t, u), dtype=np.float64)
        if out.shape != (m, n, n):
            raise ParameterError(f"jacobian must return an array of shape {(m, n, n)}, got shape {out.shape}")
        return out
