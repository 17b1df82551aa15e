"""The sweep and prune ahead of the cascade (bodies/rigid/broad_phase.py): it lists every pair whose
bounding spheres can meet, in the order a loop over all pairs meets them, so a pile steps as it does when
every pair is tested."""

import numpy as np
import pytest

import taichi_anim as ta

pytestmark = pytest.mark.usefixtures("size_buckets")


def pile(every_pair: bool):
    """60 boxes and balls dropped at random into a corner of two walls, stepped 0.5 s; every_pair: the
    broad phase's list is given no room, so each step tests every pair."""
    rng = np.random.default_rng(5)
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_plane((0, 1, 0), 0.0, friction=0.5, restitution=0.0)
    b.add_collider_plane((1, 0, 0), -0.6, friction=0.5, restitution=0.0)
    b.add_collider_plane((0, 0, 1), -0.6, friction=0.5, restitution=0.0)
    shapes = (ta.shapes.Box((0.08, 0.05, 0.06)), ta.shapes.Sphere(0.06))
    for k in range(60):
        position = (rng.uniform(-0.5, 0.5), 0.1 + 0.15 * k / 4, rng.uniform(-0.5, 0.5))
        angle = rng.uniform(0, np.pi)
        b.add_rigid_body(shapes[k % 2], position=position, orientation=(0, np.sin(angle), 0, np.cos(angle)))
    m = b.finalize()
    s = m.state()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(m)
    contacts = stepper.solver("rigid bodies").contacts
    if every_pair:
        contacts.pair_capacity = 0  # read when the step compiles: every step overflows the list
    swept = []
    for _ in range(120):
        stepper.step(s, 1 / 240)
        swept.append(int(contacts.pairs_found[None]))
    return s.rigid_snapshot(), contacts.cascade(), swept


def test_the_sweep_finds_every_pair_the_spheres_pass_and_steps_as_testing_every_pair():
    swept, counts, found = pile(False)
    every, every_counts, _ = pile(True)
    # the same pairs pass each level of the cascade, and the same contacts in the same order: the same
    # motion (the kernels differ only in how pairs are enumerated; to round-off of f64 over 120 steps)
    assert counts == every_counts
    assert counts["pairs"] == 60 * 59 // 2
    for key in ("position", "orientation", "velocity", "angular_velocity"):
        np.testing.assert_allclose(getattr(swept, key), getattr(every, key), rtol=0, atol=1e-9)
    # and the sweep lists fewer than half the pairs (the pile is 1.2 m wide, a box's interval 0.3 m), though
    # at least those the spheres pass
    assert counts["spheres"] <= found[-1] < counts["pairs"] // 2
