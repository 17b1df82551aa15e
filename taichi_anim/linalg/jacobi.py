"""Block Jacobi iteration x <- x + D^-1 (b - A x), D the 3x3 diagonal blocks of A (Saad, "Iterative
Methods for Sparse Linear Systems", 2nd ed., sec. 4.1, eq. 4.4, in block form).

Point Jacobi (scalar diagonal) need not converge here: the 3x3 blocks of a spring's n n^T couple the
components. Block Jacobi converges whenever 2D - A is positive definite, which holds for the implicit
cloth matrix: it is the mass plus springs acting on p_i + p_j. Pinned rows are filtered (held at 0).
An iteration is two parallel loops: the residual with its norm, then the stopping test and the update.
"""

import taichi as ti

from ..runtime import data_oriented
from .base import LinearSolver

START, R0, R1 = 0, 3, 4


@data_oriented
class LinearSolverJacobi(LinearSolver):
    """Block Jacobi; stops when |b - A x| <= tol |b| or after max_iterations."""

    name = "jacobi"

    def _allocate(self, rows: int, make) -> None:
        self.r = make(self, "jacobi_r", float, rows, (3,))

    @ti.kernel
    def _start(self, system: ti.template(), warm: ti.template()):
        x = ti.static(system.solution)
        self.reset()
        ti.loop_config(serialize=self.serial_blocks)
        for t in range(self.blocks() * self.spread):  # see LinearSolver.bind
            if t % self.spread == 0:
                blk = t // self.spread
                s = ti.Vector.zero(float, 3)
                for i in range(blk * self.block, self.row_end(blk)):
                    if ti.static(not warm):
                        x[i] = ti.Vector.zero(float, 3)
                    b = system.rhs[i]
                    s[0] += b.dot(b)
                self.store(START, blk, s)

    # An iteration's two passes (LinearSolver._iterate), per block of rows; k is the iteration's index
    # within the launch (base is even, so its parity picks the slots).
    @ti.func
    def _residual(self, system: ti.template(), blk, k):
        x = ti.static(system.solution)
        s = ti.Vector.zero(float, 3)
        for i in range(blk * self.block, self.row_end(blk)):
            r = system.rhs[i] - system.apply(i, x)
            self.r[i] = r
            s[0] += r.dot(r)
        self.store(R0 + k % 2, blk, s)
        self.clear(R1 - k % 2, blk)

    @ti.func
    def _update(self, system: ti.template(), blk, k, base, tol, floor, cap):
        x = ti.static(system.solution)
        bb = self.total(START)[0]
        rr = self.total(R0 + k % 2)[0]
        stop = self.converged(rr, bb, tol, floor) or base + k >= cap
        if not self.finish(blk, base + k, rr, bb, stop):
            for i in range(blk * self.block, self.row_end(blk)):
                x[i] += system.precondition(i, self.r[i])

    passes = 2

    @ti.func
    def _pass(self, p: ti.template(), system: ti.template(), blk, k, base, tol, floor, cap):
        if ti.static(p == 0):
            self._residual(system, blk, k)
        else:
            self._update(system, blk, k, base, tol, floor, cap)
