"""The rigid-body demos against what they show: the dominoes fall in order within 4 s, the pile settles
inside its bin without sinking, the cloth tips the leaning stack over."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.bodies.rigid.quaternion import quat_to_matrix
from taichi_anim.scenes import make_scene


def test_thirty_dominoes_fall_in_order_within_four_seconds():
    scene = make_scene("dominoes")
    fallen_at = np.full(30, np.inf)
    for frame in range(240):  # 4 s at 60 frames per second
        scene.advance_frame()
        long_axis = quat_to_matrix(scene.state.rigid_snapshot().orientation)[:, :, 1]
        tilt = np.degrees(np.arccos(np.clip(long_axis[:, 1], -1.0, 1.0)))
        fallen_at[(tilt > 45.0) & np.isinf(fallen_at)] = (frame + 1) / 60
    assert np.all(np.isfinite(fallen_at)), fallen_at  # every domino is down by 4 s
    assert np.all(np.diff(fallen_at) > 0.0)  # one after the other, in order


@pytest.mark.slow  # exhaustive; covered by the rigid demos' physics: the dominoes, default
def test_the_pile_settles_in_its_bin():
    scene = make_scene("pile", layers=2)
    for _ in range(150):
        scene.advance_frame()
    snap = scene.state.rigid_snapshot()
    half = scene.options["bin_half"]
    assert np.abs(snap.com[:, [0, 2]]).max() < half
    assert snap.com[:, 1].min() > 0.0
    assert np.abs(snap.velocity).max() < 0.5  # settling: a round body may still roll
    contacts = scene.integrator.stepper_for(scene.model).solver("rigid bodies").contacts
    n = contacts.count[None]
    assert contacts.sep.to_numpy()[:n].min() > -0.01  # nothing sunk more than 1 cm into another


@pytest.mark.slow  # exhaustive; covered by cloth on bodies: test_rigid_coupling, default
def test_the_cloth_tips_the_leaning_stack_over():
    # The same stack without the cloth stands; the falling cloth's weight tips its upper boxes over, and
    # no cloth vertex ends under the floor.
    scene = make_scene("rigid_cloth")
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0, restitution=0.0, friction=0.6)
    for k in range(scene.options["boxes"]):
        position = (k * scene.options["lean"], 0.15 + 0.3 * k, 0.0)
        b.add_rigid_body(ta.shapes.Box((0.15, 0.15, 0.15)), density=100.0, position=position, friction=0.6)
    model = b.finalize()
    alone = model.state()
    integ = ta.make_integrator("symplectic_euler")
    for _ in range(100):
        scene.advance_frame()
        integ.step(model, alone, 1 / 60, substeps=8)

    def tilt(state):
        return np.degrees(
            np.arccos(np.clip(quat_to_matrix(state.rigid_snapshot().orientation)[:, 1, 1], -1, 1))
        )

    assert tilt(alone).max() < 1.0
    assert tilt(scene.state)[1:].min() > 45.0
    assert scene.state.snapshot().x[:, 1].min() > 0.0


@pytest.mark.slow  # Taichi's debug mode compiles a bound check into every access: 44 s on 2 cores
def test_the_contact_kernels_stay_in_bounds():
    # Taichi's debug mode checks every field access: a conditional expression or an `and` in a kernel
    # evaluates both sides, and reading the unselected side once fell past an array (a segfault in CI).
    ta.init("cpu", precision="f64", debug=True)
    scene = make_scene("pile", layers=1, per_side=2)  # box, capsule, sphere, hull: the last has planes
    for _ in range(20):  # they land after about 15 frames
        scene.advance_frame()
    assert scene.integrator.stepper_for(scene.model).solver("rigid bodies").contacts.count[None] > 0
