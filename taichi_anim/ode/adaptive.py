"""Step size control of the adaptive methods, shared by the NumPy and the Taichi path.

rk45 (Dormand–Prince 5(4); Hairer, Nørsett & Wanner I, sec. II.4, eqs. 4.10-4.13): err = max_i
|h sum (b - b*) k|_i / (atol + rtol max(|u0|_i, |u1|_i)); accept if err <= 1; the next step is
h clip(0.9 err^(-1/5), 0.2, 5).
adaptive (step doubling; Press et al., "Numerical Recipes", 3rd ed., sec. 17.2, and the course's rule):
one step of h and two of h/2 with the base method, err = max_i |difference|_i; above k_max reject and
halve h; at or below k_max accept the two half steps, and double h if err < k_min.
Each system of a batch has its own step size. A step that lands on the end of the interval is clipped
to it, and the step size carried on is at least the unclipped one. A system fails when more than
max_rejected steps in a row are rejected or h falls below h_min (FAIL_STEP_SIZE), or after max_steps
accepted steps in one call (FAIL_MAX_STEPS).
"""

from __future__ import annotations

import numpy as np

SAFETY = 0.9
GROW_RK45 = 5.0
SHRINK_RK45 = 0.2
FAIL_STEP_SIZE = 1
FAIL_MAX_STEPS = 2


def factor_accepted(method: str, err: np.ndarray, grow_below: float) -> np.ndarray:
    """Step size factor after an accepted step (err relative to the tolerance, <= 1)."""
    if method == "rk45":
        with np.errstate(divide="ignore"):
            return np.where(err > 0.0, np.minimum(GROW_RK45, SAFETY * err**-0.2), GROW_RK45)
    return np.where(err < grow_below, 2.0, 1.0)


def factor_rejected(method: str, err: np.ndarray) -> np.ndarray:
    """Step size factor after a rejected step (err > 1, or not finite)."""
    if method == "rk45":
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(err), np.maximum(SHRINK_RK45, SAFETY * err**-0.2), SHRINK_RK45)
    return np.full(err.shape, 0.5)
