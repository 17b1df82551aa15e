"""One step of each method for a batch of systems with a NumPy F, in float64.

Every step takes (system, t (m,), U (m, dim), h (m,), opts) and returns (U1, err (m,), evals (m,),
newton_iterations (m,), converged (m,) bool). `err` is the adaptive methods' error relative to their
tolerance (accept if <= 1; see adaptive.py), 0 for fixed-step methods.
"""

from __future__ import annotations

import numpy as np

from ..integrators.rk45 import DOPRI5
from ..integrators.runge_kutta import EXPLICIT_EULER, MIDPOINT, RK4
from .adaptive import FAIL_MAX_STEPS, FAIL_STEP_SIZE, factor_accepted, factor_rejected

TABLEAUX = {"explicit_euler": EXPLICIT_EULER, "midpoint": MIDPOINT, "rk4": RK4, "rk45": DOPRI5}
EPS = np.finfo(np.float64).eps


def _runge_kutta(system, tableau, t, u, h):
    """Stages and the weighted sum of an explicit tableau (Hairer, Nørsett & Wanner I, eq. II.1.8)."""
    hc = h[:, None]
    ks = []
    for s, row in enumerate(tableau.a):
        us = u.copy()
        for j, a in enumerate(row):
            if a != 0.0:
                us += hc * a * ks[j]
        ks.append(system.eval_numpy(t + tableau.c[s] * h, us))
    u1 = u + hc * sum(b * k for b, k in zip(tableau.b, ks, strict=True) if b != 0.0)
    return u1, ks


def _ones(m: int, value: int):
    return np.full(m, value, dtype=np.int64)


def step_explicit(system, method, t, u, h, opts):
    tableau = TABLEAUX[method]
    u1, ks = _runge_kutta(system, tableau, t, u, h)
    m = len(u)
    err = np.zeros(m)
    if tableau.b_low is not None:
        # Embedded error, scaled per component (Hairer et al. I, eq. II.4.10-4.11, max norm).
        e = h[:, None] * sum((b - bl) * k for b, bl, k in zip(tableau.b, tableau.b_low, ks, strict=True))
        scale = opts["atol"] + opts["rtol"] * np.maximum(np.abs(u), np.abs(u1))
        err = np.max(np.abs(e) / scale, axis=1)
    return u1, err, _ones(m, len(tableau.b)), _ones(m, 0), np.ones(m, bool)


def step_symplectic(system, method, t, u, h, opts):
    """Symplectic Euler for u = (x, v) split after `system.split` components: kick, then drift."""
    n = system.split
    hc = h[:, None]
    mid = u.copy()
    mid[:, n:] += hc * system.eval_numpy(t, u)[:, n:]
    out = mid.copy()
    out[:, :n] += hc * system.eval_numpy(t, mid)[:, :n]
    m = len(u)
    return out, np.zeros(m), _ones(m, 2), _ones(m, 0), np.ones(m, bool)


def step_doubling(system, method, t, u, h, opts):
    """One step of h and two of h/2 with the base method; err = max |difference| / k_max."""
    base = opts["base"]
    big = STEPS[base](system, base, t, u, h, opts)[0]
    half = STEPS[base](system, base, t, u, 0.5 * h, opts)[0]
    half = STEPS[base](system, base, t + 0.5 * h, half, 0.5 * h, opts)[0]
    err = np.max(np.abs(big - half), axis=1) / opts["k_max"]
    err[~np.isfinite(err)] = np.inf
    m = len(u)
    return half, err, _ones(m, 3 * STAGES[base]), _ones(m, 0), np.ones(m, bool)


def _jacobian_fd(system, t, u, fu):
    """Forward differences dF/du, column j with step sqrt(eps) max(1, |u_j|)."""
    m, n = u.shape
    jac = np.empty((m, n, n))
    for j in range(n):
        e = np.sqrt(EPS) * np.maximum(1.0, np.abs(u[:, j]))
        up = u.copy()
        up[:, j] += e
        jac[:, :, j] = (system.eval_numpy(t, up) - fu) / e[:, None]
    return jac


def step_implicit(system, method, t, u0, h, opts):
    """Backward Euler by Newton's method on g(u) = u - u0 - h F(t + h, u) = 0, from u = u0; a row has
    converged once max |g| <= newton_tol max(|u0|, |u|) (max norms)."""
    m, n = u0.shape
    t1 = t + h
    u = u0.copy()
    evals = np.zeros(m, np.int64)
    iterations = np.zeros(m, np.int64)
    done = np.zeros(m, bool)
    rows = np.arange(m)
    for k in range(opts["newton_iterations"] + 1):
        r = rows[~done]
        if not len(r):
            break
        fu = system.eval_numpy(t1[r], u[r])
        evals[r] += 1
        g = u[r] - u0[r] - h[r, None] * fu
        scale = np.maximum(np.abs(u0[r]).max(axis=1), np.abs(u[r]).max(axis=1))
        ok = np.abs(g).max(axis=1) <= opts["newton_tol"] * scale
        done[r[ok]] = True
        r, g, fu = r[~ok], g[~ok], fu[~ok]
        if k == opts["newton_iterations"] or not len(r):
            break  # at the cap the last iterate's residual is known and the loop ends
        if system.jacobian is None:
            jac = _jacobian_fd(system, t1[r], u[r], fu)
            evals[r] += n
        else:
            jac = system.jacobian_numpy(t1[r], u[r])
        a = np.eye(n) - h[r, None, None] * jac
        u[r] -= np.linalg.solve(a, g[..., None])[..., 0]
        iterations[r] += 1
    return u, np.zeros(m), evals, iterations, done


STEPS = {
    "explicit_euler": step_explicit,
    "midpoint": step_explicit,
    "rk4": step_explicit,
    "rk45": step_explicit,
    "symplectic_euler": step_symplectic,
    "adaptive": step_doubling,
    "implicit_euler": step_implicit,
}
STAGES = {"explicit_euler": 1, "midpoint": 2, "rk4": 4, "rk45": 7, "symplectic_euler": 2}


def advance(system, method, u, hs, ts, stats, ta, tb, n_steps, opts) -> None:
    """Advance the batch `u` (m, dim) in place from ta to tb, as the Taichi kernel does (taichi_path.py):
    fixed-step methods take n_steps equal steps; adaptive ones carry their step size in hs and write the
    time reached to ts. stats (m, 6) accumulates the counters. Overflow is not warned about: a state
    that is not finite at the end raises DivergenceError (solve.py), as on the Taichi path."""
    with np.errstate(over="ignore", invalid="ignore"):
        _advance(system, method, u, hs, ts, stats, ta, tb, n_steps, opts)


def _advance(system, method, u, hs, ts, stats, ta, tb, n_steps, opts) -> None:
    step = STEPS[method]
    m = len(u)
    if method not in ("rk45", "adaptive"):
        h = np.full(m, (tb - ta) / n_steps)
        for k in range(n_steps):
            u[:], _, evals, its, ok = step(system, method, np.full(m, ta + k * h[0]), u, h, opts)
            stats[:, 2] += evals
            stats[:, 3] += its
            stats[:, 4] += ~ok
        stats[:, 0] += n_steps
        return
    ts[:] = ta
    in_row = np.zeros(m, np.int64)
    steps = np.zeros(m, np.int64)
    rows = np.arange(m)
    while True:
        r = rows[(ts < tb) & (stats[:, 5] == 0)]
        if not len(r):
            break
        h = hs[r]
        last = h >= tb - ts[r]
        hh = np.where(last, tb - ts[r], h)
        u1, err, evals, _, _ = step(system, method, ts[r], u[r], hh, opts)
        stats[r, 2] += evals
        acc = err <= 1.0  # NaN compares false: a rejection
        a, x = r[acc], r[~acc]
        u[a] = u1[acc]
        h_new = hh[acc] * factor_accepted(method, err[acc], opts["grow_below"])
        ts[a] = np.where(last[acc], tb, ts[a] + hh[acc])
        hs[a] = np.where(last[acc], np.maximum(h_new, h[acc]), h_new)
        steps[a] += 1
        in_row[a] = 0
        stats[a, 5] = np.where(steps[a] >= opts["max_steps"], FAIL_MAX_STEPS, 0)
        hs[x] = hh[~acc] * factor_rejected(method, err[~acc])
        in_row[x] += 1
        stats[x, 1] += 1
        bad = (in_row[x] > opts["max_rejected"]) | (hs[x] < opts["h_min"])
        stats[x[bad], 5] = FAIL_STEP_SIZE
    stats[:, 0] += steps
