"""Explicit Runge–Kutta methods from a Butcher tableau (Hairer, Nørsett & Wanner, "Solving Ordinary
Differential Equations I", sec. II.1, eq. 1.8), applied to u = (x, v), u' = (v, M^-1 f(x, v, t)).

Stage s evaluates the force at u0 + h sum_l a[s][j] k_l; the last stage is fused with the combination
u1 = u0 + h sum_l b_l k_l (and, for embedded pairs, the error estimate h sum_l (b_l - b*_l) k_l), so an
S-stage method costs S kernel launches. Explicit Euler (S = 1) is a single kernel.
"""

from dataclasses import dataclass

import taichi as ti

from ..runtime import data_oriented
from ..stability import StabilityRegion
from .base import Integrator


@dataclass(frozen=True)
class Tableau:
    """a: lower-triangular stage coefficients (row s has s entries); b: weights; c: nodes;
    b_low: weights of the embedded lower-order solution (None if the method has none)."""

    name: str
    order: int
    a: tuple
    b: tuple
    c: tuple
    b_low: tuple | None = None


@data_oriented
class IntegratorRungeKutta(Integrator):
    """A fixed-step explicit Runge–Kutta method given by its tableau."""

    def __init__(self, tableau: Tableau, **options):
        super().__init__(**options)
        self.tableau = tableau
        self.name = tableau.name
        self.order = tableau.order
        self.stages = len(tableau.b)
        self.fusable = self.stages == 1  # explicit Euler: no stage launches between substeps
        self._embedded = tableau.b_low is not None
        self.kx = None  # stage derivatives, (stages-1, N) each: the last stage is never stored
        self.kv = None
        self.sx = self.sv = None
        self.error = None  # 0-d: max over particles of the scaled embedded error (made by _allocate)
        self.rtol = 0.0
        self.atol = 1.0

    @property
    def stability_region(self) -> StabilityRegion:
        """Its tableau's stability function (subclasses named in INTEGRATORS declare it on the class)."""
        return StabilityRegion.runge_kutta(self.tableau)

    @property
    def rigid_scheme(self) -> Tableau:
        """Rigid bodies are stepped by the same tableau (its higher-order weights, at the step given)."""
        return self.tableau

    def _allocate(self, model) -> None:
        self.error = model.new_field(self, "rk_error", float, ())
        if self.stages > 1:
            shape = (self.stages - 1, model.particle_capacity)
            self.kx = model.new_field(self, "rk_kx", float, shape, (3,))
            self.kv = model.new_field(self, "rk_kv", float, shape, (3,))
            if model.coupled:
                # Element terms read every particle's stage state, so stages s >= 1 live in fields.
                pa = model.particle_array
                self.sx = [None] + [pa(self, f"rk_sx{s}", dims=(3,)) for s in range(1, self.stages)]
                self.sv = [None] + [pa(self, f"rk_sv{s}", dims=(3,)) for s in range(1, self.stages)]

    def prepare(self, model, state, xi, vi, ta, t, h) -> None:
        for s in range(self.stages - 1):
            self._stage(model, state, xi, vi, s, ta, t, h)

    def _stage_fields(self, xi, vi, s: int):
        """Fields holding stage s's state (coupled models): the input for stage 0, else sx[s]."""
        return (xi, vi) if s == 0 else (self.sx[s], self.sv[s])

    @ti.func
    def _stage_state(self, i, xi: ti.template(), vi: ti.template(), s: ti.template(), h):
        x = xi[i]
        v = vi[i]
        for j in ti.static(range(s)):
            if ti.static(self.tableau.a[s][j] != 0.0):
                x += h * self.tableau.a[s][j] * self.kx[j, i]
                v += h * self.tableau.a[s][j] * self.kv[j, i]
        return x, v

    @ti.kernel
    def _stage(
        self,
        model: ti.template(),
        state: ti.template(),
        xi: ti.template(),
        vi: ti.template(),
        s: ti.template(),
        ta: float,
        t: float,
        h: float,
    ):
        ts = t + self.tableau.c[s] * h
        if ti.static(model.coupled):
            fx, fv = ti.static(self._stage_fields(xi, vi, s))
            model.element_pass(self.caches, fx, fv, ts)
        ti.loop_config(serialize=model.serial)
        for i in range(model.live_particles()):
            if model.alive(state, i, ta):
                if ti.static(model.coupled):
                    fx, fv = ti.static(self._stage_fields(xi, vi, s))
                    self.kx[s, i] = fv[i]
                    self.kv[s, i] = model.accel_total(self.caches, i, fx[i], fv[i], ts)
                    # The next stage's state needs only this particle's own stage derivatives.
                    xn, vn = self._stage_state(i, xi, vi, s + 1, h)
                    self.sx[s + 1][i] = xn
                    self.sv[s + 1][i] = vn
                else:
                    x, v = self._stage_state(i, xi, vi, s, h)
                    self.kx[s, i] = v
                    self.kv[s, i] = model.accel(i, x, v, ts)

    @ti.func
    def final_pass(self, model: ti.template(), xi: ti.template(), vi: ti.template(), t, h):
        last = ti.static(self.stages - 1)
        if ti.static(model.coupled):
            fx, fv = ti.static(self._stage_fields(xi, vi, last))
            model.element_pass(self.caches, fx, fv, t + self.tableau.c[last] * h)

    @ti.func
    def update(self, model: ti.template(), i, x0, v0, t, h):
        """(x1 [m], v1 [m/s]) of particle i after a step h [s] from (x0, v0) at t [s]: the last stage and the
        tableau's weighted sum of the stages."""
        last = ti.static(self.stages - 1)
        tl = t + self.tableau.c[last] * h
        kx_last = v0
        kv_last = v0
        if ti.static(model.coupled and last == 0):
            kv_last = model.accel_total(self.caches, i, x0, v0, tl)
        elif ti.static(model.coupled):
            kx_last = self.sv[last][i]
            kv_last = model.accel_total(self.caches, i, self.sx[last][i], self.sv[last][i], tl)
        else:
            xs, vs = self._stage_state_from(i, x0, v0, last, h)
            kx_last = vs
            kv_last = model.accel(i, xs, vs, tl)
        dx = self.tableau.b[last] * kx_last
        dv = self.tableau.b[last] * kv_last
        for j in ti.static(range(last)):
            if ti.static(self.tableau.b[j] != 0.0):
                dx += self.tableau.b[j] * self.kx[j, i]
                dv += self.tableau.b[j] * self.kv[j, i]
        x1 = x0 + h * dx
        v1 = v0 + h * dv
        if ti.static(self._embedded):
            ex = (self.tableau.b[last] - self.tableau.b_low[last]) * kx_last
            ev = (self.tableau.b[last] - self.tableau.b_low[last]) * kv_last
            for j in ti.static(range(last)):
                if ti.static(self.tableau.b[j] != self.tableau.b_low[j]):
                    ex += (self.tableau.b[j] - self.tableau.b_low[j]) * self.kx[j, i]
                    ev += (self.tableau.b[j] - self.tableau.b_low[j]) * self.kv[j, i]
            # Mixed absolute/relative scale per component (Hairer et al., eq. II.4.10).
            sx = self.atol + self.rtol * ti.max(ti.abs(x0), ti.abs(x1))
            sv = self.atol + self.rtol * ti.max(ti.abs(v0), ti.abs(v1))
            e = ti.max((h * ti.abs(ex) / sx).max(), (h * ti.abs(ev) / sv).max())
            ti.atomic_max(self.error[None], e)
        return x1, v1

    @ti.func
    def _stage_state_from(self, i, x0, v0, s: ti.template(), h):
        x = x0
        v = v0
        for j in ti.static(range(s)):
            if ti.static(self.tableau.a[s][j] != 0.0):
                x += h * self.tableau.a[s][j] * self.kx[j, i]
                v += h * self.tableau.a[s][j] * self.kv[j, i]
        return x, v


EXPLICIT_EULER = Tableau("explicit_euler", 1, a=((),), b=(1.0,), c=(0.0,))
MIDPOINT = Tableau("midpoint", 2, a=((), (0.5,)), b=(0.0, 1.0), c=(0.0, 0.5))
RK4 = Tableau(
    "rk4",
    4,
    a=((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
    b=(1 / 6, 1 / 3, 1 / 3, 1 / 6),
    c=(0.0, 0.5, 0.5, 1.0),
)


@data_oriented
class IntegratorExplicitEuler(IntegratorRungeKutta):
    """Forward Euler: x1 = x0 + h v0, v1 = v0 + h a(x0, v0). First order; unstable for any h on an
    undamped oscillator (its amplitude grows by sqrt(1 + (h w)^2) per step)."""

    stability_region = StabilityRegion.runge_kutta(EXPLICIT_EULER)

    def __init__(self, **options):
        super().__init__(EXPLICIT_EULER, **options)


@data_oriented
class IntegratorMidpoint(IntegratorRungeKutta):
    """Explicit midpoint (RK2): second order, two force evaluations."""

    stability_region = StabilityRegion.runge_kutta(MIDPOINT)

    def __init__(self, **options):
        super().__init__(MIDPOINT, **options)


@data_oriented
class IntegratorRK4(IntegratorRungeKutta):
    """Classic fourth-order Runge–Kutta: four force evaluations."""

    stability_region = StabilityRegion.runge_kutta(RK4)

    def __init__(self, **options):
        super().__init__(RK4, **options)
