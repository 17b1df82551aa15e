"""Static equilibrium: the rest shape of a model under its forces, by Newton's method on the engine's own
implicit system.

A linearised backward-Euler step from zero velocity solves (M + (h beta + h^2) K) dv = h f, x1 = x0 + h dv,
i.e. dx = h^2 (M + h^2 K)^-1 f: for a step h much longer than the model's slowest period this is the
Newton step K dx = f, regularised by M / h^2 (Levenberg-Marquardt style), with the terms' positive
semi-definite stiffness. Repeating it, velocities zeroed each time, converges to f = 0 on the free
particles: quadratically where every linearisation is exact, linearly where a term projects
(compression clamps, the Gauss-Newton bending Hessian). Pinned particles stay where they are."""

import math

import numpy as np

from . import validate
from .errors import DivergenceError
from .integrators import IntegratorImplicitEuler


def solve_static(
    model, state, *, tol: float = 1e-6, max_iterations: int = 200, h: float = 100.0, linear_tol: float = 1e-8
) -> dict:
    """Move `state` to static equilibrium in place; velocities end at 0.

    tol: stop when the largest force on a free particle is below tol * m g (its weight, g = 9.81);
    h [s]: the regularising step (longer is closer to pure Newton); linear_tol: PCG relative tolerance.
    Returns {"iterations", "residual" (the largest free force over m g), "linear_iterations"}.
    Raises DivergenceError if the iteration produces non-finite positions.
    """
    tol = validate.positive("tol", tol)
    max_iterations = validate.count("max_iterations", max_iterations, 1)
    h = validate.positive("h", h)
    integ = IntegratorImplicitEuler(
        linear_solver="pcg", tol=linear_tol, max_iterations=20_000, warm_start=False
    )
    integ.bind(model)
    masses = model.particle_masses()
    free = masses > 0.0
    weight = np.maximum(masses, 1e-300) * 9.81
    linear = 0
    residual = math.inf
    zero = np.zeros((model.particle_count, 3))
    for k in range(max_iterations + 1):
        state.particle_v.from_numpy(zero.astype(state.particle_v.to_numpy().dtype))
        x = state.particle_x.to_numpy().astype(np.float64)
        if not np.all(np.isfinite(x)):
            raise DivergenceError(f"solve_static: non-finite positions after {k} Newton iterations")
        f = model.forces(x, zero, state.time)
        residual = float(np.max(np.linalg.norm(f[free], axis=1) / weight[free])) if free.any() else 0.0
        if residual <= tol or k == max_iterations:
            return {"iterations": k, "residual": residual, "linear_iterations": linear}
        xf, vf = state.particle_x, state.particle_v
        integ.advance(model, state, xf, vf, xf, vf, state.time, state.time, h, state.step_count + 1, True)
        linear += integ.last_solve.iterations
    return {"iterations": max_iterations, "residual": residual, "linear_iterations": linear}
