"""A large liquid's pressure solves in one launch on the CPU's threads (bodies/fluid/worker_solve.py): the
same iterations every step as a launch per iteration and the same positions to round-off (the passes
are the same per-slot functions, compiled into another kernel), and the same bits on one thread as on
two (a thread alone runs every chunk); for DFSPH and for position-based fluids (pbf.py). A mid-sized
liquid's whole substep on them (worker_substep.py) likewise against its serial substep, for both."""

import numpy as np
import pytest

import taichi_anim as ta
import taichi_anim.bodies.fluid.worker_solve as worker_solve
import taichi_anim.bodies.fluid.worker_substep as worker_substep
from taichi_anim import workers
from taichi_anim.bodies.fluid.dfsph import FLUID_SERIAL_BELOW


def _collapse(worker: bool, threads: int, method: str, frames: int = 3, width: float = 0.32, substep=False):
    """A block 16 particles high and `width` wide and deep (0.32: 4,096 particles, whose loops run in
    parallel) collapsing in a box twice its width: per frame (substeps, divergence iterations, density
    iterations), then the run's fluid.stats(); final positions; (whether the workers solved, the
    substep's path in run.json's fluid settings). `substep` sets worker_substep.WORKER_SUBSTEP."""
    ta.init("cpu", precision="f64", cpu_threads=threads)
    worker_solve.WORKER_SOLVE = worker
    worker_substep.WORKER_SUBSTEP = substep
    try:
        b = ta.Builder()
        b.add_force_gravity()
        b.add_collider_box((0.0, 0.0, 0.0), (2 * width, 0.64, width), restitution=0.0)
        b.add_fluid(spacing=0.02, method=method)
        b.add_fluid_block((0.0, 0.0, 0.0), (width, 0.32, width))
        model = b.finalize()
        assert (model.fluid_count >= FLUID_SERIAL_BELOW) == (width == 0.32)
        state = model.state()
        stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
        fluid = next(s for s in stepper.solvers if s.name == "fluid")
        steps = []
        for _ in range(frames):
            stepper.advance(state, 1.0 / 60.0, 1)
            f = fluid.frame_stats()
            steps.append((f["steps"], f["divergence_iterations"], f["density_iterations"]))
        steps.append(fluid.stats())  # the run's totals and the density errors reached, last
        return steps, state.positions(), (fluid.workers, fluid.settings()["substep"])
    finally:
        worker_solve.WORKER_SOLVE = None
        worker_substep.WORKER_SUBSTEP = None


@pytest.mark.parametrize("method", ["dfsph", "pbf"])
def test_worker_solves_match_a_launch_per_iteration_on_any_thread_count(method):
    """DFSPH's divergence and density solves, or position-based fluids' whole density step."""
    launches, x_launches, (used, _) = _collapse(False, 2, method)
    assert not used
    two, x_two, (used, _) = _collapse(True, 2, method)
    assert used
    one, x_one, _ = _collapse(True, 1, method)
    assert two[:-1] == launches[:-1] and one == two
    assert sum(s[2] for s in two[:-1]) > sum(s[0] for s in two[:-1])  # the density solves iterated
    np.testing.assert_array_equal(x_one, x_two)
    assert np.abs(x_two - x_launches).max() < 1e-9  # f64 round-off, amplified over 3 frames of a collapse
    assert np.abs(x_two - _collapse_start()).max() > 0.01  # the block moved


@pytest.mark.parametrize("method", ["dfsph", "pbf"])
def test_worker_substep_matches_the_serial_substep_on_any_thread_count(method):
    """1,600 particles (loops serial): the same iterations every step, the same errors reached and the
    same positions (to round-off) as the serial substep in two launches, and the same bits on one thread
    as on two."""
    serial, x_serial, (_, kind) = _collapse(None, 2, method, width=0.2, substep=False)
    assert kind == "serial"
    two, x_two, (_, kind) = _collapse(None, 2, method, width=0.2, substep=None)
    assert (kind == "workers") == workers.available()  # the default for 1,600 particles, on 2 cores
    if kind != "workers":  # one core: forced, so that the comparison below is still made
        two, x_two, (_, kind) = _collapse(None, 2, method, width=0.2, substep=True)
    one, x_one, (_, kind_one) = _collapse(None, 1, method, width=0.2, substep=True)
    assert kind == kind_one == "workers"
    assert two[:-1] == serial[:-1] and one == two  # every frame's iterations; the run's totals, bitwise
    for key, value in serial[-1].items():  # the errors reached, to round-off
        assert two[-1][key] == pytest.approx(value, rel=1e-9, abs=1e-15), key
    assert sum(s[2] for s in two[:-1]) > sum(s[0] for s in two[:-1])  # the density solves iterated
    np.testing.assert_array_equal(x_one, x_two)
    assert np.abs(x_two - x_serial).max() < 1e-9


def _collapse_start():
    ta.init("cpu", precision="f64")
    b = ta.Builder()
    b.add_collider_box((0.0, 0.0, 0.0), (0.64, 0.64, 0.32), restitution=0.0)
    b.add_fluid(spacing=0.02)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.32, 0.32, 0.32))
    return b.finalize().state().positions()
