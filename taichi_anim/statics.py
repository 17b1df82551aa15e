"""Static equilibrium: the rest shape of a model under its forces, by Newton's method on the engine's own
implicit system, globalised by a line search on the potential energy and accelerated by Anderson mixing.

Direction. A linearised backward-Euler step from zero velocity solves (M + (h beta + h^2) K) dv = h f; with
dx = h dv that is (M / h^2 + (1 + beta / h) K) dx = f: for a step h much longer than the model's slowest
period the Newton step K dx = f, regularised by M / h^2 (Levenberg-Marquardt), with the terms' positive
semi-definite stiffness K. It is solved by block-Jacobi PCG as an inexact Newton step: relative tolerance
eta_k = 0.9 (|f_k| / |f_k-1|)^2 (Eisenstat & Walker, "Choosing the forcing terms in an inexact Newton
method", SIAM J. Sci. Comput. 17(1), 1996, choice 2, with their safeguard), capped at 0.1, and stopped
at the absolute residual 0.1 tol g min(m) (2-norm over free particles: enough for the stopping test on
the lightest particle), so the last solves do not reduce the linear residual further than the stopping
test needs, nor iterate on a right-hand side at round-off.

Globalisation (when every force has a potential at v = 0: springs, membrane, bending, gravity, anchor springs,
uniform wind, a user's term of energy_kind "potential"; not aerodynamics). E(x) = the sum of the terms'
`static_potential`s (terms/base.py): their energies, - sum m g.x, - sum k w.x (wind). A step is accepted when
it satisfies Armijo's condition E(x + a dx) <= E(x) - 1e-4 a f.dx, halving a from 1 (Nocedal & Wright,
"Numerical Optimization", 2nd ed. 2006, alg. 3.1); a change of E within round-off of its parts also passes
(near the solution E no longer resolves progress). h is the Levenberg-Marquardt parameter: doubled (up to
h_max) after a full step, multiplied by a after a step cut to a. Without a potential (aerodynamics) the step
is cut until the norm of the free forces decreases instead, with the same h rule: a heuristic only (the
implicit system holds no aerodynamic Jacobian, and a sheet in wind may have no static state).
line_search=False takes every step whole at the given h.

Acceleration. Where a term projects its Hessian (springs' and the membrane's compression clamps, the
Gauss-Newton bending Hessian), Newton converges only linearly: a hanging cloth's compressed top edge or
folds leave a few modes the linearisation misjudges. Anderson acceleration (Walker & Ni, "Anderson
acceleration for fixed-point iterations", SIAM J. Numer. Anal. 49(4), 2011, type II, depth 3) of the
map x -> x + dx mixes the last steps to cancel those modes; its candidate replaces the Newton step when it
has the lower energy and satisfies Armijo's condition, otherwise the history is dropped. The history is
also dropped whenever h changes (the map changes with it).

Measured (f64, up to 200 iterations, tol 1e-6; benchmarks/results/cloth_continuum.md, section 4), the
previous version (full steps at h = 100 s, PCG to 1e-8) against this one: a 17 x 17 spring cloth
(ClothMaterial defaults) falling from flat and hanging from two corners of one edge, 200 iterations
ending at residual 5e-3 after 58,800 PCG iterations against converged in 118 and 7,700; the same as a
17 x 17 fabric, converged in 141 iterations (after passing through residuals of 1e9) and 30,400 PCG
iterations against 59 and 4,400; a 32-cell fabric sheet hanging from two clips, started flat, 109 and
47,000 against 44 and 7,200 (the line search without Anderson acceleration: 84 and 15,900); a nearly
linear cantilever, 4 and 5 Newton iterations, 14,500 PCG iterations against 10,800 (inexact Newton).
A plane-stress problem (a sheet hanging in its own plane) converges quadratically in 4 to 6
iterations. Pinned particles stay where they are.

The integrator and scratch fields are kept per model (weakly), so repeated solves of one model compile
nothing; the Newton systems are assembled on those scratch fields, never on the state's, whose kernels
would compile again for every new State.
"""

import math

import numpy as np
import taichi as ti

from . import validate
from .errors import DivergenceError
from .integrators import IntegratorImplicitEuler
from .runtime import np_float

G = 9.81  # [m/s^2] the weight that scales the stopping test
ARMIJO = 1e-4
ETA_MAX = 0.1  # loosest PCG relative tolerance (inexact Newton)
ETA_FLOOR = 0.1  # ... and the fraction of the stopping test the linear residual must reach
ANDERSON_DEPTH = 3
MIN_STEP = 1.0 / 2**14  # shortest line-search step before a step is taken anyway
STALL = 20  # stop when this many iterations lowered neither the best residual nor the energy


def _solver(model):
    """(integrator, x, v, x out, v out fields) reused by every solve of `model` (kernels compile once per
    model, not per call), kept on the model: dropped with it."""
    got = getattr(model, "_static_solver", None)
    if got is None:
        integ = IntegratorImplicitEuler(
            linear_solver="pcg", tol=ETA_MAX, max_iterations=20_000, warm_start=False
        )
        integ.bind(model)
        rows = model.particle_capacity  # the particle count, or its bucket (capacity.py)
        got = (integ, *(ti.Vector.field(3, float, rows) for _ in range(4)))
        model._static_solver = got  # on the model: a module-level map's value kept its key alive
    return got


def _potential(model, x0):
    """E(x) -> (energy [J], round-off scale [J]) of every force at zero velocity (each term's
    static_potential: elastic energies, -sum m g.x, -sum k w.x of uniform wind, a user's potential), or
    None if one has no potential (a source such as aerodynamics) at the start positions x0 (N,3) [m]."""
    m = model.particle_masses()
    # Element terms first, then pointwise ones: the order in which their parts are summed.
    terms = list(model.element_terms) + list(model.point_terms)
    if any(t.static_potential(x0, m) is None for t in terms):
        return None

    def energy(x):
        parts = [float(t.static_potential(x, m)) for t in terms]
        return sum(parts), sum(abs(p) for p in parts)

    return energy


def solve_static(
    model,
    state,
    *,
    tol: float = 1e-6,
    max_iterations: int = 200,
    h: float = 100.0,
    h_max: float = 1e4,
    linear_tol: float | None = None,
    line_search: bool = True,
    anderson: bool = True,
) -> dict:
    """Move `state` to static equilibrium in place; velocities end at 0.

    tol: stop when the largest force on a free particle is below tol * m g (its weight, g = 9.81);
    h [s]: the first regularising step (longer is closer to pure Newton), adapted between h_max [s] and
    1e-6 s by the line search; linear_tol: a fixed PCG relative tolerance instead of the inexact-Newton
    forcing terms; line_search=False and anderson=False give plain regularised Newton at a fixed h (the
    method before the line search, for comparison). Returns {"iterations", "residual" (the largest free
    force over m g), "linear_iterations", "energy" (J, None without a potential), "h" (the last),
    "backtracks" (steps cut by the line search), "accelerated" (Anderson steps taken), "converged"
    (residual <= tol), "history" (the residual before each iteration)}. It stops at tol, at max_iterations,
    when the Newton step is exactly 0 (the forces are below the linear solver's floor), or when STALL (20)
    iterations lowered neither the best residual nor the energy beyond round-off (the residual's floor at
    this precision; not with line_search=False); then "converged" is False.
    Raises DivergenceError if the iteration produces non-finite positions.
    """
    tol = validate.positive("tol", tol)
    max_iterations = validate.count("max_iterations", max_iterations, 1)
    h = validate.positive("h", h)
    h_max = max(validate.positive("h_max", h_max), h)
    if linear_tol is not None:
        linear_tol = validate.positive("linear_tol", linear_tol)
    integ, xf, vf, xo, vo = _solver(model)
    n = model.particle_count
    masses = model.particle_masses()
    free = masses > 0.0
    weight = np.maximum(masses, 1e-300) * G
    mass_norm = float(np.linalg.norm(masses[free]))
    mass_min = float(masses[free].min()) if free.any() else 0.0
    x = state.positions()
    energy = _potential(model, x) if line_search else None
    roundoff = 1e3 * float(np.finfo(np_float()).eps)  # relative noise of an energy sum
    zero = np.zeros((n, 3))
    zero_f = zero.astype(np_float())
    e0, scale0 = energy(x) if energy else (None, None)
    eta = ETA_MAX
    f_norm_prev = None
    linear = backtracks = accelerated = 0
    hist_x: list = []
    hist_r: list = []
    hist_h = None
    residual = best = math.inf
    k = best_k = 0
    best_e = e0
    history: list[float] = []
    for k in range(max_iterations + 1):
        if not np.all(np.isfinite(x)):
            raise DivergenceError(f"solve_static: non-finite positions after {k} Newton iterations")
        f = model.forces(x, zero, state.time)
        f[~free] = 0.0
        residual = float(np.max(np.linalg.norm(f[free], axis=1) / weight[free])) if free.any() else 0.0
        history.append(residual)
        if residual < best:
            best, best_k, best_e = residual, k, e0
        # Stalled: no better residual in STALL iterations, and the energy changed only by round-off
        # (not with line_search=False: the method before the line search ran to max_iterations).
        stalled = (
            line_search and k - best_k >= STALL and (e0 is None or abs(e0 - best_e) <= roundoff * scale0)
        )
        if residual <= tol or k == max_iterations or stalled:
            break
        f_norm = float(np.linalg.norm(f))
        if linear_tol is not None:
            eta = linear_tol
        elif f_norm_prev is not None:
            new = 0.9 * (f_norm / f_norm_prev) ** 2
            if 0.9 * eta * eta > 0.1:  # Eisenstat-Walker safeguard against a sudden decrease
                new = max(new, 0.9 * eta * eta)
            eta = min(max(new, ETA_FLOOR * tol * G * mass_min / max(f_norm, 1e-300)), ETA_MAX)
        f_norm_prev = f_norm
        # [N] a linear residual (2-norm) small enough for the stopping test on the lightest particle; with a
        # fixed linear_tol, the integrator's own floor
        floor = ETA_FLOOR * tol * G * mass_min if linear_tol is None else linear_tol * G * mass_norm
        dx = _newton_step(model, state, integ, xf, vf, xo, vo, x, zero_f, h, eta, floor)
        if integ.last_solve is not None:
            linear += integ.last_solve.iterations
        if not np.any(dx):  # the force is below what the linear floor resolves: nothing left to do
            break
        if energy is None:
            a = 1.0
            if line_search:  # no potential: cut the step until the force norm decreases
                while a > MIN_STEP:
                    trial = model.forces(x + a * dx, zero, state.time)
                    trial[~free] = 0.0
                    if np.linalg.norm(trial) <= (1.0 - ARMIJO * a) * f_norm:
                        break
                    a *= 0.5
                backtracks += a < 1.0
                h = min(2.0 * h, h_max) if a == 1.0 else max(h * a, 1e-6)
            x = x + a * dx
            continue

        slope = float(np.sum(f * dx))  # -dE/da at a = 0

        def acceptable(e, scale, a, e0=e0, scale0=scale0, slope=slope):
            """Armijo's condition, or a change of E within round-off of its parts."""
            return e <= e0 - ARMIJO * a * slope or abs(e - e0) <= roundoff * max(scale, scale0)

        e_full, s_full = energy(x + dx)
        step = None
        if anderson:
            if hist_h != h:
                hist_x, hist_r = [], []
            hist_x = [*hist_x[-ANDERSON_DEPTH:], x]
            hist_r = [*hist_r[-ANDERSON_DEPTH:], dx]
            hist_h = h
            if len(hist_x) > 1:
                dX = np.stack([(b - a).ravel() for a, b in zip(hist_x, hist_x[1:], strict=False)], 1)
                dR = np.stack([(b - a).ravel() for a, b in zip(hist_r, hist_r[1:], strict=False)], 1)
                gamma = np.linalg.lstsq(dR, dx.ravel(), rcond=None)[0]
                x_aa = x + dx - ((dX + dR) @ gamma).reshape(x.shape)
                e_aa, s_aa = energy(x_aa)
                if e_aa <= e_full and acceptable(e_aa, s_aa, 1.0):
                    step = (x_aa, e_aa, s_aa)
                    accelerated += 1
                else:
                    hist_x, hist_r = hist_x[-1:], hist_r[-1:]
        a = 1.0
        if step is None:
            e1, s1 = e_full, s_full
            while not acceptable(e1, s1, a) and a > MIN_STEP:
                a *= 0.5
                e1, s1 = energy(x + a * dx)
            step = (x + a * dx, e1, s1)
            backtracks += a < 1.0
        x, e0, scale0 = step
        h = min(2.0 * h, h_max) if a == 1.0 else max(h * a, 1e-6)
    state.particle_x.from_numpy(model.padded(x))
    state.particle_v.from_numpy(model.padded(zero))
    return {
        "iterations": k,
        "converged": residual <= tol,
        "residual": residual,
        "linear_iterations": linear,
        "energy": e0,
        "h": h,
        "backtracks": backtracks,
        "accelerated": accelerated,
        "history": history,
    }


def _newton_step(model, state, integ, xf, vf, xo, vo, x, zero_f, h, eta, floor) -> np.ndarray:
    """dx of one regularised Newton step at positions x (N,3): (M / h^2 + (1 + beta / h) K) dx = f, by
    PCG to the relative tolerance eta or the absolute residual `floor` [N] (the system's right-hand side
    is h f: its floor is h floor), so a right-hand side at round-off does not iterate to the cap."""
    n = model.particle_count
    xf.from_numpy(model.padded(x))
    vf.from_numpy(model.padded(zero_f))
    if integ.system is None:  # pointwise forces only: the integrator's 3x3 solves per particle
        integ.advance(model, state, xf, vf, xo, vo, state.time, state.time, h, state.step_count + 1, False)
        return xo.to_numpy()[:n].astype(np.float64) - x
    integ.linear_solver.tol = eta
    integ._assemble(model, integ.system, xf, vf, state.time, h, False)
    integ.last_solve = integ.linear_solver.solve(integ.system, atol=h * floor)
    return h * integ.system.solution.to_numpy()[:n].astype(np.float64)
