"""A large liquid's pressure solves in one launch on the CPU's threads (bodies/fluid/worker_solve.py): the
same iterations every step as a launch per iteration and the same positions to round-off (the passes
are the same per-slot functions, compiled into another kernel), and the same bits on one thread as on
two (a thread alone runs every chunk); for DFSPH and for position-based fluids (pbf.py)."""

import numpy as np
import pytest

import taichi_anim as ta
import taichi_anim.bodies.fluid.worker_solve as worker_solve
from taichi_anim.bodies.fluid.dfsph import FLUID_SERIAL_BELOW


def _collapse(worker: bool, threads: int, method: str, frames: int = 3):
    """A 16^3 block (4,096 particles: its loops run in parallel) collapsing in a box twice its width:
    per-step (substeps, divergence iterations, density iterations), final positions, whether the
    workers solved."""
    ta.init("cpu", precision="f64", cpu_threads=threads)
    worker_solve.WORKER_SOLVE = worker
    try:
        b = ta.Builder()
        b.add_force_gravity()
        b.add_collider_box((0.0, 0.0, 0.0), (0.64, 0.64, 0.32), restitution=0.0)
        b.add_fluid(spacing=0.02, method=method)
        b.add_fluid_block((0.0, 0.0, 0.0), (0.32, 0.32, 0.32))
        model = b.finalize()
        assert model.fluid_count >= FLUID_SERIAL_BELOW
        state = model.state()
        stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
        fluid = next(s for s in stepper.solvers if s.name == "fluid")
        steps = []
        for _ in range(frames):
            stepper.advance(state, 1.0 / 60.0, 1)
            f = fluid.frame_stats()
            steps.append((f["steps"], f["divergence_iterations"], f["density_iterations"]))
        return steps, state.positions(), fluid.workers
    finally:
        worker_solve.WORKER_SOLVE = None


@pytest.mark.parametrize("method", ["dfsph", "pbf"])
def test_worker_solves_match_a_launch_per_iteration_on_any_thread_count(method):
    """DFSPH's divergence and density solves, or position-based fluids' whole density step."""
    launches, x_launches, used = _collapse(False, 2, method)
    assert not used
    two, x_two, used = _collapse(True, 2, method)
    assert used
    one, x_one, _ = _collapse(True, 1, method)
    assert two == launches and one == two
    assert sum(s[2] for s in two) > sum(s[0] for s in two)  # the density solves iterated
    np.testing.assert_array_equal(x_one, x_two)
    assert np.abs(x_two - x_launches).max() < 1e-9  # f64 round-off, amplified over 3 frames of a collapse
    assert np.abs(x_two - _collapse_start()).max() > 0.01  # the block moved


def _collapse_start():
    ta.init("cpu", precision="f64")
    b = ta.Builder()
    b.add_collider_box((0.0, 0.0, 0.0), (0.64, 0.64, 0.32), restitution=0.0)
    b.add_fluid(spacing=0.02)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.32, 0.32, 0.32))
    return b.finalize().state().positions()
