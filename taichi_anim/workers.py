"""Passes in one parallel CPU launch whose threads wait for each other between passes, instead of a
parallel loop per pass (integrators/parallel_frame.py, bodies/fluid/worker_solve.py).

On the 2-core Xeon a parallel loop costs about 70-90 us to start (Taichi's thread pool wakes its second
thread for each), more than a pass of a small or medium scene takes. A launch whose loop has one task per
thread starts the threads once: Taichi 1.7's CPU loops hand out blocks of at least TASK_ITEMS iterations
(its adaptive block size), so a loop of threads x TASK_ITEMS iterations is one task per thread, and only
the first iteration of each block works (`is_worker`). Each pass is cut into chunks that the workers
claim from a counter (`claim`); a worker that finds none left waits until the pass's done counter says
every chunk is finished (`wait_done`). A worker only ever waits for chunks that a running worker has
claimed, so a thread alone (or a second one that starts late) runs every chunk itself: nothing
deadlocks, and results that do not depend on who ran a chunk are the same on any number of threads.

The counters' atomics are sequentially consistent read-modify-writes: a chunk's writes are visible to a
worker that has seen it counted done, and the wait's read is not hoisted out of its loop (a plain read
would be: `atomic_max` with -1 reads without changing the count)."""

import os

import taichi as ti

from . import runtime

TASK_ITEMS = 512  # iterations per task of a Taichi 1.7 CPU loop of known size (its adaptive block)
# Chunks per pass and worker: more than one, so a worker that is late to start or slowed by another process
# on its core leaves work that the others take. Warp's cloth (integrators/parallel_frame.py) at 32^2 /
# 64^2 / 128^2 on the 2-core Xeon, ms a frame, two runs: 1 chunk 0.92, 0.64 / 3.31, 1.87 / 7.08, 7.25;
# 2: 0.88, 0.93 / 2.24, 1.83 / 6.73, 6.69; 4: 0.75, 0.61 / 1.77, 2.14 / 6.51, 6.65; 8: 0.88, 0.72 / 2.74,
# 2.57 / 6.89, 6.75 (this VM's second core comes and goes: the spread within a setting is as large as
# between them).
CHUNKS_PER_WORKER = 4


def usable_cores() -> int:
    """CPUs this process may run on: two threads sharing one core would wait out each other's time slices
    at every barrier."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def available() -> bool:
    """Whether workers run here: the CPU backend with at least two threads and two cores for them."""
    return runtime.backend_name() == "cpu" and runtime.cpu_threads() >= 2 and usable_cores() >= 2


def count() -> int:
    """Workers a launch runs: one per thread, but no more than the cores (a worker spinning at a barrier
    on a core shared with another would wait out its time slice)."""
    return max(1, min(runtime.cpu_threads(), usable_cores()))


def chunks() -> int:
    """Chunks each pass is cut into."""
    return CHUNKS_PER_WORKER * count()


def loop_size() -> int:
    """Iterations of the launch's top-level loop: one task per worker (is_worker picks their first)."""
    return count() * TASK_ITEMS


@ti.func
def is_worker(task):
    """Whether iteration `task` of the loop of loop_size() iterations is a worker (a task's first)."""
    return task % TASK_ITEMS == 0


@ti.func
def chunk(c, n, chunks):
    """(lo, hi): chunk c of `chunks` over [0, n), in 64 bits (c n passes 2^31 from ~17 million items on
    32 cores)."""
    lo = ti.cast(ti.cast(c, ti.i64) * n // chunks, ti.i32)
    hi = ti.cast(ti.cast(c + 1, ti.i64) * n // chunks, ti.i32)
    return lo, hi


@ti.func
def claim(counter: ti.template(), q):
    """The next chunk of pass q (chunks claimed beyond the pass's count mean: none left)."""
    return ti.atomic_add(counter[q], 1)


@ti.func
def finish(done: ti.template(), q):
    """Count a chunk of pass q done (after its writes)."""
    ti.atomic_add(done[q], 1)


@ti.func
def wait_done(done: ti.template(), q, chunks):
    """Wait until `chunks` chunks of pass q are done."""
    while ti.atomic_max(done[q], -1) < chunks:
        pass
