"""Embedded Runge–Kutta 5(4) of Dormand & Prince ("A family of embedded Runge-Kutta formulae", 1980;
tableau as in Hairer, Nørsett & Wanner I, Table II.5.2) with automatic step size control
(ibid., sec. II.4, eqs. 4.10-4.13): err = max_i |h sum (b - b*) k| / (atol + rtol |u|); accept if
err <= 1; next h = h * clip(0.9 err^(-1/5), 0.2, 5). Each `step(dt)` integrates to t + dt in as
many internal steps as the tolerance needs; collisions are applied once at the end of dt.
"""

from __future__ import annotations

import math

from .. import validate
from ..errors import ConvergenceError, DivergenceError
from ..runtime import data_oriented
from ..stability import StabilityRegion
from .base import scratch_pairs
from .runge_kutta import IntegratorRungeKutta, Tableau

DOPRI5 = Tableau(
    "rk45",
    5,
    a=(
        (),
        (1 / 5,),
        (3 / 40, 9 / 40),
        (44 / 45, -56 / 15, 32 / 9),
        (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
        (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
        (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
    ),
    b=(35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0),
    c=(0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0),
    b_low=(5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40),
)


@data_oriented
class IntegratorRK45(IntegratorRungeKutta):
    """Dormand–Prince 5(4) with error control. rtol, atol: tolerances on u = (x [m], v [m/s]);
    h_init [s]: first internal step (default dt); h_min [s]: smallest internal step; max_rejected:
    rejected internal steps allowed within one `step(dt)`. adaptive=False takes exactly one fifth-order
    step per `step(dt)` (for convergence studies). `accepted` and `rejected` count internal steps (also
    in the run's Health as "substeps_accepted" / "substeps_rejected"); `evaluations` counts force
    evaluations.

    A step that needs more than max_rejected rejections, or an internal step below h_min, has failed
    (typically: the problem is stiff at this dt, and an explicit method's step is held at its stability
    limit). It is recorded as an "adaptive_failed" event and raises at once, as scipy's solve_ivp stops
    with a failure status instead of iterating on: ConvergenceError under the policy
    nonconvergence="raise", else DivergenceError (step, quantity "step_size", value h), which the
    divergence policy handles like any failed step (raise, retry with substeps, or implicit Euler).
    Accepting the step anyway would hand an unstable explicit result to the next step."""

    stability_region = StabilityRegion.adaptive()  # its error control chooses the steps

    def __init__(
        self,
        *,
        rtol: float = 1e-6,
        atol: float = 1e-6,
        h_init: float | None = None,
        h_min: float = 1e-12,
        max_rejected: int = 100,
        adaptive: bool = True,
        **options,
    ):
        super().__init__(DOPRI5, **options)
        self.adaptive = bool(adaptive)
        self.rtol = validate.non_negative("rtol", rtol)
        self.atol = validate.positive("atol", atol)
        self.h_init = None if h_init is None else validate.positive("h_init", h_init)
        self.h = self.h_init  # the next step size proposed by the error controller (run carry)
        self.h_min = validate.positive("h_min", h_min)
        self.max_rejected = validate.count("max_rejected", max_rejected, 0)
        self.xs = self.vs = None
        self.accepted = 0
        self.rejected = 0

    def settings(self) -> dict:
        """The options (adaptive, rtol, atol, max_rejected) and the accepted/rejected step counts."""
        return {
            **super().settings(),
            "adaptive": self.adaptive,
            "rtol": self.rtol,
            "atol": self.atol,
            "max_rejected": self.max_rejected,
            "accepted": self.accepted,
            "rejected": self.rejected,
        }

    def _allocate(self, model) -> None:
        super()._allocate(model)
        if self.adaptive:
            self.xs, self.vs = scratch_pairs(model, self, 2)

    def advance_step(self, model, state, dt: float) -> None:
        if not self.adaptive:
            super().advance_step(model, state, dt)
            return
        xs, vs = self.xs, self.vs
        ta, step = state.time, state.step_count + 1
        self._copy(model, state, state.particle_x, state.particle_v, xs[0], vs[0], ta)
        # Fixed roles (work = xs[0], candidate = xs[1]) and a copy on accept: swapping the fields instead
        # would compile a second kernel instance in the middle of a run (fields are template arguments).
        done = 0.0
        h_next = self.h or dt
        accepted = rejected = 0
        while dt - done > 1e-12 * dt:
            h = min(h_next, dt - done)
            self.error[None] = 0.0
            self.advance(model, state, xs[0], vs[0], xs[1], vs[1], ta, ta + done, h, step, False)
            err = float(self.error[None])
            if err <= 1.0:
                self._copy(model, state, xs[1], vs[1], xs[0], vs[0], ta)
                done += h
                accepted += 1
                h_next = h * (5.0 if err == 0.0 else min(5.0, 0.9 * err**-0.2))
            else:
                rejected += 1
                # A non-finite estimate is a rejection too: the controller shrinks h by its largest factor.
                h_next = h * (max(0.2, 0.9 * err**-0.2) if math.isfinite(err) else 0.2)
            if rejected > self.max_rejected or h_next < self.h_min:
                self._tally(accepted, rejected)
                fail_step(self, step, ta + done, h_next, err, accepted, rejected)
        self.h = h_next
        self._tally(accepted, rejected)
        self._finish_all(model, state, xs[0], vs[0], ta, dt, step)

    def run_carry(self) -> dict:
        return {"h": self.h}

    def set_run_carry(self, carry: dict | None) -> None:
        self.h = self.h_init if carry is None else carry["h"]

    def _tally(self, accepted: int, rejected: int) -> None:
        self.accepted += accepted
        self.rejected += rejected
        self.health.count("substeps_accepted", accepted)
        self.health.count("substeps_rejected", rejected)


def fail_step(method, step: int, t: float, h: float, err: float, accepted: int, rejected: int) -> None:
    """An adaptive method's step failed its error control (too many rejections, or h below h_min):
    record it and raise ConvergenceError (policy nonconvergence="raise") or DivergenceError."""
    why = (
        f"more than max_rejected={method.max_rejected} rejected internal steps"
        if rejected > method.max_rejected
        else f"the internal step fell below h_min={method.h_min:g} s"
    )
    message = (
        f"{method.name}: step {step} (t={t:g} s) failed its error control: {why} "
        f"({rejected} rejected, {accepted} accepted; h reached {h:.3g} s, error {err:.3g} of the "
        f"tolerance). The problem is stiff at this step: use implicit_euler, a smaller dt, or looser "
        f"tolerances"
    )
    method.health.event("adaptive_failed", step, message, time=t, h=h, accepted=accepted, rejected=rejected)
    if method.policy.nonconvergence == "raise":
        raise ConvergenceError(message)
    raise DivergenceError(message, step=step, quantity="step_size", value=h)
