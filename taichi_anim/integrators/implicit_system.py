"""The linear system of one linearised backward-Euler step with coupled forces (Baraff & Witkin,
"Large Steps in Cloth Simulation", 1998, eq. 6 and 15):
    A dv = b,   A = M - h df/dv - h^2 df/dx,   b = h (f0 + h df/dx v0)
and of a later Newton iteration on backward Euler (implicit_euler.py), linearised at the iterate v_k:
    A d = -g(v_k),   g(v) = M (v - v0) - h f(x0 + h v, v)
A is applied matrix-free: (A p)_i = D_i p_i + sum_s S_s (p_i - p_j), where D_i = m_i I - h K_v - h^2 K_x
holds the pointwise terms' 3x3 Jacobians and each element term adds its S = -(h df/dv + h^2 df/dx)
(terms/base.py), which every term keeps symmetric positive semi-definite (springs by the compression
clamp, the membrane by clamping compressive stress, bending by its Gauss-Newton part), so A is symmetric
positive definite for m > 0. Pinned particles (inverse mass 0) are filtered: their rows of A p, b and of the
preconditioner are 0, so dv stays 0 there and they keep their prescribed velocity.
"""

import numpy as np
import taichi as ti

from ..runtime import data_oriented


@data_oriented
class ImplicitSystem:
    """Fields: rhs b (N,3), solution dv (N,3), block D_i (N,3,3), inverse diagonal blocks (N,3,3)."""

    def __init__(self, model, caches):
        n = model.particle_count
        self.model = model
        self.caches = caches  # the integrator's element caches, holding the linearisation
        self.size = n
        # Under capacity buckets the fields hold particle_capacity rows and loops run to the live count.
        self.capacity = model.particle_capacity if model.size_buckets else None
        # Without pointwise Jacobians (gravity only) D_i = m_i I: no 3x3 block to store or read.
        self.pointwise = any(t.has_jacobian for t in model.point_terms)
        self.mass_norm = float(np.linalg.norm(model.particle_masses()))  # the solvers' absolute floor
        self._fields = None  # (x, v) for NumPy access, n rows: made on first use (tests and reports)
        vec = model.particle_array
        self.rhs = vec(self, "system_rhs", dims=(3,))
        self.solution = vec(self, "system_solution", dims=(3,))
        self.block = vec(self, "system_block", dims=(3, 3)) if self.pointwise else None
        self.inv_block = vec(self, "system_inv_block", dims=(3, 3))

    @ti.func
    def free(self, i):
        return self.model.inv_mass(i) > 0.0

    @ti.func
    def filter(self, i, r):
        out = r
        if not self.free(i):
            out = ti.Vector.zero(float, 3)
        return out

    @ti.func
    def apply(self, i, pf: ti.template()):
        """Row i of A p (0 on pinned rows)."""
        d = self.model.mass(i) * pf[i]
        if ti.static(self.pointwise):
            d = self.block[i] @ pf[i]
        for k in ti.static(range(len(self.model.element_terms))):
            d += self.model.element_terms[k].apply(self.caches[k], i, pf)
        return self.filter(i, d)

    @ti.func
    def precondition(self, i, r):
        """Row i of the block-Jacobi preconditioner times r (0 on pinned rows)."""
        return self.inv_block[i] @ r

    @ti.func
    def linearize(self, xf: ti.template(), vf: ti.template(), t, h):
        """Every element term's forces and blocks (top-level loops: first in the kernel)."""
        for k in ti.static(range(len(self.model.element_terms))):
            self.model.element_terms[k].linearize(self.caches[k], xf, vf, t, h, self.model.serial)

    @ti.func
    def assemble_row(self, i, xf: ti.template(), vf: ti.template(), t, h):
        """After linearize: fill b_i, D_i and the inverse diagonal block of row i."""
        self.row(i, xf, vf, t, h, False, self.solution)

    @ti.func
    def assemble_row_newton(self, i, xf: ti.template(), vf: ti.template(), dvf: ti.template(), t, h):
        """A Newton iteration's row at the iterate v_k = v0 + dv (xf = x0 + h v_k, vf = v_k): the same
        matrix, b_i = -g_i = h f_i(x_k, v_k) - m_i dv_i (the backward-Euler residual, negated)."""
        self.row(i, xf, vf, t, h, True, dvf)

    @ti.func
    def row(self, i, xf: ti.template(), vf: ti.template(), t, h, newton: ti.template(), dvf: ti.template()):
        x = xf[i]
        v = vf[i]
        f = ti.Vector.zero(float, 3)
        kxv = ti.Vector.zero(float, 3)
        element_diag = ti.Matrix.zero(float, 3, 3)
        for k in ti.static(range(len(self.model.element_terms))):
            fk, kxvk, dk = self.model.element_terms[k].gather_linear(self.caches[k], i)
            f += fk
            kxv += kxvk
            element_diag += dk
        fp = self.model.force(i, x, v, t)
        kx, kv = self.model.force_jacobian(i, x, v, t)
        d = self.model.mass(i) * ti.Matrix.identity(float, 3) - h * kv - h * h * kx
        b = h * (f + fp + h * (kxv + kx @ v))
        if ti.static(newton):
            b = h * (f + fp) - self.model.mass(i) * dvf[i]
        inv = ti.Matrix.zero(float, 3, 3)
        if self.free(i):
            inv = (d + element_diag).inverse()
        else:
            b = ti.Vector.zero(float, 3)
            self.solution[i] = ti.Vector.zero(float, 3)
        self.rhs[i] = b
        if ti.static(self.pointwise):
            self.block[i] = d
        self.inv_block[i] = inv

    # ---- NumPy access, for tests and reports (each call launches a kernel and copies)

    def assemble(self, x, v, h: float, t: float = 0.0) -> None:
        """Build the system at positions x (N,3) [m] and velocities v (N,3) [m/s] for step h [s]."""
        xf, vf = self._scratch()
        xf.from_numpy(self.model.padded(x))
        vf.from_numpy(self.model.padded(v))
        self._assemble_all(xf, vf, t, h)

    def matvec(self, p) -> np.ndarray:
        """A p for p (N,3), rows of pinned particles 0."""
        pf, qf = self._scratch()
        pf.from_numpy(self.model.padded(p))
        self._matvec(pf, qf)
        return qf.to_numpy()[: self.size].astype(np.float64)

    def _scratch(self):
        if self._fields is None:
            self._fields = tuple(ti.Vector.field(3, float, self.model.particle_capacity) for _ in range(2))
        return self._fields

    @ti.kernel
    def _assemble_all(self, xf: ti.template(), vf: ti.template(), t: float, h: float):
        self.linearize(xf, vf, t, h)
        for i in range(self.model.live_particles()):
            self.assemble_row(i, xf, vf, t, h)

    @ti.kernel
    def _matvec(self, pf: ti.template(), qf: ti.template()):
        for i in range(self.model.live_particles()):
            qf[i] = self.apply(i, pf)
