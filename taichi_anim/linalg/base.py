"""Shared pieces of the iterative solvers: options, the result record, and reductions without serial
tasks.

Each solver iteration is a few loops over blocks of rows (serial on small CPU systems), and nothing
else: a block writes its partial dot products into a slot, and the next loop's blocks each add up those
partials themselves, in the same fixed order, so every block derives the same scalars (alpha, beta, the
stopping test) without a serial task in between (each costs a kernel launch, tens of microseconds on the
CPU). On the CPU the order of the sums never depends on the thread count, so a solve gives the same bits
with 1 or 2 threads.
On GPUs a block is one row and the partials are added with atomics (fast, not bitwise reproducible);
thread 0 clears a slot one loop before it is reused.
"""

import math
from dataclasses import dataclass
from enum import Enum

import taichi as ti

from .. import validate
from ..capacity import live, plain
from ..runtime import backend_name, compile_with, cpu_threads, data_oriented

CPU_BLOCK = 256  # rows per block on the CPU (fixed, so results do not depend on the thread count)
# Below this many rows the block loops run serially on the CPU: a parallel loop costs ~70-80 us more than
# a serial one here (thread-pool round trip, paid even when the loop is a single task), more than a
# 4096-row loop's work; above it the loops are spread over real tasks (bind). Measured on the scene of
# benchmarks/results/cloth_implicit.md (PCG tol 1e-3): 64^2 94 steps/s serial against 71 spread; 128^2 26.3
# serial against 30.3 spread.
CPU_PARALLEL_ROWS = 8192
TASK_ITEMS = 512  # Taichi's CPU range-for splits a loop into tasks of at least this many iterations
SLOTS = 5  # START (b.b, r.r, r.z of the initial residual) and two parity-alternating pairs per solver


class LinearSolverKind(Enum):
    JACOBI = "jacobi"
    CG = "cg"
    PCG = "pcg"


@dataclass(frozen=True)
class LinearSolveResult:
    """iterations run; residual: final |b - A x| / |b| (2-norms, 0 when b = 0); converged: residual <= tol,
    or |b - A x| <= atol (the absolute floor, for right-hand sides that are round-off); rhs_norm: |b|."""

    iterations: int
    residual: float
    converged: bool
    rhs_norm: float = 0.0


@data_oriented
class LinearSolver:
    """Base: tol (relative residual |b - A x| / |b|), max_iterations, warm_start (start from the last
    solution instead of 0), check_every (iterations per kernel launch between convergence reads; even)."""

    name = "base"

    def __init__(
        self, *, tol: float = 1e-4, max_iterations: int = 200, warm_start: bool = True, check_every: int = 8
    ):
        self.tol = validate.positive("tol", tol)
        self.max_iterations = validate.count("max_iterations", max_iterations, 1)
        self.warm_start = bool(warm_start)
        self.check_every = 2 * ((validate.count("check_every", check_every, 1) + 1) // 2)
        self.size = -1
        self.capacity = None
        self.buckets = False
        self.last = LinearSolveResult(0, 0.0, True)
        self.total_iterations = 0
        self.solves = 0

    def settings(self) -> dict:
        """The solver's settings for run.json."""
        return {
            "linear_solver": self.name,
            "tol": self.tol,
            "max_iterations": self.max_iterations,
            "warm_start": self.warm_start,
            "mean_iterations": self.total_iterations / max(self.solves, 1),
            "last_residual": self.last.residual,
        }

    def solve(self, system, atol: float = 0.0) -> LinearSolveResult:
        """Solve system.apply(x) = system.rhs into system.solution; stops when |r| <= tol |b| or
        |r| <= atol (in b's units), or after max_iterations. Returns iterations and residual."""
        if self.size < 0:
            self.bind(system.size)  # a solver used on its own binds to its first system
        if system.size != self.size:
            raise ValueError(
                f"{self.name}: bound to systems of {self.size} rows, got {system.size}; call bind(n) first"
            )
        self._start(system, self.warm_start)
        base = 0
        floor = float(atol) ** 2
        # Serial systems: the same iterations as one serial loop (`_iterate_serial`: less to compile).
        iterate = self._iterate_serial if self.serial_blocks else self._iterate
        while True:
            iterate(system, self.check_every, base, self.tol, floor, self.max_iterations)
            base += self.check_every
            if self.status[0] > 0:
                break
        return self._record(floor)

    def bind(self, n: int, capacity: int | None = None, new_field=None) -> None:
        """Allocate the solver's vectors for systems of n block rows (before any solve). capacity: the
        rows of the fields under capacity buckets (capacity.py), with new_field the model's allocator:
        the row and block counts are then read at run time and every choice below goes by the capacity,
        so that any n of one bucket runs the same compiled kernels (the same sums in the same order)."""
        if n == self.size and capacity == self.capacity:
            return
        self.size = n
        self.capacity = capacity
        self.buckets = capacity is not None
        rows = capacity if self.buckets else n
        make = new_field if self.buckets else plain
        cpu = backend_name() == "cpu"
        self.block = CPU_BLOCK if cpu else 1
        self.blocked = cpu
        self.block_count = math.ceil(n / self.block)
        blocks = math.ceil(rows / self.block)
        # A loop over blocks runs as `for t in range(block_count * spread)`, block t // spread at every
        # spread-th t: Taichi cuts a CPU loop into tasks of >= TASK_ITEMS iterations, so a loop over a few
        # dozen blocks would be one task on one thread; spreading them makes 2 tasks per thread.
        self.serial_blocks = cpu and rows < CPU_PARALLEL_ROWS
        self.spread = 1
        if cpu and not self.serial_blocks:
            threads = max(1, cpu_threads())
            self.spread = max(1, math.ceil(TASK_ITEMS * 2 * threads / blocks))
        self.partial = make(self, "solver_partial", float, (SLOTS, blocks), (3,)) if cpu else None
        self.sums = make(self, "solver_sums", float, SLOTS, (3,))  # GPU: the slots themselves
        self.status = make(self, "solver_status", ti.i32, 2)  # done flag, iterations
        self.final = make(self, "solver_final", float, 2)  # r.r and b.b when done
        self.live = None  # (rows, blocks) read at run time under buckets
        if self.buckets:
            self.live = make(self, "solver_live", ti.i32, (), (2,))
            self.live[None] = (n, self.block_count)
        self._allocate(rows, make)

    def _allocate(self, rows: int, make) -> None:
        """The solver's vectors of `rows` rows, from make(owner, role, dtype, shape, dims)."""
        raise NotImplementedError

    @ti.func
    def rows(self):
        """Rows of the system: the live count under buckets (a field read), else a constant."""
        return live(self.live, 0, self.size)

    @ti.func
    def blocks(self):
        """Blocks of rows the loops run over (as rows())."""
        return live(self.live, 1, self.block_count)

    def _record(self, floor: float) -> LinearSolveResult:
        it = int(self.status[1])
        rr, bb = float(self.final[0]), float(self.final[1])  # two scalar reads: no parallel copy kernel
        res = math.sqrt(max(rr, 0.0) / bb) if bb > 0 else 0.0
        self.last = LinearSolveResult(it, res, res <= self.tol or rr <= floor, math.sqrt(max(bb, 0.0)))
        self.total_iterations += it
        self.solves += 1
        return self.last

    # ---- the iterations: a solver's iteration is `passes` loops over blocks of rows, block blk of pass p
    # of iteration k (its index within the launch; base is even, so k's parity picks the slots) being
    # `self._pass(p, system, blk, k, base, tol, floor, cap)`.

    passes = 1

    # check_every unrolled iterations, each inlining every term's product: the CFG passes took 24 s of the
    # flag's 38 s cold compile and bought no run time (81 ms/frame either way). For systems whose block
    # loops run in parallel; serial ones take `_iterate_serial`.
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
            for p in ti.static(range(self.passes)):
                ti.loop_config(serialize=self.serial_blocks)
                for t in range(self.blocks() * self.spread):  # see bind
                    if t % self.spread == 0 and self.status[0] == 0:
                        self._pass(p, system, t // self.spread, k, base, tol, floor, cap)

    # The same iterations in the same order, for systems whose block loops run serially (bind: small CPU
    # systems): one serial loop over the iterations instead of unrolled copies, so Taichi's front end and
    # compiler see one iteration instead of check_every (the flag's warm start: 0.9 s of 1.8 s of compiling
    # were the unrolled solver).
    @ti.kernel
    def _iterate_serial(
        self, system: ti.template(), count: ti.i32, base: ti.i32, tol: float, floor: float, cap: ti.i32
    ):
        ti.loop_config(serialize=True)
        for k in range(count):
            for p in ti.static(range(self.passes)):
                for blk in range(self.blocks()):
                    if self.status[0] == 0:
                        self._pass(p, system, blk, k, base, tol, floor, cap)

    # ---- helpers used inside the solvers' kernels (blk: a block index; one row per block on GPUs)

    @ti.func
    def reset(self):
        """Start of a solve (scalar statements first in `_start`): not done, no iterations, sums cleared."""
        self.status[0] = 0
        self.status[1] = 0
        for slot in ti.static(range(SLOTS)):
            self.sums[slot] = ti.Vector.zero(float, 3)

    @ti.func
    def row_end(self, blk):
        """One past the last row of block blk (its first row is blk * block)."""
        return ti.min((blk + 1) * self.block, self.rows())

    @ti.func
    def store(self, slot, blk, s):
        """Add block blk's partial sum s to slot `slot`: kept per block on the CPU (summed later in block
        order), an atomic add on GPUs."""
        if ti.static(self.blocked):
            self.partial[slot, blk] = s
        else:
            ti.atomic_add(self.sums[slot], s)

    @ti.func
    def total(self, slot):
        """The sum in slot `slot`: the per-block partial sums added in block order on the CPU (the same on any
        thread count), the atomic sum on GPUs."""
        acc = ti.Vector.zero(float, 3)
        if ti.static(self.blocked):
            for b in range(self.blocks()):  # inside a parallel loop body: serial, fixed order
                acc += self.partial[slot, b]
        else:
            acc = self.sums[slot]
        return acc

    @ti.func
    def clear(self, slot, blk):
        """Zero a GPU slot (thread 0) a loop before it accumulates again; nothing to do on the CPU."""
        if ti.static(not self.blocked):
            if blk == 0:
                self.sums[slot] = ti.Vector.zero(float, 3)

    @ti.func
    def converged(self, rr, bb, tol, floor):
        """Whether rr <= max(tol^2 bb, floor): the squared residual norm against the squared right-hand side
        norm bb and an absolute floor."""
        return rr <= ti.max(tol * tol * bb, floor)

    @ti.func
    def finish(self, blk, iterations, rr, bb, stop):
        """The stopping test every block evaluates identically; block 0 records the result."""
        if stop and blk == 0:
            self.status[0] = 1
            self.status[1] = iterations
            self.final[0] = rr
            self.final[1] = bb
        return stop
