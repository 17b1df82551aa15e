"""A frame of rigid steps in one launch (Stepper mode "solver_frame", RigidDynamics.frame): the same
kernel as step by step, so the same bits; and a contact overflow in the middle of a frame stops it and
is reported like one step's."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.errors import DivergenceError

pytestmark = pytest.mark.usefixtures("size_buckets")  # conftest.py: kernels compiled once

H = 1 / 240
SUBSTEPS = 8


def scene(capacity=None):
    """A keyframed paddle pushing a box along a floor while a tilted box falls, tumbles and lands: time
    inside the frame (the keys), contacts appearing and warm starts carried from step to step."""
    b = ta.Builder()
    b.add_force_gravity((0.0, -9.81, 0.0))
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, friction=0.5)
    if capacity is not None:
        b.set_rigid_contacts(capacity=capacity)
    motion = ta.RigidMotion([0.0, 1.0], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    b.add_rigid_body(ta.shapes.Box((0.05, 0.2, 0.3)), position=(-0.5, 0.2, 0.0), motion=motion)
    b.add_rigid_body(ta.shapes.Box((0.1, 0.1, 0.1)), position=(-0.2, 0.1, 0.0))
    b.add_rigid_body(
        ta.shapes.Box((0.2, 0.05, 0.1)), position=(1.0, 0.4, 0.0), orientation=(0.3, 0.2, 0.1, 0.92),
        angular_velocity=(1.0, 2.0, 0.0),
    )  # fmt: skip
    m = b.finalize()
    return m, m.state()


def test_a_frame_in_one_launch_equals_its_steps_bit_for_bit():
    # 0.5 s as 15 frames of 8 steps against 120 single steps, each in its own model (warm starts are the
    # solver's): the frame runs the step's kernel with a step count, so every bit agrees.
    framed, by_step = ta.make_integrator("symplectic_euler"), ta.make_integrator("symplectic_euler")
    m1, s1 = scene()
    m2, s2 = scene()
    for _ in range(15):
        framed.step(m1, s1, SUBSTEPS * H, substeps=SUBSTEPS)
    for _ in range(15 * SUBSTEPS):
        by_step.step(m2, s2, H)
    assert framed.stepper_for(m1).frame_mode()["mode"] == "solver_frame"
    a, b = s1.rigid_snapshot(), s2.rigid_snapshot()
    for name in ("position", "orientation", "velocity", "angular_velocity"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert s1.time == pytest.approx(s2.time, abs=1e-12) and s1.step_count == s2.step_count == 120
    # the paddle is where its keys put it at t = 0.5 s (the time advanced inside the launch)
    np.testing.assert_allclose(a.position[0], [0.0, 0.2, 0.0], atol=1e-6)
    assert a.position[2][1] < 0.2  # the tilted box has landed


@pytest.mark.parametrize("check_every", [1, 20])
def test_an_overflow_inside_a_frame_is_reported_and_the_frame_start_kept(check_every):
    # Room for 4 contacts: the first frame (the boxes in the air but the pushed one, 4 corners on the
    # floor) holds; the paddle's corners reach the box within the next frames and overflow the buffers:
    # the frame stops, the error names the capacity (also where the watch is read only every 20 steps),
    # and the state is the last good frame's start.
    m, s = scene(capacity=4)
    integ = ta.make_integrator("symplectic_euler", check_every=check_every, policy={"keep_last_good": True})
    stepper = integ.stepper_for(m)
    with pytest.raises(DivergenceError, match=r"found, the buffers hold 4 \(Builder.set_rigid_contacts"):
        for _ in range(60):
            before = s.rigid_snapshot().position, s.step_count, s.time
            integ.step(m, s, SUBSTEPS * H, substeps=SUBSTEPS)
    assert stepper.frame_mode()["mode"] == "solver_frame"
    if check_every == 1:  # the rollback point is every frame's start
        assert s.step_count == before[1] and s.time == before[2]
        np.testing.assert_array_equal(s.rigid_snapshot().position, before[0])
