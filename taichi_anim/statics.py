"""Static equilibrium (prototype under measurement)."""

import math

import numpy as np
import taichi as ti

from . import validate
from .errors import DivergenceError
from .integrators import IntegratorImplicitEuler
from .runtime import np_float
from .terms import AnchorSpring, Drag, Gravity

G = 9.81
GROW = 2.0
SHRINK = 1.0
ETA_SAFE = 0.0


def _potential(model):
    """E(x) [J] of every force at zero velocity, or None when one has no potential."""
    if any(not getattr(t, "has_energy", False) for t in model.element_terms):
        return None
    gravity = []
    anchors = []
    for t in model.point_terms:
        if isinstance(t, Gravity):
            gravity.append(np.asarray(t.g, dtype=np.float64))
        elif isinstance(t, Drag) and not any(t.wind):
            continue  # no force at v = 0
        elif isinstance(t, AnchorSpring):
            anchors.append((t.anchor.to_numpy().astype(np.float64), t.params.to_numpy().astype(np.float64)))
        else:
            return None
    m = model.particle_masses()
    g = sum(gravity, np.zeros(3))

    def energy(x):
        e = sum(model.energy(x).values()) - float(np.sum(m * (x @ g)))
        for a, p in anchors:
            stretch = np.linalg.norm(x - a, axis=1) - p[:, 1]
            e += 0.5 * float(np.sum(p[:, 0] * stretch**2))
        return e

    return energy


def solve_static(
    model,
    state,
    *,
    tol: float = 1e-6,
    max_iterations: int = 200,
    h: float = 100.0,
    linear_tol: float | None = None,
    line_search: bool = True,
    adapt: bool = True,
    h_max: float = 1e4,
    verbose: bool = False,
) -> dict:
    tol = validate.positive("tol", tol)
    max_iterations = validate.count("max_iterations", max_iterations, 1)
    h = validate.positive("h", h)
    integ = IntegratorImplicitEuler(
        linear_solver="pcg", tol=linear_tol or 0.1, max_iterations=20_000, warm_start=False
    )
    integ.bind(model)
    n = model.particle_count
    xo = ti.Vector.field(3, float, n)
    vo = ti.Vector.field(3, float, n)
    masses = model.particle_masses()
    free = masses > 0.0
    weight = np.maximum(masses, 1e-300) * G
    energy = _potential(model) if line_search else None
    linear = 0
    residual = math.inf
    zero = np.zeros((n, 3))
    state.particle_v.from_numpy(zero.astype(np_float()))
    x = state.particle_x.to_numpy().astype(np.float64)
    e0 = energy(x) if energy else None
    fnorm_prev = None
    mnorm = float(np.linalg.norm(masses[free]))
    eta = 0.1
    history = []
    for k in range(max_iterations + 1):
        if not np.all(np.isfinite(x)):
            raise DivergenceError(f"solve_static: non-finite positions after {k} Newton iterations")
        f = model.forces(x, zero, state.time)
        f[~free] = 0.0
        residual = float(np.max(np.linalg.norm(f[free], axis=1) / weight[free])) if free.any() else 0.0
        fnorm = float(np.linalg.norm(f))
        if verbose:
            print(k, f"res {residual:.3e} h {h:.3g} E {e0} eta {eta:.2e} lin {linear}")
        if residual <= tol or k == max_iterations:
            break
        if linear_tol is None:
            if fnorm_prev is not None:
                eta_new = 0.9 * (fnorm / fnorm_prev) ** 2
                if 0.9 * eta * eta > 0.1:
                    eta_new = max(eta_new, 0.9 * eta * eta)
                floor = ETA_SAFE * tol * G * mnorm / max(fnorm, 1e-300)
                eta = min(max(eta_new, floor, 1e-10), 0.1)
            integ.linear_solver.tol = eta
        fnorm_prev = fnorm
        state.particle_x.from_numpy(x.astype(np_float()))
        xf, vf = state.particle_x, state.particle_v
        if integ.system is not None:
            integ._assemble(model, integ.system, xf, vf, state.time, h)
            res = integ.linear_solver.solve(integ.system, atol=0.0)
            linear += res.iterations
            dx = h * integ.system.solution.to_numpy().astype(np.float64)
        else:
            integ.advance(
                model, state, xf, vf, xo, vo, state.time, state.time, h, state.step_count + 1, False
            )
            dx = xo.to_numpy().astype(np.float64) - x
        alpha = 1.0
        if energy is not None:
            slope = float(np.sum(f * dx))  # -dE/dalpha at 0
            while True:
                e1 = energy(x + alpha * dx)
                if e1 <= e0 - 1e-4 * alpha * slope or abs(e1 - e0) <= 1e-13 * abs(e0) + 1e-300:
                    break
                if alpha < 1e-4:
                    break
                alpha *= 0.5
            e0 = e1
            if adapt:
                if alpha == 1.0:
                    h = min(h * GROW, h_max)
                else:
                    h = max(h * alpha**SHRINK, 1e-6)
        history.append(alpha)
        x = x + alpha * dx
    state.particle_x.from_numpy(x.astype(np_float()))
    state.particle_v.from_numpy(zero.astype(np_float()))
    return {"iterations": k, "residual": residual, "linear_iterations": linear, "h": h, "alphas": history}
