"""`solve`: integrate a batch of independent systems u' = F(t, u) over t_span with one method, and
report what it cost (steps, rejected steps, F evaluations, Newton iterations) next to the result."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .. import validate
from ..errors import ConvergenceError, DivergenceError, ParameterError, SolverWarning
from ..health import make_policy
from ..runtime import ensure_initialized, float_dtype, np_float
from . import numpy_path
from .adaptive import FAIL_MAX_STEPS
from .system import TAICHI_MAX_DIM_IMPLICIT, System
from .taichi_path import build_kernel

METHODS = ("explicit_euler", "symplectic_euler", "midpoint", "rk4", "rk45", "adaptive", "implicit_euler")
ORDERS = {"explicit_euler": 1, "symplectic_euler": 1, "midpoint": 2, "rk4": 4, "rk45": 5, "implicit_euler": 1}
ADAPTIVE = ("rk45", "adaptive")
BASES = ("explicit_euler", "midpoint", "rk4")
_STEP_CONTROL = {"h_min": None, "max_rejected": 50, "max_steps": 100_000}
OPTIONS = {
    "rk45": {"rtol": 1e-6, "atol": 1e-9, **_STEP_CONTROL},
    "adaptive": {"k_max": 1e-6, "k_min": None, "base": "rk4", **_STEP_CONTROL},
    "implicit_euler": {"newton_tol": None, "newton_iterations": 10},
}
STATS = ("steps", "rejected", "evaluations", "newton_iterations", "unconverged")


@dataclass(frozen=True)
class Result:
    """What `solve` returns. u: the state at t (shape of u0: (dim,) or (batch, dim)); t_eval and u_eval:
    the requested sample times and the states there ((len(t_eval),) + u0's shape), None if none were
    asked. Cost per system (an int for one system, a (batch,) int64 array for a batch): steps (accepted
    steps), rejected (rejected steps of adaptive methods), evaluations (of F, finite-difference
    Jacobians included), newton_iterations and unconverged (implicit Euler's Newton iterations, and
    steps whose Newton loop stopped at its cap). method, backend ("taichi" or "numpy") and dtype: how it
    was computed."""

    u: np.ndarray
    t: float
    t_eval: np.ndarray | None
    u_eval: np.ndarray | None
    steps: int | np.ndarray
    rejected: int | np.ndarray
    evaluations: int | np.ndarray
    newton_iterations: int | np.ndarray
    unconverged: int | np.ndarray
    method: str
    backend: str
    dtype: str

    def stats(self) -> dict:
        """The cost summed over the batch ({"steps", "rejected", "evaluations", "newton_iterations",
        "unconverged"}: ints), with "systems" (the batch size), "method" and "backend"."""
        systems = 1 if np.ndim(self.steps) == 0 else len(self.steps)
        totals = {k: int(np.sum(getattr(self, k))) for k in STATS}
        return {"method": self.method, "backend": self.backend, "systems": systems, **totals}


def solve(
    system: System,
    u0,
    t_span,
    *,
    method: str = "rk4",
    dt: float | None = None,
    t_eval=None,
    policy=None,
    **options,
) -> Result:
    """Integrate u' = F(t, u) from t_span[0] to t_span[1] [s] for every row of u0.

    system: a `System` (Taichi or NumPy F). u0: (dim,) for one system or (batch, dim) for a batch of
    independent ones. method: one of METHODS. dt [s]: the step of fixed-step methods (required; each
    interval between output times takes ceil(length / dt) equal steps, so dt is the largest step), the
    first trial step of adaptive ones (default: a hundredth of t_span). t_eval: increasing times within
    t_span at which to record the state (Result.u_eval). policy: a Policy or dict; its nonconvergence
    ("ignore", "warn" (default) or "raise") says what a Newton loop that stops at its cap does.

    Options by method: rk45: rtol (1e-6), atol (1e-9); adaptive (step doubling): k_max (1e-6, max-norm
    error per step), k_min (default k_max / 2^(p+1), p the base's order), base ("rk4", "midpoint" or
    "explicit_euler"); both: h_min [s] (default 16 machine epsilons of the time), max_rejected (50 in a
    row), max_steps (100000 per system per call); implicit_euler: newton_tol (1000 machine epsilons,
    relative to max |u|), newton_iterations (10), and the system's jacobian or finite differences.

    Raises ParameterError for bad input, ConvergenceError when an adaptive method fails its step
    control, and DivergenceError when a state becomes non-finite.
    """
    if not isinstance(system, System):
        raise ParameterError(f"system must be a ta.ode.System, got {system!r}")
    validate.choice("method", method, METHODS)
    opts = _options(method, options)
    u, single = _initial_state(u0, system.dim)
    t0, t1 = _span(t_span)
    times = _times(t_eval, t0, t1)
    if method in ADAPTIVE:
        h0 = (t1 - t0) / 100.0 if dt is None else validate.positive("dt", dt)
    elif dt is None:
        raise ParameterError(f"method {method!r} takes fixed steps: give dt > 0 [s], got dt=None")
    else:
        h0 = validate.positive("dt", dt)
    if method == "symplectic_euler" and system.split is None:
        raise ParameterError("method 'symplectic_euler' needs a split system u = (x, v): give split=len(x)")
    policy = make_policy(policy)
    taichi = system.backend == "taichi"
    if taichi and method == "implicit_euler" and system.dim > TAICHI_MAX_DIM_IMPLICIT:
        raise ParameterError(
            f"dim={system.dim}: implicit_euler on the Taichi path unrolls a dense dim x dim solve, up to "
            f"dim={TAICHI_MAX_DIM_IMPLICIT}; use ta.ode.System.numpy for larger systems"
        )
    if taichi:
        ensure_initialized()
    dtype = np_float() if taichi else np.float64
    eps = float(np.finfo(dtype).eps)
    _fill_defaults(method, opts, eps, t0, t1)
    u = np.ascontiguousarray(u, dtype=dtype)
    batch = len(u)
    hs = np.full(batch, h0, dtype)
    ts = np.zeros(batch, dtype)
    stats = np.zeros((batch, 6), np.int32 if taichi else np.int64)
    samples = []
    ends = [te for te in times if te > t0] + ([t1] if not times or times[-1] < t1 else [])
    if times and times[0] == t0:
        samples.append(u.copy())
    ta = t0
    for tb in ends:
        n_steps = 0 if method in ADAPTIVE else max(1, math.ceil((tb - ta) / h0 - 1e-9))
        if n_steps > validate.INT32_MAX:
            raise ParameterError(
                f"dt={dt!r} needs {n_steps} steps over [{ta:g}, {tb:g}] s: more than 2^31 - 1"
            )
        if taichi:
            _advance_taichi(system, method, u, hs, ts, stats, ta, tb, n_steps, opts)
        else:
            numpy_path.advance(system, method, u, hs, ts, stats, ta, tb, n_steps, opts)
        _check(method, u, hs, ts, stats, tb, opts)
        if tb in times:
            samples.append(u.copy())
        ta = tb
    counts = {k: stats[:, j].astype(np.int64) for j, k in enumerate(STATS)}
    unconverged = int(counts["unconverged"].sum())
    if unconverged:
        _report_newton(policy.nonconvergence, unconverged, opts)
    pick = (lambda a: a[0]) if single else (lambda a: a)
    u_eval = np.stack(samples)[:, 0] if single and times else np.stack(samples) if times else None
    return Result(
        u=pick(u),
        t=t1,
        t_eval=np.asarray(times) if times else None,
        u_eval=u_eval,
        **{k: (int(v[0]) if single else v) for k, v in counts.items()},
        method=method if method != "adaptive" else f"adaptive_{opts['base']}",
        backend=system.backend,
        dtype=np.dtype(dtype).name,
    )


def _options(method: str, given: dict) -> dict:
    """The method's options: defaults updated with `given`, which may hold only the method's own."""
    allowed = OPTIONS.get(method, {})
    if given and not allowed:
        raise ParameterError(f"method {method!r} takes no options, got {sorted(given)}")
    validate.options(method, given, allowed)
    opts = {**allowed, **given}
    for name in ("rtol",):
        if name in opts:
            opts[name] = validate.non_negative(name, opts[name])
    for name in ("atol", "k_max"):
        if name in opts:
            opts[name] = validate.positive(name, opts[name])
    for name in ("h_min", "newton_tol"):
        if opts.get(name) is not None:
            opts[name] = validate.positive(name, opts[name])
    if opts.get("k_min") is not None:  # 0: the step never doubles
        opts["k_min"] = validate.non_negative("k_min", opts["k_min"])
    if "max_rejected" in opts:
        opts["max_rejected"] = validate.count("max_rejected", opts["max_rejected"], 0)
        opts["max_steps"] = validate.count("max_steps", opts["max_steps"], 1)
    if "newton_iterations" in opts:
        opts["newton_iterations"] = validate.count("newton_iterations", opts["newton_iterations"], 1)
    if "base" in opts:
        validate.choice("base", opts["base"], BASES)
    return opts


def _fill_defaults(method: str, opts: dict, eps: float, t0: float, t1: float) -> None:
    """Defaults that depend on the precision and the time span; neutral values for unused options."""
    if method in ADAPTIVE and opts["h_min"] is None:
        opts["h_min"] = 16.0 * eps * max(abs(t0), abs(t1))  # below this, t + h rounds back to t
    if method == "adaptive":
        k_min = opts["k_max"] / 2.0 ** (ORDERS[opts["base"]] + 1) if opts["k_min"] is None else opts["k_min"]
        if k_min > opts["k_max"]:
            raise ParameterError(f"k_min must not exceed k_max={opts['k_max']:g}, got k_min={k_min:g}")
        opts["grow_below"] = k_min / opts["k_max"]
    if method == "implicit_euler" and opts["newton_tol"] is None:
        opts["newton_tol"] = 1000.0 * eps
    neutral = {"rtol": 0.0, "atol": 1.0, "k_max": 1.0, "grow_below": 0.0, "newton_tol": 0.0}
    neutral.update(newton_iterations=1, h_min=0.0, max_rejected=0, max_steps=1, base="rk4")
    for key, value in neutral.items():
        opts.setdefault(key, value)


def _initial_state(u0, dim: int) -> tuple[np.ndarray, bool]:
    u = validate.real_array("u0", u0)
    single = u.shape == (dim,)
    if not single and (u.ndim != 2 or u.shape[1] != dim or len(u) == 0):
        raise ParameterError(
            f"u0 must have shape ({dim},) or (batch, {dim}) with batch >= 1, got shape {u.shape}"
        )
    return validate.finite_array("u0", u.reshape(-1, dim), (dim,)).copy(), single


def _span(t_span) -> tuple[float, float]:
    try:
        t0, t1 = t_span
    except (TypeError, ValueError):
        raise ParameterError(f"t_span must be a pair (t_start, t_end) [s], got {t_span!r}") from None
    t0, t1 = validate.finite("t_span[0]", t0), validate.finite("t_span[1]", t1)
    if not t1 > t0:
        raise ParameterError(f"t_span must have t_end > t_start, got {t_span!r}")
    return t0, t1


def _times(t_eval, t0: float, t1: float) -> list[float]:
    if t_eval is None:
        return []
    a = validate.real_array("t_eval", t_eval)
    if a.ndim != 1 or not len(a) or not np.all(np.isfinite(a)):
        raise ParameterError(f"t_eval must be a non-empty 1-D array of finite times [s], got {t_eval!r}")
    if np.any(np.diff(a) <= 0.0) or a[0] < t0 or a[-1] > t1:
        raise ParameterError(f"t_eval must increase strictly within t_span [{t0:g}, {t1:g}], got {t_eval!r}")
    return [float(x) for x in a]


def _advance_taichi(system, method, u, hs, ts, stats, ta, tb, n_steps, opts) -> None:
    import taichi as ti

    key = (method, opts["base"], str(float_dtype()))
    first = key not in system._kernels
    if first:
        system._kernels[key] = build_kernel(system, method, opts["base"], float_dtype())
    args = (u, hs, ts, stats, ta, tb, n_steps, opts["rtol"], opts["atol"], opts["k_max"], opts["grow_below"])
    args += (opts["newton_tol"], opts["newton_iterations"], opts["h_min"], opts["max_rejected"])
    try:
        system._kernels[key](*args, min(opts["max_steps"], validate.INT32_MAX))
    except ti.TaichiCompilationError as e:
        if not first:
            raise
        del system._kernels[key]
        what = "f and jacobian" if system.jacobian is not None else "f"
        raise ParameterError(
            f"{what} of {system!r} must be @ti.func (t, u) -> ti.Vector of dim={system.dim} "
            f"(jacobian: ti.Matrix({system.dim}, {system.dim})); Taichi could not compile them: {e}"
        ) from None


def _check(method, u, hs, ts, stats, tb, opts) -> None:
    """Raise on an adaptive failure or a non-finite state, naming the first system concerned."""
    failed = np.flatnonzero(stats[:, 5])
    if len(failed):
        i = int(failed[0])
        why = (
            f"took max_steps={opts['max_steps']} steps"
            if stats[i, 5] == FAIL_MAX_STEPS
            else f"rejected more than max_rejected={opts['max_rejected']} steps in a row or its step fell "
            f"below h_min={opts['h_min']:.3g} s"
        )
        raise ConvergenceError(
            f"{method}: system {i} (of {len(failed)} failed) {why} at t={float(ts[i]):g} s before "
            f"t={tb:g} s (step {float(hs[i]):.3g} s, {int(stats[i, 0])} accepted, "
            f"{int(stats[i, 1])} rejected). "
            f"The problem is stiff here: use implicit_euler, or looser tolerances"
        )
    bad = ~np.isfinite(u)
    if bad.any():
        i, c = (int(x) for x in np.argwhere(bad)[0])
        raise DivergenceError(
            f"{method}: system {i} became non-finite by t={tb:g} s (u[{c}] = {u[i, c]}; "
            f"{int(bad.any(axis=1).sum())} systems affected): the step is beyond the method's stability "
            f"limit or F is not finite there",
            quantity="u",
            value=float(u[i, c]),
        )


def _report_newton(action: str, count: int, opts: dict) -> None:
    message = (
        f"implicit_euler: {count} steps stopped at newton_iterations={opts['newton_iterations']} "
        f"above newton_tol={opts['newton_tol']:.3g}"
    )
    if action == "raise":
        raise ConvergenceError(message)
    if action == "warn":
        warnings.warn(message, SolverWarning, stacklevel=3)
