"""Cloth on CUDA, run by hand on a GPU machine (figures in results/cloth_gpu.md): implicit steps/s and
PCG iterations at 64^2..256^2 (Warp-layout scene, k = 1e4, dt = 1/60), and symplectic ms/frame on Warp's
k = 1e3 scene (16 substeps), after warm-up."""

import time

import numpy as np
import taichi as ti

import taichi_anim as ta

ta.init("cuda")


def scene(n, k, damping=10.0):
    b = ta.Builder()
    mat = ta.ClothMaterial(
        density=10.0,
        stretch_stiffness=k,
        shear_stiffness=k,
        bend_stiffness=k,
        stretch_damping=damping,
        shear_damping=damping,
        bend_damping=damping,
    )
    b.add_cloth_grid(size=(0.1 * (n - 1),) * 2, resolution=(n, n), material=mat, pinned=[0, n - 1])
    b.add_force_gravity()
    m = b.finalize()
    return m, m.state()


for n in (64, 128, 256):
    for tol in (1e-3, 1e-4):
        m, s = scene(n, 1e4)
        integ = ta.IntegratorImplicitEuler(linear_solver="pcg", tol=tol, max_iterations=1000)
        integ.step(m, s, 1 / 60)
        integ.step(m, s, 1 / 60)
        ti.sync()
        its = []
        t0 = time.perf_counter()
        for _ in range(60):
            integ.step(m, s, 1 / 60)
            its.append(integ.last_solve.iterations)
        ti.sync()
        t = time.perf_counter() - t0
        print(
            f"cuda implicit pcg n={n} tol={tol:g}: {60 / t:.1f} steps/s, iterations mean {np.mean(its):.1f} "
            f"max {max(its)}, last residual {integ.last_solve.residual:.1e}",
            flush=True,
        )
    m, s = scene(n, 1e3)
    integ = ta.make_integrator("symplectic_euler", check_every=16)
    for _ in range(32):
        integ.step(m, s, 1 / 960)
    s.particle_x.to_numpy()
    t0 = time.perf_counter()
    for _ in range(30):
        for _ in range(16):
            integ.step(m, s, 1 / 960)
        s.particle_x.to_numpy()
    print(
        f"cuda symplectic n={n}: {(time.perf_counter() - t0) / 30 * 1e3:.2f} ms/frame (16 substeps)",
        flush=True,
    )
