"""Surface tension of the liquid (Akinci, Akinci & Teschner, "Versatile Surface Tension and Adhesion for
SPH Fluids", SIGGRAPH Asia 2013, sec. 4): a cohesion force between particle pairs and a curvature force
that evens out the surface normals, both symmetric in each pair (momentum is conserved), added to the
velocities before the pressure solve (add_fluid(surface_tension=gamma)).

With H the support radius, n_i = H sum_j (m / rho_j) grad W_ij (eq. 4, the scaled gradient of the
colour field: large at the surface, 0 inside), and K_ij = 2 rho0 / (rho_i + rho_j) (eq. 5):

    F_ij = -gamma K_ij [ m^2 C(|x_ij|) x_ij / |x_ij|  +  m (n_i - n_j) ]                  (eq. 1, 3, 5)

    C(r) = 32 / (pi H^9) * { (H - r)^3 r^3                  for H/2 < r <= H
                           { 2 (H - r)^3 r^3 - H^6 / 64     for 0 < r <= H/2              (eq. 2)

C repels pairs closer than about 0.2 H and attracts the rest, so the cohesion alone holds particles at
about the rest spacing; the curvature term pulls a bulging surface in and does not act on a flat one.
Adhesion to walls (the paper's sec. 5) is left out."""

import math

import taichi as ti


@ti.func
def cohesion(r, support):
    """C(r) of eq. 2 [1/m^3]."""
    h = support
    out = ti.cast(0.0, float)
    if r <= h and r > 0.0:
        a = (h - r) * (h - r) * (h - r) * r * r * r
        if 2.0 * r > h:
            out = a
        else:
            out = 2.0 * a - h**6 / 64.0
        out *= 32.0 / (math.pi * h**9)
    return out


@ti.func
def normals(solver: ti.template()):
    """n_k of eq. 4 for every live slot into solver.normal, from the listed pairs' m grad W_kj."""
    ti.loop_config(serialize=solver.serial)
    for k in range(solver._live()):
        n = ti.Vector.zero(float, 3)
        for m in range(solver.nn[k]):
            n += solver.grad[k, m] / solver.rho[solver.nbr[k, m]]
        solver.normal[k] = solver.support * n


@ti.func
def accelerate(solver: ti.template(), h, gamma):
    """v_k += h sum_j F_kj / m over the listed pairs (positions at the substep's start)."""
    ti.loop_config(serialize=solver.serial)
    for k in range(solver._live()):
        xi, ni, rho = solver.grid.sorted_x[k], solver.normal[k], solver.rho[k]
        a = ti.Vector.zero(float, 3)
        for m in range(solver.nn[k]):
            j = solver.nbr[k, m]
            d = xi - solver.grid.sorted_x[j]
            r = d.norm()
            pull = solver.mass * cohesion(r, solver.support) * d / ti.max(r, 1e-12) + (ni - solver.normal[j])
            a -= (2.0 * solver.rest_density / (rho + solver.rho[j])) * pull
        solver.sv2[k] = solver.sv[k] + (h * gamma) * a
    ti.loop_config(serialize=solver.serial)
    for k in range(solver._live()):
        solver.sv[k] = solver.sv2[k]
