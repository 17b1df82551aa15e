"""The cubic spline smoothing kernel of SPH in 3-D (Monaghan, "Smoothed particle hydrodynamics", Rep.
Prog. Phys. 68, 2005, eq. 2.6; written with the support radius H = 2h as in Koschier et al., "Smoothed
Particle Hydrodynamics Techniques for the Physics Based Simulation of Fluids and Solids", Eurographics
tutorial 2019, eq. 4): with q = r / H and sigma = 8 / (pi H^3),

    W(r) = sigma (6 (q^3 - q^2) + 1)   for q <= 1/2,
           sigma 2 (1 - q)^3           for 1/2 < q <= 1,
           0                           beyond.

It integrates to one over its support. The functions take the support H [m] and return W [1/m^3] and its
gradient with respect to the first point [1/m^4]: grad W = dW/dq (x_i - x_j) / (r H), with
dW/dq = 6 sigma q (3 q - 2) inside q <= 1/2 and -6 sigma (1 - q)^2 beyond."""

import math

import numpy as np
import taichi as ti


@ti.func
def cubic_w(r, support):
    """W(r) [1/m^3] for a distance r [m] and support radius `support` [m]."""
    q = r / support
    sigma = 8.0 / (math.pi * support * support * support)
    w = ti.cast(0.0, float)
    if q <= 0.5:
        w = sigma * (6.0 * (q * q * q - q * q) + 1.0)
    elif q <= 1.0:
        f = 1.0 - q
        w = sigma * 2.0 * f * f * f
    return w


@ti.func
def cubic_w_grad(d, support):
    """(W(|d|) [1/m^3], grad_i W [1/m^4]) for d = x_i - x_j [m], from one square root; the gradient is
    zero at d = 0 and beyond the support."""
    r = d.norm()
    q = r / support
    sigma = 8.0 / (math.pi * support * support * support)
    w = ti.cast(0.0, float)
    g = ti.Vector.zero(float, 3)
    if q <= 1.0:
        scale = 6.0 * sigma / support  # 48 / (pi H^4)
        dq = d / (r * support) if r > 1.0e-9 * support else ti.Vector.zero(float, 3)
        if q <= 0.5:
            w = sigma * (6.0 * (q * q * q - q * q) + 1.0)
            g = scale * support * q * (3.0 * q - 2.0) * dq
        else:
            f = 1.0 - q
            w = sigma * 2.0 * f * f * f
            g = -scale * support * f * f * dq
    return w, g


def cubic_w_numpy(r, support: float):
    """W(r) [1/m^3] in NumPy, for setting up (masses of a lattice, boundary volumes) and for tests."""
    q = np.asarray(r, dtype=np.float64) / support
    sigma = 8.0 / (math.pi * support**3)
    inner = sigma * (6.0 * (q**3 - q**2) + 1.0)
    outer = sigma * 2.0 * np.clip(1.0 - q, 0.0, None) ** 3
    return np.where(q <= 0.5, inner, np.where(q <= 1.0, outer, 0.0))


def lattice_sum(spacing: float, support: float, dims: int = 3) -> float:
    """sum_j W(|x_i - x_j|) [1/m^3] over a cubic lattice of `spacing` [m] around a point of it (dims=2:
    over the square lattice of its plane only). The particle mass that gives an interior lattice
    particle exactly the rest density is rho0 / lattice_sum(d, H)."""
    n = int(math.ceil(support / spacing))
    k = np.arange(-n, n + 1) * spacing
    axes = [k] * dims + [np.zeros(1)] * (3 - dims)
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return float(cubic_w_numpy(np.linalg.norm(g, axis=1), support).sum())
