"""Finite-difference check of a force term: its Jacobian products and its energy's gradient against
central differences (f(x + e p) - f(x - e p)) / 2e along a random direction p, whose error is O(e^2)
(Nocedal & Wright, "Numerical Optimization", 2nd ed. 2006, sec. 8.1, eq. 8.7). The step e is a
fraction of the scale of x (and of v): 1e-3 in float32, where rounding of f is ~1e-7 and the error then
~1e-4 of the derivative, and 1e-6 in float64. NumPy in, NumPy out; each call launches kernels (a new
term compiles its own once).
"""

import numpy as np
import taichi as ti

from .. import validate
from ..errors import ParameterError
from ..runtime import data_oriented, np_float
from .base import check_protocol


def check_term(term, x=None, v=None, t: float = 0.0, **options):
    """Check that `term` is a force term the engine can use (check_protocol: raises ParameterError
    naming its class and everything it lacks) and, given positions x (N,3) [m] (optionally v (N,3)
    [m/s], t [s] and check_term_derivatives' options), its derivatives: returns
    check_term_derivatives(term, x, v, t, ...), the relative errors of its Jacobian and energy gradient
    against central differences of its force and energy. Without x: returns None."""
    check_protocol(term)
    if x is None:
        return None
    return check_term_derivatives(term, x, v, t, **options)


def check_term_derivatives(
    term, x, v=None, t: float = 0.0, *, masses=None, h: float = 1.0, eps: float | None = None, seed: int = 0
) -> dict:
    """Relative errors of `term`'s derivatives at positions x (N,3) [m], velocities v (N,3) [m/s]
    (default 0) and time t [s], with particle masses (N,) [kg] (default 1) for a pointwise term:
      "jacobian_x": |(df/dx) p - FD_x|_inf / |FD_x|_inf, FD_x the central difference of the force in x
      "jacobian_v": the same in v
      "energy_gradient": |f(x, 0) . p + dE/dp| / |dE/dp| (None unless energy_kind is "potential")
    each over one random direction p (seed). An element term's Jacobian is its linearisation at step h
    [s] (element_linear; K = -df/dx and C = -df/dv recovered from two step sizes): a term that projects
    indefinite parts away (springs under compression) differs there by design. A derivative that is
    exactly 0 on both sides gives 0. eps: the relative difference step (default 1e-3 in float32, 1e-6
    in float64)."""
    check_protocol(term)
    x = validate.finite_array("x", np.asarray(x, dtype=np.float64))
    if x.ndim != 2 or x.shape[1] != 3:
        raise ParameterError(f"x must have shape (N, 3) [m], got {x.shape}")
    v = np.zeros_like(x) if v is None else validate.finite_array("v", np.asarray(v, dtype=np.float64))
    if v.shape != x.shape:
        raise ParameterError(f"v must have the shape of x {x.shape}, got {v.shape}")
    n = len(x)
    m = np.ones(n) if masses is None else np.asarray(masses, dtype=np.float64).reshape(-1)
    if m.shape != (n,):
        raise ParameterError(f"masses must have shape ({n},) [kg], got {m.shape}")
    if eps is None:
        eps = 1e-3 if np_float() == np.float32 else 1e-6
    eps = validate.positive("eps", eps)
    rng = np.random.default_rng(seed)
    p = rng.standard_normal(x.shape)
    p /= np.abs(p).max()
    ex = eps * max(float(np.abs(x).max()), 1e-3)  # [m]
    ev = eps * max(float(np.abs(v).max()), 1.0)  # [m/s]
    probe = _probe(term, n)
    f0, jx, jv = probe(x, v, t, m, h)
    fd_x = (probe(x + ex * p, v, t, m, h)[0] - probe(x - ex * p, v, t, m, h)[0]) / (2.0 * ex)
    fd_v = (probe(x, v + ev * p, t, m, h)[0] - probe(x, v - ev * p, t, m, h)[0]) / (2.0 * ev)
    out = {
        "jacobian_x": _relative(jx(p), fd_x),
        "jacobian_v": _relative(jv(p), fd_v),
        "energy_gradient": None,
    }
    if term.energy_kind == "potential":
        dE = (term.energy(x + ex * p, m) - term.energy(x - ex * p, m)) / (2.0 * ex)
        f_static = probe(x, np.zeros_like(x), t, m, h)[0]
        out["energy_gradient"] = _relative(np.array([-float(np.sum(f_static * p))]), np.array([dE]))
    return out


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    scale = max(float(np.abs(b).max(initial=0.0)), float(np.abs(a).max(initial=0.0)))
    return 0.0 if scale == 0.0 else float(np.abs(a - b).max()) / scale


def _probe(term, n: int):
    """(x, v, t, masses, h) -> (forces (N,3), p -> (df/dx) p, p -> (df/dv) p) for a term of either kind."""
    if term.coupled:
        return _element_probe(term, n)
    probe = _PointProbe(term, n)

    def run(x, v, t, m, h):
        f, jx, jv = probe.run(x, v, t, m)
        return f, (lambda p: np.einsum("nij,nj->ni", jx, p)), (lambda p: np.einsum("nij,nj->ni", jv, p))

    return run


def _element_probe(term, n: int):
    if not hasattr(term, "element_arrays"):
        raise ParameterError(f"check_term_derivatives needs an ElementTerm, got {type(term).__name__}")
    ids = np.asarray(term.vertices)
    dofs = (3 * ids[:, :, None] + np.arange(3)).reshape(len(ids), -1)

    def scatter(per_element):
        return np.bincount(dofs.ravel(), weights=per_element.ravel(), minlength=3 * n).reshape(n, 3)

    def run(x, v, t, m, h):
        F, _, S1, _ = term.element_arrays(x, v, t, h)
        S2 = term.element_arrays(x, v, t, 2.0 * h)[2]
        # S(h) = -(h df/dv + h^2 df/dx): two step sizes give K = -df/dx and C = -df/dv.
        K = (S2 - 2.0 * S1) / (2.0 * h * h)
        C = S1 / h - h * K

        def product(A):
            return lambda p: scatter(-np.einsum("eij,ej->ei", A, p.reshape(-1)[dofs]))

        return scatter(F), product(K), product(C)

    return run


@data_oriented
class _PointProbe:
    """A pointwise term's force and Jacobian blocks at NumPy arrays (one kernel per term)."""

    def __init__(self, term, n: int):
        self.term = term
        self.n = n
        self.x = ti.Vector.field(3, float, n)
        self.v = ti.Vector.field(3, float, n)
        self.m = ti.field(float, n)
        self.f = ti.Vector.field(3, float, n)
        self.jx = ti.Matrix.field(3, 3, float, n)
        self.jv = ti.Matrix.field(3, 3, float, n)

    def run(self, x, v, t, m):
        f = np_float()
        self.x.from_numpy(np.asarray(x, dtype=f))
        self.v.from_numpy(np.asarray(v, dtype=f))
        self.m.from_numpy(np.asarray(m, dtype=f))
        self._run(self.term, t)
        return tuple(a.to_numpy().astype(np.float64) for a in (self.f, self.jx, self.jv))

    @ti.kernel
    def _run(self, term: ti.template(), t: float):
        for i in range(self.n):
            self.f[i] = term.force(i, self.m[i], self.x[i], self.v[i], t)
            jx, jv = term.jacobian(i, self.m[i], self.x[i], self.v[i], t)
            self.jx[i] = jx
            self.jv[i] = jv
