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

from ..runtime import compile_with, data_oriented
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

    # Each iteration's three loops, per block of rows, for the two forms of `_iterate` below. k is the
    # iteration's index within the launch (base is even, so its parity picks the slots).
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

    # check_every unrolled iterations, each inlining every term's product: the CFG passes took 24 s of
    # the flag's 38 s cold compile and bought no run time (81 ms/frame either way). Used where the block
    # loops run in parallel; serial systems take `_iterate_serial`.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _iterate(
        self,
        system: ti.template(),
        unroll: ti.template(),
        base: ti.i32,
        tol: float,
        floor: float,
        cap: ti.i32,
    ):
        for k in ti.static(range(unroll)):
            ti.loop_config(serialize=self.serial_blocks)
            for t in range(self.blocks() * self.spread):  # see LinearSolver.bind
                if t % self.spread == 0 and self.status[0] == 0:
                    self._product(system, t // self.spread, k, base, tol, floor, cap)
            ti.loop_config(serialize=self.serial_blocks)
            for t in range(self.blocks() * self.spread):
                if t % self.spread == 0 and self.status[0] == 0:
                    self._update(system, t // self.spread, k)
            ti.loop_config(serialize=self.serial_blocks)
            for t in range(self.blocks() * self.spread):
                if t % self.spread == 0 and self.status[0] == 0:
                    self._direction(t // self.spread, k)

    # The same iterations as `_iterate` in the same order, for systems whose block loops run serially
    # (LinearSolver.bind: small CPU systems): one serial loop over the iterations instead of unrolled
    # copies, so Taichi's front end builds one iteration instead of check_every (the flag's warm start:
    # 0.9 s of 1.8 s compiling were this kernel).
    @ti.kernel
    def _iterate_serial(
        self, system: ti.template(), count: ti.i32, base: ti.i32, tol: float, floor: float, cap: ti.i32
    ):
        ti.loop_config(serialize=True)
        for k in range(count):
            for blk in range(self.blocks()):
                if self.status[0] == 0:
                    self._product(system, blk, k, base, tol, floor, cap)
            for blk in range(self.blocks()):
                if self.status[0] == 0:
                    self._update(system, blk, k)
            for blk in range(self.blocks()):
                if self.status[0] == 0:
                    self._direction(blk, k)
