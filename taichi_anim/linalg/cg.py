"""Conjugate gradient, optionally preconditioned (Shewchuk, "An Introduction to the Conjugate Gradient
Method Without the Agonizing Pain", 1994, sec. B2/B3), with constraint filtering for pinned rows: the
system returns 0 for a filtered row of A p and of the preconditioner, so p, r and x stay 0 there (Baraff
& Witkin 1998, sec. 5.3, "modified PCG" with S = 0 on pinned particles). The preconditioner is the
inverse of A's 3x3 diagonal blocks (block Jacobi); plain CG uses the identity on free rows.

An iteration is three parallel loops (q = A p with p.q; x, r, z updates with r.r and r.z; p = z + beta p)
and `check_every` iterations run per launch (base.py: no serial tasks). The stopping test |r| <= tol |b|
or |r| <= atol (or the iteration cap) is made at the start of an iteration.
"""

import taichi as ti

from ..runtime import data_oriented
from .base import LinearSolver

START, PQ0, PQ1, R0, R1 = range(5)  # R slots hold (r.r, r.z, -); the START slot (b.b, r.r, r.z)


@data_oriented
class LinearSolverCG(LinearSolver):
    """CG (preconditioned=False) or PCG with the block-Jacobi preconditioner (preconditioned=True)."""

    def __init__(self, *, preconditioned: bool = True, **options):
        super().__init__(**options)
        self.preconditioned = bool(preconditioned)
        self.name = "pcg" if preconditioned else "cg"

    def _allocate(self, rows: int, make) -> None:
        self.r, self.z, self.p, self.q = (make(self, f"cg_{v}", float, rows, (3,)) for v in "rzpq")

    @ti.func
    def _z(self, system: ti.template(), i, r):
        z = r
        if ti.static(self.preconditioned):
            z = system.precondition(i, r)
        else:
            z = system.filter(i, r)
        return z

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
                    b = system.rhs[i]
                    r = b
                    if ti.static(warm):
                        r = b - system.apply(i, x)
                    else:
                        x[i] = ti.Vector.zero(float, 3)
                    z = self._z(system, i, r)
                    self.r[i] = r
                    self.z[i] = z
                    self.p[i] = z
                    s += ti.Vector([b.dot(b), r.dot(r), r.dot(z)])
                self.store(START, blk, s)
                # The residual of "iteration -1" for the first stopping test and beta.
                self.store(R1, blk, ti.Vector([s[1], s[2], 0.0]))

    # An iteration's three passes (LinearSolver._iterate), per block of rows; k is the iteration's index
    # within the launch (base is even, so its parity picks the slots).
    @ti.func
    def _product(self, system: ti.template(), blk, k, base, tol, floor, cap):
        pq_slot, r_new, r_old = PQ0 + k % 2, R0 + k % 2, R1 - k % 2
        bb = self.total(START)[0]
        rr = self.total(r_old)[0]
        stop = self.converged(rr, bb, tol, floor) or base + k >= cap
        if not self.finish(blk, base + k, rr, bb, stop):
            self.clear(r_new, blk)
            s = ti.Vector.zero(float, 3)
            for i in range(blk * self.block, self.row_end(blk)):
                q = system.apply(i, self.p)
                self.q[i] = q
                s[0] += self.p[i].dot(q)
            self.store(pq_slot, blk, s)

    @ti.func
    def _update(self, system: ti.template(), blk, k):
        pq_slot, r_new, r_old = PQ0 + k % 2, R0 + k % 2, R1 - k % 2
        x = ti.static(system.solution)
        pq = self.total(pq_slot)[0]
        alpha = 0.0
        if pq > 0.0:  # p = 0 only when the residual is 0 on the free rows
            alpha = self.total(r_old)[1] / pq
        s = ti.Vector.zero(float, 3)
        for i in range(blk * self.block, self.row_end(blk)):
            x[i] += alpha * self.p[i]
            r = self.r[i] - alpha * self.q[i]
            z = self._z(system, i, r)
            self.r[i] = r
            self.z[i] = z
            s += ti.Vector([r.dot(r), r.dot(z), 0.0])
        self.store(r_new, blk, s)
        self.clear(PQ1 - k % 2, blk)

    @ti.func
    def _direction(self, blk, k):
        r_new, r_old = R0 + k % 2, R1 - k % 2
        rz_old = self.total(r_old)[1]
        beta = self.total(r_new)[1] / ti.max(rz_old, 1e-30)
        for i in range(blk * self.block, self.row_end(blk)):
            self.p[i] = self.z[i] + beta * self.p[i]

    passes = 3

    @ti.func
    def _pass(self, p: ti.template(), system: ti.template(), blk, k, base, tol, floor, cap):
        if ti.static(p == 0):
            self._product(system, blk, k, base, tol, floor, cap)
        elif ti.static(p == 1):
            self._update(system, blk, k)
        else:
            self._direction(blk, k)
