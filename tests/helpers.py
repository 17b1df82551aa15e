"""Small scene builders shared by the tests (public API only)."""

import numpy as np

import taichi_anim as ta


def spring_particle(*, k: float, m: float = 1.0, c: float = 0.0, rest: float = 10.0, x0: float = 10.5):
    """One particle on the x axis tied to the origin by a spring: m x'' = -k (x - L0) - c x'."""
    b = ta.Builder()
    b.add_particle((x0, 0.0, 0.0), (0.0, 0.0, 0.0), mass=m)
    b.add_force_anchor_spring(0, (0.0, 0.0, 0.0), stiffness=k, rest_length=rest, damping=c)
    model = b.finalize()
    return model, model.state()


def run(model, state, integrator, dt: float, steps: int, record=None):
    """Step `steps` times; return (steps+1, N, 3) positions and velocities if `record`."""
    xs, vs = [state.positions()], [state.velocities()]
    for _ in range(steps):
        integrator.step(model, state, dt)
        if record:
            xs.append(state.positions())
            vs.append(state.velocities())
    return np.array(xs), np.array(vs)


def spring_energy(xs, vs, k, m, rest):
    """E = m v^2 / 2 + k (x - L0)^2 / 2 for the particle of `spring_particle`."""
    return 0.5 * m * (vs[:, 0] ** 2).sum(-1) + 0.5 * k * (np.linalg.norm(xs[:, 0], axis=-1) - rest) ** 2


def kernel_eps() -> float:
    """Machine epsilon of the precision the kernels run in (f32 or f64)."""
    from taichi_anim.runtime import np_float

    return float(np.finfo(np_float()).eps)


def ulp_tolerance(scale: float, ulps: int = 64) -> float:
    """An absolute tolerance of `ulps` units in the last place of the kernels' precision at `scale`.

    For comparing two differently compiled kernels that evaluate the same floating-point expression:
    LLVM may fuse multiply-adds, reorder or vectorise them differently in each (1-2 ulp per operation
    on AVX-512 CPUs), so only bitwise comparisons of the same kernel (determinism) are exact. 64 ulp
    covers the tens of roundings of a closest-point or ray-triangle evaluation with a margin."""
    return ulps * kernel_eps() * scale
