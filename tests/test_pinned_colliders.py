"""Pinned particles are kinematic: colliders never move them (as in Blender, Houdini Vellum and Newton).

A pinned vertex placed inside a collider with State.set_positions stays exactly where it was put, in
both collision modes, with and without cloth self-contact (whose sweeps also project vertices out of
colliders); the free vertices around it are still kept out.
"""

import numpy as np
import pytest

import taichi_anim as ta


def pinned_cloth(self_contact: bool):
    """A 4 x 4 cloth (0.3 m) at y = 0.5 under gravity, pinned at vertex 0, above a ball of radius 0.2 m
    at the origin and a floor at y = -1."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(origin=(-0.15, 0.5, -0.15), size=(0.3, 0.3), resolution=(4, 4), pinned=[0])
    b.add_collider_sphere((0.0, 0.0, 0.0), 0.2)
    b.add_collider_plane(offset=-1.0)
    if self_contact:
        b.add_cloth_self_contact(thickness=0.01)
    return b.finalize()


@pytest.mark.parametrize("mode", ["projection", "backward"])
@pytest.mark.parametrize("self_contact", [False, True])
def test_a_pinned_vertex_inside_a_collider_stays_where_it_was_put(mode, self_contact):
    """Pass: pinned vertex 0 moved to (0.05, 0.1, 0) (0.09 m deep inside the ball) and another pinned
    particle 0.2 m below the floor stay bitwise at those points over 10 steps of 1/60 s; free vertices
    end outside the ball (|x| >= R - 1e-4). Before: both were pushed to the surfaces in the first step."""
    ta.init("cpu", precision="f64")
    model = pinned_cloth(self_contact)
    state = model.state()
    inside = np.array([[0.05, 0.1, 0.0]])
    state.set_positions(inside, indices=[0])
    integ = ta.make_integrator("implicit_euler", collision_mode=mode)
    for _ in range(10):
        integ.step(model, state, 1 / 60)
    x = state.positions()
    assert np.array_equal(x[0], inside[0])
    free = np.arange(1, model.particle_count)
    assert np.all(np.linalg.norm(x[free], axis=1) >= 0.2 - 1e-4)


@pytest.mark.parametrize("mode", ["projection", "backward"])
def test_a_pinned_particle_below_a_floor_stays_there(mode):
    """Pass: a pinned point particle (mass 0) set 0.2 m below the floor plane y = 0 stays bitwise there
    over 5 steps, while a free particle set at the same depth is pushed onto the floor (y = 0)."""
    ta.init("cpu", precision="f64")
    b = ta.Builder()
    b.add_force_gravity()
    b.add_particles([[0.0, 1.0, 0.0], [1.0, 1.0, 0.0]], mass=[0.0, 1.0])
    b.add_collider_plane(offset=0.0)
    model = b.finalize()
    state = model.state()
    below = np.array([[0.0, -0.2, 0.0], [1.0, -0.2, 0.0]])
    state.set_positions(below)
    integ = ta.make_integrator("symplectic_euler", collision_mode=mode)
    for _ in range(5):
        integ.step(model, state, 1 / 60)
    x = state.positions()
    assert np.array_equal(x[0], below[0])
    assert x[1, 1] == pytest.approx(0.0, abs=1e-9)
