"""The linear system of one linearised backward-Euler step with coupled forces (Baraff & Witkin,
"Large Steps in Cloth Simulation", 1998, eq. 6 and 15):
    A dv = b,   A = M - h df/dv - h^2 df/dx,   b = h (f0 + h df/dx v0)
A is applied matrix-free: (A p)_i = D_i p_i + sum_s S_s (p_i - p_j), where D_i = m_i I - h K_v - h^2 K_x
holds the pointwise terms' 3x3 Jacobians and S_s = -(h df/dv + h^2 df/dx) of spring s
(forces/springs.py), positive semi-definite after the compression clamp, so A is symmetric positive
definite for m > 0. Pinned particles (inverse mass 0) are filtered: their rows of A p, b and of the
preconditioner are 0, so dv stays 0 there and they keep their prescribed velocity.
"""

import numpy as np
import taichi as ti

from ..runtime import data_oriented, np_float


@data_oriented
class ImplicitSystem:
    """Fields: rhs b (N,3), solution dv (N,3), block D_i (N,3,3), inverse diagonal blocks (N,3,3)."""

    def __init__(self, model):
        n = model.particle_count
        self.model = model
        self.size = n
        model.springs.ensure_implicit()
        # Without pointwise Jacobians (gravity only) D_i = m_i I: no 3x3 block to store or read.
        self.pointwise = any(getattr(t, "has_jacobian", True) for t in model.terms)
        self.mass_norm = float(np.linalg.norm(model.particle_masses()))  # the solvers' absolute floor
        self.rhs = ti.Vector.field(3, float, n)
        self.solution = ti.Vector.field(3, float, n)
        self.block = ti.Matrix.field(3, 3, float, n) if self.pointwise else None
        self.inv_block = ti.Matrix.field(3, 3, float, n)

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
        return self.filter(i, d + self.model.springs.apply(i, pf))

    @ti.func
    def precondition(self, i, r):
        """Row i of the block-Jacobi preconditioner times r (0 on pinned rows)."""
        return self.inv_block[i] @ r

    @ti.func
    def spring_pass(self, xf: ti.template(), vf: ti.template(), h):
        """Evaluate every spring's force and blocks (a top-level loop: first in the kernel)."""
        self.model.springs.evaluate_implicit(xf, vf, h, self.model.serial)

    @ti.func
    def assemble_row(self, i, xf: ti.template(), vf: ti.template(), t, h):
        """After spring_pass: fill b_i, D_i and the inverse diagonal block of row i."""
        x = xf[i]
        v = vf[i]
        f, kxv, spring_diag = self.model.springs.assemble(i)
        fp = self.model.force(i, x, v, t)
        kx, kv = self.model.force_jacobian(i, x, v, t)
        d = self.model.mass(i) * ti.Matrix.identity(float, 3) - h * kv - h * h * kx
        b = h * (f + fp + h * (kxv + kx @ v))
        inv = ti.Matrix.zero(float, 3, 3)
        if self.free(i):
            inv = (d + spring_diag).inverse()
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
        xf.from_numpy(np.asarray(x, dtype=np_float()))
        vf.from_numpy(np.asarray(v, dtype=np_float()))
        self._assemble_all(xf, vf, t, h)

    def matvec(self, p) -> np.ndarray:
        """A p for p (N,3), rows of pinned particles 0."""
        pf, qf = self._scratch()
        pf.from_numpy(np.asarray(p, dtype=np_float()))
        self._matvec(pf, qf)
        return qf.to_numpy().astype(np.float64)

    def _scratch(self):
        # Allocated once: new fields would be new template arguments, and a recompile per call.
        if not hasattr(self, "_fields"):
            self._fields = (ti.Vector.field(3, float, self.size), ti.Vector.field(3, float, self.size))
        return self._fields

    @ti.kernel
    def _assemble_all(self, xf: ti.template(), vf: ti.template(), t: float, h: float):
        self.spring_pass(xf, vf, h)
        for i in range(self.size):
            self.assemble_row(i, xf, vf, t, h)

    @ti.kernel
    def _matvec(self, pf: ti.template(), qf: ti.template()):
        for i in range(self.size):
            qf[i] = self.apply(i, pf)
