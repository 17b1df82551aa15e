"""A frame of coupled particles in one parallel launch (integrators/parallel_frame.py): the same bits as
one launch per substep (the same arithmetic per element and per particle, whoever runs it), on one
thread as on two (a thread alone runs every chunk, nothing waits for a thread that never starts), the
same divergence stop, and the mode chosen where it applies."""

import numpy as np
import pytest

import taichi_anim as ta
import taichi_anim.stepper as stepper_module
from taichi_anim import DivergenceError

from .helpers import ulp_tolerance

# Big enough that both threads run chunks of one pass at once: at 24^2 frames without the barrier's wait
# still matched (the second thread joined too late to race); at 64^2 a wait one pass short failed the
# comparison in 4 runs of 4.
N = 64


def _cloth(n: int, *, fabric: bool, stiffness: float = 1e3, colliders: bool = True):
    b = ta.Builder()
    material = (
        ta.FabricMaterial() if fabric
        else ta.ClothMaterial(density=0.2, stretch_stiffness=stiffness, shear_stiffness=stiffness,
                              bend_stiffness=stiffness)
    )  # fmt: skip
    cloth = b.add_cloth_grid(origin=(-0.5, 1.0, -0.5), size=(1.0, 1.0), resolution=(n, n), plane="xz",
                             pinned=[0, n - 1], material=material)  # fmt: skip
    if fabric:  # a force that depends on time: the frame's substep times are t0 + k h in the kernel
        b.add_force_aerodynamics(cloth, wind=(2.0, 0.0, 0.0), gust_amplitude=0.5, gust_frequency=50.0)
    b.add_force_gravity()
    b.add_force_drag(1e-4)
    if colliders:
        b.add_collider_plane(normal=(0.0, 1.0, 0.0), offset=0.3, friction=0.2)
        b.add_collider_sphere((0.1, 0.5, 0.0), 0.25, friction=0.3)
    return b.finalize()


def _frames(mode: str, n: int, frames: int, substeps: int, h: float, **cloth):
    model = _cloth(n, **cloth)
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler", check_every=substeps).stepper_for(model)
    stepper._frame_mode = {"mode": mode, "reason": "test"}
    for _ in range(frames):
        stepper.advance(state, h, substeps)
    return state


@pytest.mark.parametrize("fabric", [False, True], ids=["springs", "membrane+bending"])
def test_parallel_frame_equals_a_launch_per_substep_on_any_thread_count(fabric):
    """Springs (Springs.evaluate_range) or a StVK membrane with dihedral bending and gusting wind
    (ElementTerm's; the wind depends on time), drag, a plane and a sphere with friction: 4 frames of 16
    substeps equal one launch per substep to the roundings of 64 steps (kernels compiled apart, which
    LLVM may contract differently: at 24^2 the springs gave the same bits, the membrane 1 ulp in 2 of
    1,728 coordinates), and the parallel frame on one thread (which then runs every chunk itself) gives
    the bits it gives on two."""
    runs = {}
    for threads in (2, 1):
        ta.init("cpu", precision="f32", cpu_threads=threads)
        h = 5e-5 if not fabric else 2.5e-5
        runs[threads] = _frames("parallel_frame", N, 4, 16, h, fabric=fabric)
        x, v = (getattr(runs[threads], name).to_numpy() for name in ("particle_x", "particle_v"))
        runs[threads] = (x, v, runs[threads].step_count, runs[threads].time)
        if threads == 2:
            want = _frames("launches", N, 4, 16, h, fabric=fabric)
            start = _cloth(N, fabric=fabric).state().positions()
            wx, wv = want.particle_x.to_numpy(), want.particle_v.to_numpy()
            for got, ref in ((x, wx), (v, wv)):
                np.testing.assert_allclose(got, ref, rtol=0, atol=ulp_tolerance(np.abs(ref).max(), 64 * 64))
            assert runs[threads][2] == want.step_count == 64 and runs[threads][3] == want.time
            # Not a trivial comparison: the sheet moved, and not as one rigid fall (pins and forces acted).
            fall = 0.5 * 9.81 * (64 * h) ** 2
            assert np.abs(wx[: len(start)] - start).max() > 0.5 * fall and np.ptp(wv[:, 1]) > 1e-3
    for k in range(2):
        np.testing.assert_array_equal(runs[1][k], runs[2][k])


def test_parallel_frame_stops_at_the_step_that_diverged():
    """k = 1e6 N/m at h = 2e-3 s is far beyond symplectic Euler's limit: the parallel frame raises the same
    DivergenceError (step, particle, quantity) as one launch per substep."""
    errors = []
    for mode in ("launches", "parallel_frame"):
        with pytest.raises(DivergenceError) as info:
            _frames(mode, 12, 2, 8, 2e-3, fabric=False, stiffness=1e6, colliders=False)
        errors.append(info.value)
    assert errors[0].step <= 8 and errors[1].step == errors[0].step
    assert errors[1].particle == errors[0].particle and errors[1].quantity == errors[0].quantity


def test_the_parallel_frame_is_chosen_by_size_threads_and_terms(monkeypatch):
    """From FRAME_PARALLEL_FROM of work on two threads; never on one thread, and never with an element
    term that cannot evaluate a range of its elements."""
    ta.init("cpu", cpu_threads=2)
    big = _cloth(48, fabric=False)
    assert big.work >= stepper_module.FRAME_PARALLEL_FROM
    mode = ta.make_integrator("symplectic_euler").stepper_for(big).frame_mode()
    assert mode["mode"] == "parallel_frame" and str(big.work) in mode["reason"]
    small = _cloth(12, fabric=False)
    assert ta.make_integrator("symplectic_euler").stepper_for(small).frame_mode()["mode"] == "serial_frame"
    monkeypatch.setattr(type(big.element_terms[0]), "splits_evaluation", False)
    assert ta.make_integrator("symplectic_euler").stepper_for(big).frame_mode()["mode"] != "parallel_frame"
    monkeypatch.undo()
    # A term whose evaluate is overridden below the class that gives evaluate_range: not split.
    fabric = _cloth(48, fabric=True)
    assert ta.make_integrator("symplectic_euler").stepper_for(fabric).frame_mode()["mode"] == "parallel_frame"
    term = fabric.element_terms[0]
    monkeypatch.setattr(term, "__class__", type("Custom", (type(term),), {"evaluate": type(term).evaluate}))
    assert ta.make_integrator("symplectic_euler").stepper_for(fabric).frame_mode()["mode"] != "parallel_frame"
    monkeypatch.undo()
    ta.init("cpu", cpu_threads=1)
    one = _cloth(48, fabric=False)
    assert ta.make_integrator("symplectic_euler").stepper_for(one).frame_mode()["mode"] != "parallel_frame"
