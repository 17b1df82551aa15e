"""integrator="auto": the cheapest method that is stable at a scene's frame step, chosen per model.

Every candidate is costed in force evaluations per frame (one element pass and particle update, the
cost of one symplectic Euler step):
- an explicit method with s stages takes n = ceil(frame_dt / (AUTO_SAFETY x limit)) substeps, its
  stability limit on the model's highest frequency omega (stability.py, the estimate the stability guard
  makes; Lanczos on the linearised forces): s x n evaluations;
- implicit Euler takes `implicit_substeps` steps (stable at any step; the demos take 4 per 1/60 s frame to
  keep its numerical damping low), each an assembly (IMPLICIT_ASSEMBLY evaluations) and I conjugate-
  gradient iterations (CG_ITERATION evaluations each). I is bounded by the CG error bound (Shewchuk 1994,
  eq. 55: iterations <= sqrt(kappa) ln(2 / tol) / 2) with kappa ~ 1 + (h omega)^2 for M + h^2 K, times
  CG_BOUND_SHARE, the share of the bound PCG used on the cloth demos, capped at max_iterations.
The constants were measured (benchmarks/results/auto_choice.md) on the cloth, drape and flag demos (per-step
times and iterations, 2-core CPU); the same benchmark checks that the chosen method is the one measured
fastest per frame. The estimate costs one Lanczos run (~0.1-1 s); the choice, its reason and every
candidate's estimated cost go into the run's settings (`Choice.record`).

With an error_tolerance [m] the choice is also held to accuracy: each candidate, cheapest first, runs
one frame from the state at n and at 2n substeps (scratch states), and Richardson's estimate of the
n-substep frame's position error, max_i |x_n - x_2n| 2^p / (2^p - 1) for a method of order p (Hairer,
Norsett & Wanner, "Solving ODEs I", sec. II.4), must be within the tolerance; otherwise n doubles (up to
MAX_DOUBLINGS times). The cheapest candidate that meets it wins. This measures the scene itself (no
fitted error model), at the price of compiling and running every candidate for a few frames.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from .. import validate
from ..errors import DivergenceError, ParameterError
from ..stability import AUTO_SAFETY, MAX_AUTO_SUBSTEPS, stability_limit, state_frequency
from . import make_integrator

CANDIDATES = ("symplectic_euler", "rk4", "implicit_euler")
STAGES = {"symplectic_euler": 1, "explicit_euler": 1, "midpoint": 2, "rk4": 4}
IMPLICIT_ASSEMBLY = 2.0  # evaluations: linearising the terms and assembling the right-hand side
CG_ITERATION = 0.8  # evaluations: one matrix-free product and the vector updates (0.75-0.84 measured)
CG_BOUND_SHARE = 0.5  # measured PCG iterations / the CG bound (0.45-1.0 on the cloth demos)
MAX_DOUBLINGS = 6  # error_tolerance: substeps doubled at most this often beyond the stable count


@dataclass(frozen=True)
class Choice:
    """name and options of the chosen integrator, substeps per frame, and why (candidates: name ->
    {"substeps", "evaluations_per_frame", "limit" [s] or None, "note"})."""

    name: str
    options: dict
    substeps: int
    reason: str
    omega: float
    candidates: dict = field(default_factory=dict)
    estimate: object = field(default=None, repr=False, compare=False)  # stability.Frequency (reused)
    integrator: object = field(default=None, repr=False, compare=False)  # made while testing accuracy

    def record(self) -> dict:
        """The choice for run.json: name, substeps, reason, omega [rad/s] and each candidate's cost."""
        return {
            "chosen": self.name,
            "substeps": self.substeps,
            "reason": self.reason,
            "omega": self.omega,
            "candidates": self.candidates,
        }


def implicit_iterations(h_omega: float, tol: float, max_iterations: int) -> float:
    """Estimated PCG iterations of one implicit Euler solve at h omega (module docstring)."""
    bound = 0.5 * math.sqrt(1.0 + h_omega * h_omega) * math.log(2.0 / tol)
    return min(float(max_iterations), max(1.0, CG_BOUND_SHARE * bound))


def _stable_cost(name: str, est, frame_dt: float, implicit_substeps: int, implicit_options: dict, coupled):
    """Substeps and force evaluations per frame of candidate `name` at its stable step (module
    docstring); evaluations_per_frame is inf when no step up to MAX_AUTO_SUBSTEPS is stable."""
    if name == "implicit_euler":
        h = frame_dt / implicit_substeps
        tol = implicit_options.get("tol", 1e-4)
        iters = implicit_iterations(h * est.omega, tol, implicit_options.get("max_iterations", 200))
        iters = iters if coupled else 0.0
        return {
            "substeps": implicit_substeps,
            "evaluations_per_frame": implicit_substeps * (IMPLICIT_ASSEMBLY + CG_ITERATION * iters),
            "limit": None,
            "note": f"~{iters:.0f} PCG iterations per step (h omega {h * est.omega:.3g}, tol {tol:g})",
        }
    limit = stability_limit(name, est.omega, est.zeta)
    if limit is None or limit <= 0.0:
        n = math.inf
    elif math.isinf(limit):
        n = 1
    else:
        n = max(1, math.ceil(frame_dt / (AUTO_SAFETY * limit) - 1e-9))
    return {
        "substeps": n if math.isfinite(n) else None,
        "evaluations_per_frame": STAGES[name] * n if n <= MAX_AUTO_SUBSTEPS else math.inf,
        "limit": None if limit is None or math.isinf(limit) else limit,
        "note": "no stable step" if not math.isfinite(n) else f"{n} substeps within the limit",
    }


def choose_integrator(
    model,
    frame_dt: float,
    *,
    state=None,
    candidates=CANDIDATES,
    implicit_substeps: int = 1,
    implicit_options: dict | None = None,
    explicit_options: dict | None = None,
    error_tolerance: float | None = None,
) -> Choice:
    """The cheapest of `candidates` stable at frame_dt [s] on `model` (at `state`, default the model's
    start): see the module docstring. implicit_options: implicit Euler's options (tol, max_iterations,
    linear solver; they enter its cost); explicit_options: the explicit methods' (e.g. check_every);
    error_tolerance [m]: also hold the estimated position error of one frame within it (module docstring)."""
    frame_dt = validate.positive("frame_dt", frame_dt)
    implicit_substeps = validate.count("implicit_substeps", implicit_substeps, 1)
    for name in candidates:
        validate.choice("candidates", name, [*STAGES, "implicit_euler"])
    implicit_options = dict(implicit_options or {})
    start = model.state() if state is None else state
    est = state_frequency(model, start)
    costs = {name: _stable_cost(name, est, frame_dt, implicit_substeps, implicit_options, model.coupled)
             for name in candidates}  # fmt: skip
    best = min(costs, key=lambda k: costs[k]["evaluations_per_frame"])
    if math.isinf(costs[best]["evaluations_per_frame"]):
        raise ParameterError(
            f"integrator='auto': none of {list(candidates)} is stable at {frame_dt:.3g} s per frame within "
            f"{MAX_AUTO_SUBSTEPS} substeps (highest frequency {est.omega:.4g} rad/s); add implicit_euler"
        )
    for c in costs.values():  # JSON has no infinity
        if math.isinf(c["evaluations_per_frame"]):
            c["evaluations_per_frame"] = None
    ranked = sorted(
        (k for k in costs if costs[k]["evaluations_per_frame"] is not None),
        key=lambda k: costs[k]["evaluations_per_frame"],
    )
    options_for = {
        k: (implicit_options if k == "implicit_euler" else dict(explicit_options or {})) for k in costs
    }
    integ = None
    if error_tolerance is not None:
        error_tolerance = validate.positive("error_tolerance", error_tolerance)
        best, integ = _meet_tolerance(
            model, frame_dt, start, est, costs, ranked, error_tolerance, options_for
        )
        ranked = sorted(
            (k for k in ranked if costs[k].get("tolerance", {}).get("met")),
            key=lambda k: costs[k]["evaluations_per_frame"],
        )
    runner_up = next((k for k in ranked if k != best), None)

    def cost(k: str) -> str:
        return f"{k} x{costs[k]['substeps']}: ~{costs[k]['evaluations_per_frame']:.0f}"

    reason = f"{cost(best)} force evaluations per frame"
    if runner_up is not None:
        reason += f" against {cost(runner_up)}"
    reason += f" (highest frequency {est.omega:.4g} rad/s)"
    if error_tolerance is not None:
        err = costs[best]["tolerance"]["estimated_error"]
        reason += f"; estimated error of a frame {err:.2g} m <= {error_tolerance:g} m"
    return Choice(best, options_for[best], int(costs[best]["substeps"]), reason, est.omega, costs, est, integ)


def frame_error(stepper, start, scratch, frame_dt: float, n: int, order: int) -> float:
    """Richardson's estimate [m] of the position error of one frame of n substeps from `start`
    (module docstring): max over particles of |x_n - x_2n| 2^p / (2^p - 1); inf if either run diverges."""
    a, b = scratch
    try:
        for s, count in ((a, n), (b, 2 * n)):
            start.save(s)
            stepper.advance(s, frame_dt / count, count)
            stepper.check(s)
    except DivergenceError:
        return math.inf
    xa = a.positions()
    xb = b.positions()
    diff = float(np.abs(xa - xb).max()) if len(xa) else 0.0
    return diff * 2**order / (2**order - 1) if math.isfinite(diff) else math.inf


def _meet_tolerance(model, frame_dt, start, est, costs, ranked, tol, options_for):
    """(name, integrator) of the cheapest candidate whose frame error is within tol, each candidate's
    substeps doubled from its stable count until it is; records the outcome in costs[name]["tolerance"]
    and updates its substeps and cost. Raises ParameterError if none meets it."""
    scratch = (model.state(), model.state())
    found = None
    for name in ranked:  # cheapest stable cost first: doubling only adds, so stop once one is cheaper
        if (
            found is not None
            and costs[name]["evaluations_per_frame"] >= costs[found[0]]["evaluations_per_frame"]
        ):
            break
        integ = make_integrator(name, **options_for[name])
        stepper = integ.stepper_for(model)
        stepper.stability_estimate = est  # the guard reuses the choice's estimate
        n = costs[name]["substeps"]
        per_frame = costs[name]["evaluations_per_frame"] / n
        for _ in range(MAX_DOUBLINGS + 1):
            err = frame_error(stepper, start, scratch, frame_dt, n, integ.order)
            if err <= tol:
                break
            n *= 2
        met = err <= tol
        costs[name]["tolerance"] = {"substeps": n, "estimated_error": err if math.isfinite(err) else None,
                                    "met": met}  # fmt: skip
        if met:
            costs[name].update(substeps=n, evaluations_per_frame=per_frame * n)
            if found is None or per_frame * n < costs[found[0]]["evaluations_per_frame"]:
                found = (name, integ)
    if found is None:
        raise ParameterError(
            f"integrator='auto': no candidate of {ranked} keeps the estimated error of a {frame_dt:.3g} s "
            f"frame within error_tolerance={tol:g} m with up to {2**MAX_DOUBLINGS}x its stable substeps"
        )
    return found


def make_chosen(model, choice: Choice):
    """The chosen integrator, bound to `model`, its stepper reusing the choice's frequency estimate (so
    the stability guard does not repeat it)."""
    if choice.integrator is not None:  # made while testing accuracy: already bound, compiled
        return choice.integrator
    integ = make_integrator(choice.name, **choice.options)
    integ.stepper_for(model).stability_estimate = choice.estimate
    return integ
