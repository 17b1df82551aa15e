"""A liquid's whole substep in two launches on the CPU's threads (workers.py), its passes separated by
barriers: before the method moves the particles, the positions' gather, the grid's build, the
neighbourhoods, the divergence solve and the velocities' write-back; after it, XSPH, the density solve
(position-based fluids: their density step, pbf.py) and the last guard: the passes of serial_substep.py,
in the same order, with the same per-slot functions.

Why: a liquid of one to three thousand particles runs its loops serially (below FLUID_SERIAL_BELOW,
dfsph.py), on one core, because a parallel loop costs ~70-90 us to start on the 2-core Xeon and a substep
makes about a dozen. Here the threads start twice a substep. The grid's build (a counting sort whose
passes are short) runs on one worker while the others wait at its barrier. The `dam_break` demo's column
in frames of 1/30 s (benchmarks/fluid_realtime.py's scene, f32), medians of the frames of three
alternating runs each, serial against here: DFSPH 28.0-28.9 against 25.3-26.4 ms at 1,458 particles,
42.1-44.2 against 32.8-41.4 at 2,000, 64.1-67.2 against 47.1-58.9 at 2,662, but 16.5-17.0 against
17.1-18.5 at 1,024; position-based fluids 21.2-22.7 against 16.5-18.7 at 1,024, 35.2-36.3 against
26.2-27.0 at 1,458, 56.6-57.4 against 37.8-48.3 at 2,000, 81.1-86.2 against 63.2-68.1 at 2,662, but
12.2-12.7 against 13.4 at 686 (two runs): each method starts at its WORKER_SUBSTEP_FROM. Its two kernels
compile in about 0.4 s more than the serial ones with an empty cache (2,000 particles' first frame 0.93 ->
1.35 s with DFSPH, 0.90 -> 1.28 s with position-based fluids) and 0.1 s more with a warm one. Larger
liquids keep a parallel loop per pass and their solves on workers: there this launch, compiled without
Taichi's CFG passes, was 5-40 % slower (DFSPH, 4,394 and 6,859 particles), and with them no faster in
three alternating runs while the 2,000 particles' first frame took 2.8 s.

A slot's work does not depend on who runs it, and the errors are summed as fixed-point integers
(pressure.py), so a substep gives the same bits on any number of threads; against the serial or the
launch-per-pass substep the per-slot code is compiled into another kernel, so it agrees to round-off
(tests/test_fluid_workers.py). Without nozzles, bodies or surface tension in the liquid; the others
keep their substeps."""

import taichi as ti

from ... import runtime, workers
from ...runtime import compile_with, data_oriented
from . import worker_solve

# None: a plain liquid (_make_worker_substep) of WORKER_SUBSTEP_FROM to FLUID_SERIAL_BELOW particles where
# workers run (workers.available()); True: any plain liquid, at any thread count (one thread then runs
# every chunk); False: never. Read when the liquid's solver is made; tests compare the paths.
WORKER_SUBSTEP = None
WORKER_SUBSTEP_FROM = {"dfsph": 1200, "pbf": 1000}  # particles, by method (the module docstring)
SUBSTEP_PASSES = 4  # the most passes outside the solve in one launch (their counters are reset per launch)


@data_oriented
class WorkerSubstep:
    """Mixin of FluidDynamics: _begin_by_workers and _end_by_workers."""

    def _make_worker_substep(self) -> None:
        """Whether this liquid's substeps run on workers (the solve's counters are made with the worker
        solve's, _make_worker_solve, and the substep's own with them)."""
        plain = not (self.emitted or self.coupled or self.surface_tension > 0.0)
        # Its solves run on workers: not where they are switched off (WORKER_SOLVE False) or where a
        # launch per pass is asked for (one_launch_solve False; tests compare those paths).
        plain = plain and runtime.backend_name() == "cpu" and self.one_launch_solve
        plain = plain and worker_solve.WORKER_SOLVE is not False
        if WORKER_SUBSTEP is None:
            mid = self.serial and self.model.fluid_capacity >= WORKER_SUBSTEP_FROM[self.method]
            self.worker_substep = plain and mid and workers.available()
        else:
            self.worker_substep = plain and WORKER_SUBSTEP

    def _make_substep_counters(self, make) -> None:
        self.sub_claim = make(self, "fluid_sub_claim", ti.i32, SUBSTEP_PASSES)
        self.sub_done = make(self, "fluid_sub_done", ti.i32, SUBSTEP_PASSES)

    @ti.func
    def _reset_substep(self):
        """Every counter to zero: the solve's and the substep's (a serial loop at a kernel's top level)."""
        self._reset_passes()
        ti.loop_config(serialize=True)
        for q in range(SUBSTEP_PASSES):
            self.sub_claim[q] = 0
            self.sub_done[q] = 0
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.reached_sum[None] = 0

    @ti.func
    def _each(self, q, n, kind: ti.template(), state: ti.template(), model: ti.template(), a, b):
        """Substep pass q over the slots [0, n), chunk by chunk (workers.py); returns when all are done."""
        chunks = self.chunks
        c = workers.claim(self.sub_claim, q)
        while c < chunks:
            lo, hi = workers.chunk(c, n, chunks)
            for k in range(lo, hi):
                if ti.static(kind == 0):
                    self._gather_position_one(state, model, k)
                elif ti.static(kind == 1):
                    self._neighborhood_one(state, model, k)
                elif ti.static(kind == 2):
                    self._write_velocity_one(state, model, k, a)
                elif ti.static(kind == 3):
                    self._copy_velocity_one(state, model, k)
                elif ti.static(kind == 4):  # a: the viscosity, b: h
                    self._xsph_one(k, a)
                    self._wall_push_one(state, k, b)
                else:
                    self._finish_one(state, model, k, a, b)
            workers.finish(self.sub_done, q)
            c = workers.claim(self.sub_claim, q)
        workers.wait_done(self.sub_done, q, chunks)

    @ti.func
    def _once(self, q, count, t):
        """Substep pass q, the grid's build, run by one worker (the first to claim it) while the others
        wait."""
        if workers.claim(self.sub_claim, q) == 0:
            self.grid.build_pass(self.cx, count, None, t, False)
            workers.finish(self.sub_done, q)
        workers.wait_done(self.sub_done, q, 1)

    # Without Taichi's CFG passes, as the workers' solve (its code is inlined here).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _begin_by_workers(
        self,
        state: ti.template(),
        model: ti.template(),
        count: ti.i32,
        t: float,
        h: float,
        above: ti.i64,
        least: ti.i32,
        most: ti.i32,
    ) -> ti.types.vector(3, ti.i64):
        """serial_substep.py's _begin_serially on workers: returns (iterations, the last errors'
        fixed-point sum, live particles)."""
        self._reset_substep()
        n = self._live()
        for task in range(self.worker_items):
            if workers.is_worker(task):
                self._each(0, n, 0, state, model, h, t)
                self._once(1, count, t)
                self._each(2, n, 1, state, model, h, t)
                if ti.static(self.divergence_solve):
                    self._solve_in_worker(task, state, h, 1, n, above, least, most)
                    self._each(3, n, 2, state, model, h, t)
        ti.loop_config(serialize=True)  # after every worker: the neighbourhoods' mean error reached
        for _ in range(1):
            self._reached_mean()
        out = ti.Vector([0, 0, n], dt=ti.i64)  # without a divergence solve (position-based fluids)
        if ti.static(self.divergence_solve):
            self._report_pass()
            out = ti.Vector([self.solve_out[0], self.solve_out[1], n], dt=ti.i64)
        return out

    # Without Taichi's CFG passes, as the last guard it holds (dfsph.py's _finish says why).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _end_by_workers(
        self,
        state: ti.template(),
        model: ti.template(),
        h: float,
        t: float,
        viscosity: float,
        above: ti.i64,
        least: ti.i32,
        most: ti.i32,
    ) -> (ti.types.vector(3, ti.i64), float):
        """serial_substep.py's _end_serially on workers: returns ((iterations, the last errors' fixed-point
        sum, live particles), the largest error)."""
        self._reset_substep()
        n = self._live()
        for task in range(self.worker_items):
            if workers.is_worker(task):
                self._each(0, n, 3, state, model, h, t)
                self._each(1, n, 4, state, model, viscosity, h)
                if ti.static(self.divergence_solve):
                    self._solve_in_worker(task, state, h, 0, n, above, least, most)
                else:  # position-based fluids' density step (pbf.py)
                    self._density_in_worker(task, state, h, 0, n, above, least, most)
                self._each(2, n, 5, state, model, h, t)
        self._report_pass()
        return ti.Vector([self.solve_out[0], self.solve_out[1], n], dt=ti.i64), self.err_max[None]
