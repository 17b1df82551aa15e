"""Adaptive step size by step doubling (Press et al., "Numerical Recipes", 3rd ed., sec. 17.2; the
course's rule): take one step of h and two of h/2 with the base method; their difference estimates the
error. Above `tol` halve h and retry; below tol / 2^(p+1) (doubling h multiplies the local error of an
order-p method by 2^(p+1)) accept and double h; otherwise accept and keep h. The two half steps are kept.
The error is the max norm over all particles of the difference in u = (x [m], v [m/s]).
A step needing more than `max_rejected` halvings, or a step below `h_min`, fails as in rk45.py
(`fail_step`: ConvergenceError under nonconvergence="raise", else DivergenceError).
"""

import taichi as ti

from .. import validate
from ..runtime import data_oriented
from ..stability import StabilityRegion
from .base import Integrator, scratch_pairs
from .rk45 import fail_step


@data_oriented
class IntegratorAdaptive(Integrator):
    """Step doubling around any fixed-step base integrator (default RK4). tol: max-norm error of
    u = (x [m], v [m/s]) per internal step; h_init, h_min [s]: first and smallest internal step;
    max_rejected: halvings allowed within one `step(dt)`. Accepted and rejected internal steps are
    counted here and in the run's Health ("substeps_accepted" / "substeps_rejected")."""

    own_caches = False  # the base method evaluates the terms with its own caches
    stability_region = StabilityRegion.adaptive()  # step doubling chooses the steps

    def __init__(
        self,
        base: Integrator | str = "rk4",
        *,
        tol: float = 1e-4,
        h_init: float | None = None,
        h_min: float = 1e-10,
        max_rejected: int = 100,
        **options,
    ):
        super().__init__(**options)
        if isinstance(base, str):
            # cycle: the integrators package imports this module before it defines make_integrator
            from . import make_integrator

            base = make_integrator(base, collision_mode=self.collision_mode)
        self.base = base
        self.name = f"adaptive_{base.name}"
        self.order = base.order
        self.stages = 3 * base.stages
        self.tol = validate.positive("tol", tol)
        self.h_init = None if h_init is None else validate.positive("h_init", h_init)
        self.h = self.h_init  # the next step size proposed by the error controller (run carry)
        self.h_min = validate.positive("h_min", h_min)
        self.max_rejected = validate.count("max_rejected", max_rejected, 0)
        self.xs = self.vs = None
        self.diff = None  # 0-d: the step-doubling difference (made by _allocate)
        self.accepted = 0
        self.rejected = 0

    @property
    def rigid_scheme(self):
        """The base method's: bodies take the Stepper's steps, not the step-doubling substeps."""
        return self.base.rigid_scheme

    def settings(self) -> dict:
        """The options (base method, tol, max_rejected) and the accepted/rejected substep counts."""
        return {
            **super().settings(),
            "base": self.base.name,
            "tol": self.tol,
            "max_rejected": self.max_rejected,
            "accepted": self.accepted,
            "rejected": self.rejected,
        }

    def run_carry(self) -> dict:
        return {"h": self.h, "base": self.base.run_carry()}

    def set_run_carry(self, carry: dict | None) -> None:
        self.h = self.h_init if carry is None else carry["h"]
        self.base.set_run_carry(None if carry is None else carry["base"])

    def _allocate(self, model) -> None:
        self.base.bind(model)
        self.diff = model.new_field(self, "adaptive_diff", float, ())
        self.xs, self.vs = scratch_pairs(model, self, 3)

    def advance_step(self, model, state, dt: float) -> None:
        xs, vs = self.xs, self.vs
        ta, step = state.time, state.step_count + 1
        w, big, half = 0, 1, 2
        self._copy(model, state, state.particle_x, state.particle_v, xs[w], vs[w], ta)
        done = 0.0
        h_next = self.h or dt
        lower = self.tol / 2 ** (self.order + 1)
        adv = self.base.advance
        accepted = rejected = 0
        while dt - done > 1e-12 * dt:
            h = min(h_next, dt - done)
            t = ta + done
            adv(model, state, xs[w], vs[w], xs[big], vs[big], ta, t, h, step, False)
            adv(model, state, xs[w], vs[w], xs[half], vs[half], ta, t, 0.5 * h, step, False)
            adv(model, state, xs[half], vs[half], xs[half], vs[half], ta, t + 0.5 * h, 0.5 * h, step, False)
            self.diff[None] = 0.0
            self._max_diff(model, state, xs[big], vs[big], xs[half], vs[half], ta)
            err = float(self.diff[None])
            if err > self.tol or err != err:
                rejected += 1
                h_next = 0.5 * h
                if rejected > self.max_rejected or h_next < self.h_min:
                    self._tally(accepted, rejected)
                    fail_step(self, step, t, h_next, err / self.tol, accepted, rejected)
                continue
            accepted += 1
            self._copy(model, state, xs[half], vs[half], xs[w], vs[w], ta)  # fixed roles: no recompiles
            done += h
            h_next = 2.0 * h if err < lower else h
        self.h = h_next
        self.evaluations = self.base.evaluations
        self._tally(accepted, rejected)
        self._finish_all(model, state, xs[w], vs[w], ta, dt, step)

    def _tally(self, accepted: int, rejected: int) -> None:
        self.accepted += accepted
        self.rejected += rejected
        self.health.count("substeps_accepted", accepted)
        self.health.count("substeps_rejected", rejected)

    @ti.kernel
    def _max_diff(
        self,
        model: ti.template(),
        state: ti.template(),
        xa: ti.template(),
        va: ti.template(),
        xb: ti.template(),
        vb: ti.template(),
        ta: float,
    ):
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            if model.alive(state, i, ta):
                d = ti.max(ti.abs(xa[i] - xb[i]).max(), ti.abs(va[i] - vb[i]).max())
                ti.atomic_max(self.diff[None], d)
