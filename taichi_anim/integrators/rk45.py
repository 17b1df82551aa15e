"""Embedded Runge–Kutta 5(4) of Dormand & Prince ("A family of embedded Runge-Kutta formulae", 1980;
tableau as in Hairer, Nørsett & Wanner I, Table II.5.2) with automatic step size control
(ibid., sec. II.4, eqs. 4.10-4.13): err = max_i |h sum (b - b*) k| / (atol + rtol |u|); accept if
err <= 1; next h = h * clip(0.9 err^(-1/5), 0.2, 5). Each `step(dt)` integrates to t + dt in as
many internal steps as the tolerance needs; collisions are applied once at the end of dt.
"""

from __future__ import annotations

import math

from .. import validate
from ..errors import DivergenceError
from ..runtime import data_oriented
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
    h_init [s]: first internal step (default dt); h_min [s]: below it the run is declared diverged.
    adaptive=False takes exactly one fifth-order step per `step(dt)` (for convergence studies).
    `accepted` and `rejected` count internal steps; `evaluations` counts force evaluations."""

    def __init__(
        self,
        *,
        rtol: float = 1e-6,
        atol: float = 1e-6,
        h_init: float | None = None,
        h_min: float = 1e-12,
        adaptive: bool = True,
        **options,
    ):
        super().__init__(DOPRI5, **options)
        self.adaptive = bool(adaptive)
        self.rtol = validate.non_negative("rtol", rtol)
        self.atol = validate.positive("atol", atol)
        self.h = None if h_init is None else validate.positive("h_init", h_init)
        self.h_min = validate.positive("h_min", h_min)
        self.xs = self.vs = None
        self.accepted = 0
        self.rejected = 0

    def settings(self) -> dict:
        return {
            **super().settings(),
            "adaptive": self.adaptive,
            "rtol": self.rtol,
            "atol": self.atol,
            "accepted": self.accepted,
            "rejected": self.rejected,
        }

    def _allocate(self, model) -> None:
        super()._allocate(model)
        if self.adaptive:
            self.xs, self.vs = scratch_pairs(model.particle_count, 2)

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
        while dt - done > 1e-12 * dt:
            h = min(h_next, dt - done)
            self.error[None] = 0.0
            self.advance(model, state, xs[0], vs[0], xs[1], vs[1], ta, ta + done, h, step, False)
            err = float(self.error[None])
            if not math.isfinite(err):
                raise DivergenceError(
                    f"rk45: non-finite error estimate at step {step} (t={ta + done:g} s, h={h:g} s)"
                )
            if err <= 1.0:
                self._copy(model, state, xs[1], vs[1], xs[0], vs[0], ta)
                done += h
                self.accepted += 1
                h_next = h * (5.0 if err == 0.0 else min(5.0, 0.9 * err**-0.2))
            else:
                self.rejected += 1
                h_next = h * max(0.2, 0.9 * err**-0.2)
            if h_next < self.h_min:
                raise DivergenceError(
                    f"rk45: step size {h_next:g} s fell below h_min={self.h_min:g} s at step {step}"
                )
        self.h = h_next
        self._finish_all(model, state, xs[0], vs[0], ta, dt, step)
