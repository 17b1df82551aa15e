"""A large liquid's pressure solve in one launch on the CPU's threads (workers.py): the warm start, then
each iteration's correction and prediction as passes of that launch, the threads meeting at a barrier
between passes, instead of a launch per iteration with three or two parallel loops in each (pressure.py,
_solve). On the 2-core Xeon each parallel loop costs about 70-90 us to start, and a 6,859-particle dam
break's step made about 12 of them in its two solves.

The passes are pressure.py's per-slot functions (_warm_one, _correct_one, _predict_one) over chunks of
the slots; a prediction's errors are summed per chunk as the same 2^-40 fixed-point integers, whose sum
does not depend on the order: every stop decision, and every bit, is the same on any number of threads.
Against a launch per iteration the per-slot code is compiled apart, so it agrees to round-off (the same
iterations in the tests, unless round-off moves a sum across the threshold).
After each prediction every worker reads the finished sum and decides alike whether to iterate on (the
test of pressure.py's _solve_pass, against first_sum_above's threshold). Each pass has its own claim,
done, sum and largest-error counters, so none is reset while a late worker may still read it.
Position-based fluids (pbf.py) run their density step on the same passes, with their own per-slot work
(`_slot`) and kernel (`_density_by_workers`)."""

import taichi as ti

from ... import runtime, workers
from ...runtime import compile_with, data_oriented
from .pressure import ERROR_SCALE, WARM_DIVERGENCE

# None: a liquid whose loops run in parallel solves by workers where they run (workers.available());
# True: on the CPU at any thread count (one thread then runs every chunk); False: never (a launch per
# iteration; nor a substep on workers, worker_substep.py). Read when the liquid's solver is made; tests
# compare the paths.
WORKER_SOLVE = None


@data_oriented
class WorkerSolve:
    """Mixin of FluidDynamics: _solve_by_workers."""

    def _make_worker_solve(self, make) -> None:
        """Counters for the solve's passes: the warm start, then a correction and a prediction for each of
        at most max_iterations + 1 predictions (position-based fluids: three passes an iteration)."""
        passes = 3 * self.max_iterations + 4  # DFSPH needs 2 a prediction, PBF 3 (pbf.py)
        on_cpu = runtime.backend_name() == "cpu"
        wanted = workers.available() if WORKER_SOLVE is None else WORKER_SOLVE and on_cpu
        self.workers = not self.serial and wanted and not self.worker_substep
        if not (self.workers or self.worker_substep):  # the substep's solves run on these counters too
            return
        self.worker_items, self.chunks = workers.loop_size(), workers.chunks()
        self.pass_claim = make(self, "fluid_pass_claim", ti.i32, passes)
        self.pass_done = make(self, "fluid_pass_done", ti.i32, passes)
        self.pass_sum = make(self, "fluid_pass_sum", ti.i64, passes)
        self.pass_max = make(self, "fluid_pass_max", float, passes)
        self.solve_out = make(self, "fluid_solve_out", ti.i64, 3)
        if self.worker_substep:
            self._make_substep_counters(make)

    # Without Taichi's CFG passes (its other solve kernels' code, inlined twice more, compiles slowly).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _solve_by_workers(
        self, state: ti.template(), h: float, divergence: ti.i32, above: ti.i64, least: ti.i32, most: ti.i32
    ) -> ti.types.vector(2, ti.i64):
        """The whole solve (pressure.py's _solve_pass, in passes): returns (iterations, the last errors'
        fixed-point sum); err_sum and err_max hold the last prediction's, as after _iterate."""
        self._reset_passes()
        n = self._live()
        for task in range(self.worker_items):
            if workers.is_worker(task):
                self._solve_in_worker(task, state, h, divergence, n, above, least, most)
        self._report_pass()
        return ti.Vector([self.solve_out[0], self.solve_out[1]], dt=ti.i64)

    @ti.func
    def _solve_in_worker(self, task, state: ti.template(), h, divergence, n, above, least, most):
        """One worker's part of the solve, on the passes' counters from 0 (reset before the workers
        start); the first worker writes solve_out (iterations, the last errors' sum, its pass)."""
        self._pass(0, 0, state, h, divergence, n)
        q, it = 1, -1
        apply = WARM_DIVERGENCE > 0.0 or divergence == 0
        while True:
            if apply:
                self._pass(q, 1, state, h, divergence, n)
                q += 1
            self._pass(q, 2, state, h, divergence, n)
            it += 1
            s = self.pass_sum[q]
            if not (it < most and (s >= above or it < least)):
                if task == 0:
                    self.solve_out[0] = it
                    self.solve_out[1] = s
                    self.solve_out[2] = q
                break
            q += 1
            apply = True

    @ti.func
    def _pass(self, q, kind: ti.template(), state: ti.template(), h, divergence, n):
        """Pass q over the slots [0, n), chunk by chunk: `_slot(kind, ...)` for each slot, its errors
        summed into pass_sum[q] and their largest into pass_max[q] where the kind measures errors
        (`error_kinds`); returns when every chunk of the pass is done."""
        chunks = self.chunks
        c = workers.claim(self.pass_claim, q)
        while c < chunks:
            lo, hi = workers.chunk(c, n, chunks)
            if ti.static(kind in self.error_kinds):
                total, worst = ti.cast(0, ti.i64), ti.cast(0.0, float)
                for k in range(lo, hi):
                    e = self._slot(kind, state, k, h, divergence)
                    total += ti.cast(e * ERROR_SCALE + 0.5, ti.i64)
                    worst = ti.max(worst, e)
                ti.atomic_add(self.pass_sum[q], total)
                ti.atomic_max(self.pass_max[q], worst)
            else:
                for k in range(lo, hi):
                    self._slot(kind, state, k, h, divergence)
            workers.finish(self.pass_done, q)
            c = workers.claim(self.pass_claim, q)
        workers.wait_done(self.pass_done, q, chunks)

    error_kinds = (2,)  # the kinds of pass whose slots return an error (summed per pass)

    @ti.func
    def _slot(self, kind: ti.template(), state: ti.template(), k, h, divergence):
        """Slot k's work in a pass of `kind` (0 the warm start, 1 the correction, 2 the prediction);
        returns its error (0 where the kind measures none)."""
        e = ti.cast(0.0, float)
        if ti.static(kind == 0):
            self._warm_one(state, k, h, divergence)
        elif ti.static(kind == 1):
            self._correct_one(k, h)
        else:
            e = self._predict_one(k, h, divergence)
        return e

    @ti.func
    def _reset_passes(self):
        """Every pass's counters to zero (a serial loop: call it at a kernel's top level)."""
        ti.loop_config(serialize=True)
        for q in range(self.pass_claim.shape[0]):
            self.pass_claim[q] = 0
            self.pass_done[q] = 0
            self.pass_sum[q] = 0
            self.pass_max[q] = 0.0

    @ti.func
    def _report_pass(self):
        """err_sum and err_max from the last measured pass (solve_out[2]), as a launch-per-iteration
        solve leaves them (a serial loop: call it at a kernel's top level, after the workers)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            last = ti.cast(self.solve_out[2], ti.i32)
            self.err_sum[None] = self.pass_sum[last]
            self.err_max[None] = self.pass_max[last]
