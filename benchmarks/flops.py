"""Arithmetic per element-step and this machine's arithmetic limits, for step_breakdown.py.

The counts are read off the source on the path a step takes when nothing is hit (one flop per add,
multiply, compare, min/max, reciprocal square root); no hardware counter is available on the VM this was
written on (no `cpu` PMU under /sys/bus/event_source/devices), so they are a model, as the byte counts are.

- Particle-step (particles.py's fountain, symplectic Euler, f32): the death test (1); the update
  (integrators/symplectic_euler.py: a = (m g) / m, v += h a, x += h v: 18); the container box in
  projection mode (collision/response.py `_project_light`: the nearest of six walls and the radius, 14);
  the watchdog (watchdog.py `watch_against`: the non-finite sum and its bit test, six bounds, |v|², 18).
- Spring-substep (terms/springs.py `spring_force`: d and dv 6, |d|² 5, the clamp and rsqrt 2, the
  length 1, the damping dot and its scale 6, stretch, damping and force scale 5, the force vector 3) plus
  its two sums into the ends or gathers (6).
- Cloth vertex-substep (the update with gravity 12, the watchdog 18, the force scale by 1/m 3, the
  gravity force 3, the element sum 2).
"""

import time

import numpy as np
import taichi as ti

PARTICLE_STEP = 1 + 18 + 14 + 18
SPRING_SUBSTEP = 6 + 5 + 2 + 1 + 6 + 5 + 3 + 6
CLOTH_VERTEX_SUBSTEP = 12 + 18 + 3 + 3 + 2


def sgemm_peak(n: int = 4096) -> float:
    """Best GFLOP/s of a NumPy float32 matrix product (its BLAS: every core, the widest vector units):
    the arithmetic limit of vector code here."""
    a = np.random.default_rng(0).random((n, n), dtype=np.float32)
    best = 0.0
    for _ in range(4):
        t0 = time.perf_counter()
        a @ a
        best = max(best, 2 * n**3 / (time.perf_counter() - t0) / 1e9)
    return best


def taichi_scalar_peak(iters: int = 2000) -> float:
    """Best GFLOP/s of a Taichi parallel loop of eight independent multiply-add chains per element, in
    the current `ti.init`: the arithmetic limit of code Taichi does not vectorise."""
    n = 1 << 16
    out = ti.field(ti.f32, n)

    @ti.kernel
    def chains(iters: ti.i32):
        for i in range(n):
            a = ti.Vector([ti.cast(i, ti.f32) * 1e-6 + k for k in ti.static(range(8))])
            for _ in range(iters):
                a = a * 0.999 + 0.001
            out[i] = a.sum()

    chains(10)
    ti.sync()
    best = 0.0
    for _ in range(5):
        t0 = time.perf_counter()
        chains(iters)
        ti.sync()
        best = max(best, n * iters * 8 * 2 / (time.perf_counter() - t0) / 1e9)
    return best


def frame_flops(r: dict, particle_steps: int, cloth_substeps: int) -> tuple[float, str] | None:
    """(flops per frame, flops per element-step as text) of a step_breakdown row, or None (spheres)."""
    if r["scene"] == "particles":
        return r["info"]["alive"] * PARTICLE_STEP * particle_steps, f"{PARTICLE_STEP} per particle-step"
    if r["scene"] == "cloth":
        per = r["elements"] * CLOTH_VERTEX_SUBSTEP + r["info"]["springs"] * SPRING_SUBSTEP
        text = f"{SPRING_SUBSTEP} per spring-substep, {CLOTH_VERTEX_SUBSTEP} per vertex-substep"
        return per * cloth_substeps, text
    return None
