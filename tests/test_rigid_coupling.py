"""Particles and rigid bodies pushing each other (bodies/rigid/particle_coupling.py): momentum exchanged
equal and opposite, hard spheres bouncing off a body, a cloth's weight carried by the body under it."""

import numpy as np
import pytest

import taichi_anim as ta

G = 9.81


def momentum(model, state):
    """Total linear momentum [kg m/s] of particles and bodies."""
    snap, bodies = state.snapshot(), state.rigid_snapshot()
    masses = model.particle_masses()[snap.index]
    return (masses[:, None] * snap.v).sum(axis=0) + (model.rigid_mass[:, None] * bodies.velocity).sum(axis=0)


def test_a_particle_stream_pushes_a_free_box_and_momentum_is_kept():
    # No gravity: 200 particles of 10 g at 5 m/s hit a 1 kg box head-on. Every impulse on a particle is
    # matched by the opposite one on the box: the total momentum stays 200 * 0.01 * 5 = 10 kg m/s.
    rng = np.random.default_rng(2)
    x = np.column_stack(
        [rng.uniform(-2.0, -0.3, 200), rng.uniform(-0.08, 0.08, 200), rng.uniform(-0.08, 0.08, 200)]
    )
    v = np.tile([5.0, 0.0, 0.0], (200, 1))
    b = ta.Builder()
    b.add_particles(x, v, mass=0.01, radius=0.01)
    box = b.add_rigid_body(ta.shapes.Box((0.1, 0.1, 0.1)), density=125.0, restitution=0.5, friction=0.3)
    m = b.finalize()
    s = m.state()
    assert m.rigid_mass[box] == pytest.approx(1.0)
    integ = ta.make_integrator("symplectic_euler")
    before = np.array([10.0, 0.0, 0.0])
    for _ in range(240):
        integ.step(m, s, 1 / 240)
    coupling = integ.stepper_for(m).solver("rigid bodies").coupling
    np.testing.assert_allclose(momentum(m, s), before, atol=1e-10)
    assert s.rigid_snapshot().velocity[box][0] > 1.0  # the box was pushed along
    assert coupling is not None


def test_a_sphere_bounces_off_a_heavy_box_at_e_times_its_speed():
    # A 10 g sphere at 3 m/s against a 1000 kg box (e = 0.8): it leaves at 0.8 * 3 m/s, the box barely moves.
    b = ta.Builder()
    b.add_particles([[-0.5, 0.0, 0.0]], [[3.0, 0.0, 0.0]], mass=0.01, radius=0.02)
    b.add_rigid_body(ta.shapes.Box((0.5, 0.5, 0.5)), density=1000.0, restitution=0.8)
    m = b.finalize()
    s = m.state()
    integ = ta.make_integrator("symplectic_euler")
    for _ in range(120):
        integ.step(m, s, 1 / 240)
    v = s.snapshot().v[0]
    assert v[0] == pytest.approx(-0.8 * 3.0, rel=1e-4)
    assert s.rigid_snapshot().velocity[0][0] == pytest.approx(0.01 * 3.0 * 1.8 / 1000.0, rel=1e-3)


def test_a_cloth_lying_on_a_box_weighs_on_it():
    # A 0.6 m cloth of 0.2 kg/m^2 dropped on a box resting on the floor: once it settles, the floor carries
    # the box and the cloth, (M + m) g, through the box's contacts.
    b = ta.Builder()
    b.add_force_gravity((0.0, -G, 0.0))
    b.add_collider_plane((0, 1, 0), 0.0, friction=0.5, restitution=0.0)
    cloth = b.add_cloth_grid(origin=(-0.3, 0.25, -0.3), size=(0.6, 0.6), resolution=(13, 13), plane="xz",
                             material=ta.ClothMaterial(density=0.2), thickness=0.005)  # fmt: skip
    b.add_rigid_body(ta.shapes.Box((0.4, 0.1, 0.4)), position=(0, 0.1, 0), density=100.0, friction=0.5)
    m = b.finalize()
    s = m.state()
    integ = ta.make_integrator("implicit_euler")  # stiff cloth springs; bodies step semi-implicitly
    h = 1 / 1200
    for _ in range(1800):
        integ.step(m, s, h)
    cloth_mass = 0.2 * 0.6 * 0.6
    contacts = integ.stepper_for(m).solver("rigid bodies").contacts
    n = contacts.count[None]
    floor = contacts.b.to_numpy()[:n] == -1
    carried = contacts.impulse.to_numpy()[:n][floor, 0].sum() / h
    assert carried == pytest.approx((m.rigid_mass[0] + cloth_mass) * G, rel=0.02)
    assert s.snapshot().x[:, 1].min() > 0.2 - 1e-3  # the cloth lies on the box's top, not in it
    assert len(cloth.particles) == 13 * 13
