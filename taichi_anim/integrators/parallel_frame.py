"""A frame of substeps of coupled particles (springs, cloth) in one parallel launch on the CPU, with the
threads kept running between the substeps' passes and waiting for each other at barriers.

Why: a substep of a cloth needs two passes, the elements' forces and then the particles' update (each
particle gathers the forces of its elements), and each pass was a parallel loop. On the 2-core Xeon a
parallel loop costs about 70-90 us to start (Taichi's thread pool wakes its second thread each time),
while a 64 x 64 cloth's substep is about 180 us of work: the wake-ups bounded the frame. Here one launch
starts the threads once per frame, and the passes are separated by a barrier of two atomics
(3.7 against 89 us a pass on a 2,048-float stencil trial).

How (workers.py): the launch's loop has one task per worker. Each pass of the frame (substep k's
elements: pass 2k; its particles: 2k + 1) is cut into `chunks` ranges; a worker claims the next chunk
from one counter over the whole frame, waits until every chunk of the passes before it is done (a second
counter), runs it and counts it done. Claims follow the pass order, so nothing waits for a chunk nobody
runs: one thread alone (or a second one that starts late) runs every chunk itself. No result depends on
who ran which chunk, so a frame gives the same bits on any number of threads. Each chunk runs the same
functions per element and per particle as the one-launch-per-substep path (`final_particle`, and
`evaluate_range`, the per-element form of `evaluate`), whose frames it equals to round-off
(tests/test_parallel_frame.py: kernels compiled apart may contract differently)."""

import taichi as ti

from .. import workers
from ..runtime import compile_with, data_oriented
from .base import Integrator


def parallel_frame_applies(model, method) -> bool:
    """Whether frames of `method` on `model` can run here: on the CPU with at least two threads and two
    cores to run them, a method whose substep is the default force pass and update
    (Integrator.final_pass), and element terms that evaluate a range of their elements
    (`splits_evaluation`)."""
    return (
        workers.available()
        and type(method).final_pass is Integrator.final_pass
        and all(_splits(t) for t in model.element_terms)
    )


def _splits(term) -> bool:
    """Whether `term` evaluates a range of its elements as its `evaluate` does: it says so, and the class
    that gives its `evaluate_range` also gives its `evaluate` (a subclass that overrides `evaluate` alone
    would have its ranges evaluated the old way)."""

    def giver(name):
        return next((c for c in type(term).__mro__ if name in vars(c)), None)

    return bool(getattr(term, "splits_evaluation", False)) and giver("evaluate") is giver("evaluate_range")


@data_oriented
class ParallelFrame:
    """Runs frames of a fusable `method` on `model` (Stepper.frame_mode "parallel_frame")."""

    def __init__(self, model, method):
        self.model = model
        self.method = method
        self.loop_size, self.chunks = workers.loop_size(), workers.chunks()
        self.claimed = model.new_field(self, "parallel_frame_claimed", ti.i32, 1)
        self.done = model.new_field(self, "parallel_frame_done", ti.i32, 1)

    def run(self, state, h: float, count: int, step0: int) -> None:
        """`count` substeps of h [s] from the state's time, numbered from step0 (the caller advances time
        and step count)."""
        self._run(self.model, state, self.method, float(state.time), h, count, step0)

    # Without Taichi's CFG passes, as _final (integrators/base.py), whose per-particle code this inlines.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _run(self, model: ti.template(), state: ti.template(), method: ti.template(), t0: float, h: float,
             count: ti.i32, step0: ti.i32):  # fmt: skip
        x, v = ti.static(state.particle_x, state.particle_v)
        self.claimed[0] = 0
        self.done[0] = 0
        chunks = self.chunks
        for task in range(self.loop_size):
            if workers.is_worker(task):
                last = 2 * count * chunks
                g = workers.claim(self.claimed, 0)
                while g < last:
                    p, c = g // chunks, g % chunks
                    workers.wait_done(self.done, 0, p * chunks)
                    k = p // 2
                    t = t0 + k * h
                    if p % 2 == 0:
                        for e in ti.static(range(len(model.element_terms))):
                            term = model.element_terms[e]
                            n = term.element_count()
                            lo, hi = workers.chunk(c, n, chunks)
                            term.evaluate_range(method.caches[e], x, v, t, lo, hi)
                    else:
                        lo, hi = workers.chunk(c, model.live_particles(), chunks)
                        for i in range(lo, hi):
                            method.final_particle(model, state, x, v, x, v, t, t, h, step0 + k, True, i)
                    workers.finish(self.done, 0)
                    g = workers.claim(self.claimed, 0)
