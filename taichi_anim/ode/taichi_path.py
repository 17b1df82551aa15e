"""The Taichi path: one kernel per (system, method) advances a batch of independent systems over an
interval, each thread integrating one system through all its steps (one launch per interval).

The state lives in a ``ti.ndarray`` argument (a NumPy array on the CPU), so a new batch size reuses the
compiled kernel. Floats are Taichi's default float (the precision given to ``taichi_anim.init``).
Adaptive methods carry each system's next step size in `hs` and write the time reached to `ts`.
Per-system counters go to a (batch, 6) int32 array: accepted steps, rejected steps, F evaluations,
Newton iterations, steps whose Newton loop hit its cap, and a failure code (adaptive.py).
"""

import taichi as ti

from ..integrators.rk45 import DOPRI5
from ..integrators.runge_kutta import MIDPOINT, RK4
from .adaptive import FAIL_MAX_STEPS, FAIL_STEP_SIZE, GROW_RK45, SAFETY, SHRINK_RK45

STAGES = {"explicit_euler": 1, "midpoint": 2, "rk4": 4, "rk45": 7, "symplectic_euler": 2}


def _explicit_steps(f, real):
    """Fixed-step explicit methods as @ti.func (t, y, h) -> y1, written out from their tableaux."""
    am, cm = MIDPOINT.a, MIDPOINT.c
    a4, b4, c4 = RK4.a, RK4.b, RK4.c

    @ti.func
    def euler(t, y, h):
        return y + h * f(t, y)

    @ti.func
    def midpoint(t, y, h):
        k1 = f(t, y)
        return y + h * f(t + cm[1] * h, y + am[1][0] * h * k1)

    @ti.func
    def rk4(t, y, h):
        k1 = f(t, y)
        k2 = f(t + c4[1] * h, y + a4[1][0] * h * k1)
        k3 = f(t + c4[2] * h, y + a4[2][1] * h * k2)
        k4 = f(t + c4[3] * h, y + a4[3][2] * h * k3)
        return y + h * (b4[0] * k1 + b4[1] * k2 + b4[2] * k3 + b4[3] * k4)

    return {"explicit_euler": euler, "midpoint": midpoint, "rk4": rk4}


def _dopri5(f, real):
    """Dormand–Prince 5(4): (y1, scaled embedded error), as in numpy_path.step_explicit."""
    a, b, c = DOPRI5.a, DOPRI5.b, DOPRI5.c
    e = tuple(bi - bl for bi, bl in zip(DOPRI5.b, DOPRI5.b_low, strict=True))

    @ti.func
    def step(t, y, h, rtol, atol):
        k1 = f(t, y)
        k2 = f(t + c[1] * h, y + h * (a[1][0] * k1))
        k3 = f(t + c[2] * h, y + h * (a[2][0] * k1 + a[2][1] * k2))
        k4 = f(t + c[3] * h, y + h * (a[3][0] * k1 + a[3][1] * k2 + a[3][2] * k3))
        k5 = f(t + c[4] * h, y + h * (a[4][0] * k1 + a[4][1] * k2 + a[4][2] * k3 + a[4][3] * k4))
        y6 = y + h * (a[5][0] * k1 + a[5][1] * k2 + a[5][2] * k3 + a[5][3] * k4 + a[5][4] * k5)
        k6 = f(t + c[5] * h, y6)
        y1 = y + h * (b[0] * k1 + b[2] * k3 + b[3] * k4 + b[4] * k5 + b[5] * k6)
        k7 = f(t + c[6] * h, y1)
        err = h * (e[0] * k1 + e[2] * k3 + e[3] * k4 + e[4] * k5 + e[5] * k6 + e[6] * k7)
        scale = atol + rtol * ti.max(ti.abs(y), ti.abs(y1))
        return y1, (ti.abs(err) / scale).max()

    return step


def _symplectic(f, n, split, real):
    """Kick v with F_v(t, x0, v0), then drift x with F_x(t, x0, v1): masks select the halves."""
    mask_v = [0.0] * split + [1.0] * (n - split)
    mask_x = [1.0] * split + [0.0] * (n - split)

    @ti.func
    def step(t, y, h):
        mid = y + h * ti.Vector(mask_v, dt=real) * f(t, y)
        return mid + h * ti.Vector(mask_x, dt=real) * f(t, mid)

    return step


def _dense_solve(n):
    """x with A x = b for a small dense A: Gaussian elimination with partial pivoting, unrolled."""

    @ti.func
    def solve(a_in, b_in):
        a = a_in
        b = b_in
        for k in ti.static(range(n)):
            p = k
            best = ti.abs(a[k, k])
            for r in ti.static(range(k + 1, n)):
                if ti.abs(a[r, k]) > best:
                    best = ti.abs(a[r, k])
                    p = r
            for r in ti.static(range(k + 1, n)):
                if p == r:
                    for col in ti.static(range(n)):
                        tmp = a[k, col]
                        a[k, col] = a[r, col]
                        a[r, col] = tmp
                    tb = b[k]
                    b[k] = b[r]
                    b[r] = tb
            for r in ti.static(range(k + 1, n)):
                m = a[r, k] / a[k, k]
                for col in ti.static(range(k, n)):
                    a[r, col] -= m * a[k, col]
                b[r] -= m * b[k]
        x = b
        for k in ti.static(range(n - 1, -1, -1)):
            s = b[k]
            for col in ti.static(range(k + 1, n)):
                s -= a[k, col] * x[col]
            x[k] = s / a[k, k]
        return x

    return solve


def _implicit(system, real):
    """Backward Euler by Newton's method, as numpy_path.step_implicit: (y1, evals, iterations, ok)."""
    f, n, jac = system.f, system.dim, system.jacobian
    solve = _dense_solve(n)
    analytic = jac is not None
    eps = (2.220446049250313e-16 if real == ti.f64 else 1.1920929e-07) ** 0.5  # sqrt(machine epsilon)

    @ti.func
    def jacobian(t, y, fy):
        mat = ti.Matrix.zero(real, n, n)
        if ti.static(analytic):
            mat = jac(t, y)
        else:
            for j in ti.static(range(n)):
                d = eps * ti.max(1.0, ti.abs(y[j]))
                yp = y
                yp[j] += d
                col = (f(t, yp) - fy) / d
                for r in ti.static(range(n)):
                    mat[r, j] = col[r]
        return mat

    @ti.func
    def step(t, y0, h, tol, max_iterations):
        t1 = t + h
        y = y0
        evals = 0
        iterations = 0
        ok = 0
        for k in range(max_iterations + 1):
            fy = f(t1, y)
            evals += 1
            g = y - y0 - h * fy
            if ti.abs(g).max() <= tol * ti.max(ti.abs(y0).max(), ti.abs(y).max()):
                ok = 1
                break
            if k == max_iterations:
                break
            mat = ti.Matrix.identity(real, n) - h * jacobian(t1, y, fy)
            if ti.static(not analytic):
                evals += n
            y -= solve(mat, g)
            iterations += 1
        return y, evals, iterations, ok

    return step


def build_kernel(system, method: str, base: str, real):
    """The advance kernel of `method` for `system` in float type `real` (see the module docstring)."""
    f, n = system.f, system.dim
    real = ti.f64 if real == ti.f64 else ti.f32  # Taichi's own type objects, as kernel annotations need
    vec = ti.types.vector(n, real)
    explicit = _explicit_steps(f, real)
    adaptive = method in ("rk45", "adaptive")
    dopri = implicit = symplectic = None  # Taichi reads every closure cell, used or not
    if method == "rk45":
        dopri = _dopri5(f, real)
    elif method == "implicit_euler":
        implicit = _implicit(system, real)
    elif method == "symplectic_euler":
        symplectic = _symplectic(f, n, system.split, real)
    fixed = explicit.get(base if method == "adaptive" else method)
    stages = 3 * STAGES[base] if method == "adaptive" else STAGES.get(method, 0)

    @ti.func
    def step(t, y, h, rtol, atol, k_max, newton_tol, newton_max):
        """(y1, err, evals, newton iterations, converged) of one step, as numpy_path's steps."""
        y1 = y
        err = ti.cast(0.0, real)
        evals = stages
        its = 0
        ok = 1
        if ti.static(method == "rk45"):
            y1, err = dopri(t, y, h, rtol, atol)
        elif ti.static(method == "adaptive"):
            big = fixed(t, y, h)
            half = fixed(t + 0.5 * h, fixed(t, y, 0.5 * h), 0.5 * h)
            y1 = half
            err = ti.abs(big - half).max() / k_max
        elif ti.static(method == "implicit_euler"):
            y1, evals, its, ok = implicit(t, y, h, newton_tol, newton_max)
        elif ti.static(method == "symplectic_euler"):
            y1 = symplectic(t, y, h)
        else:
            y1 = fixed(t, y, h)
        return y1, err, evals, its, ok

    @ti.kernel
    def advance(
        u: ti.types.ndarray(dtype=vec, ndim=1),
        hs: ti.types.ndarray(dtype=real, ndim=1),
        ts: ti.types.ndarray(dtype=real, ndim=1),
        stats: ti.types.ndarray(dtype=ti.i32, ndim=2),
        ta: real,
        tb: real,
        n_steps: ti.i32,
        rtol: real,
        atol: real,
        k_max: real,
        grow_below: real,
        newton_tol: real,
        newton_max: ti.i32,
        h_min: real,
        max_rejected: ti.i32,
        max_steps: ti.i32,
    ):
        for i in range(u.shape[0]):
            y = u[i]
            steps = 0
            rejected = 0
            evals = 0
            its = 0
            unconverged = 0
            fail = 0
            if ti.static(not adaptive):
                h = (tb - ta) / n_steps
                for k in range(n_steps):
                    y1, err, ev, it, ok = step(ta + k * h, y, h, rtol, atol, k_max, newton_tol, newton_max)
                    y = y1
                    evals += ev
                    its += it
                    unconverged += 1 - ok
                steps = n_steps
            else:
                t = ta
                h = hs[i]
                in_row = 0  # rejections since the last accepted step
                while t < tb and fail == 0:
                    last = h >= tb - t
                    hh = h
                    if last:
                        hh = tb - t
                    y1, err, ev, it, ok = step(t, y, hh, rtol, atol, k_max, newton_tol, newton_max)
                    evals += ev
                    if err <= 1.0:  # NaN compares false: a rejection
                        y = y1
                        steps += 1
                        in_row = 0
                        factor = ti.cast(2.0, real)
                        if ti.static(method == "rk45"):
                            factor = GROW_RK45
                            if err > 0.0:
                                factor = ti.min(GROW_RK45, SAFETY * err ** (-0.2))
                        elif err >= grow_below:
                            factor = 1.0
                        h_new = hh * factor
                        if last:
                            t = tb
                            h_new = ti.max(h_new, h)
                        else:
                            t += hh
                        h = h_new
                        if steps >= max_steps:
                            fail = FAIL_MAX_STEPS
                    else:
                        rejected += 1
                        in_row += 1
                        factor = ti.cast(0.5, real)
                        if ti.static(method == "rk45"):
                            factor = SHRINK_RK45
                            if not (ti.math.isnan(err) or ti.math.isinf(err)):
                                factor = ti.max(SHRINK_RK45, SAFETY * err ** (-0.2))
                        h = hh * factor
                        if in_row > max_rejected or h < h_min:
                            fail = FAIL_STEP_SIZE
                hs[i] = h
                ts[i] = t
            u[i] = y
            stats[i, 0] += steps
            stats[i, 1] += rejected
            stats[i, 2] += evals
            stats[i, 3] += its
            stats[i, 4] += unconverged
            if fail != 0:
                stats[i, 5] = fail

    return advance
