"""Where a liquid comes from: nozzles (add_fluid_emitter: whole layers of the rest lattice at the flow
rate), closed meshes filled (add_fluid_mesh: the lattice points inside, by winding number), and the
refusals of bad input. A poured container fills to the level its particles' volume gives."""

import math

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.errors import ParameterError
from taichi_anim.geometry import box_mesh, revolve_mesh
from taichi_anim.shapes import polyhedron_mass_properties, uv_sphere

D = 0.01


def stepper_of(model):
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    return stepper, next(s for s in stepper.solvers if s.name == "fluid")


def alive(model, state) -> np.ndarray:
    return state.particle_death.to_numpy()[model.fluid_particles] > state.time


def test_a_nozzle_emits_whole_layers_at_its_flow_rate_as_a_rigid_lattice():
    """No gravity, no walls: a nozzle of 2 spacings' radius (13 lattice points) facing +x at 1 m/s for
    0.1 s emits one layer per 10 ms, 13 x floor(v t / d) particles by time t (the distance carries
    across steps), then stops at 10 layers. The jet is too thin to be compressed anywhere, so the solves
    leave it alone: every particle keeps the nozzle's velocity and the layers stay a spacing apart (the
    rest lattice). Unborn slots stay out of the solves: one among the particles would drag the jet."""
    b = ta.Builder()
    b.add_fluid(spacing=D, domain=((-0.1, -0.1, -0.1), (1.0, 0.1, 0.1)))
    b.add_fluid_emitter(
        center=(0.0, 0.0, 0.0), radius=2 * D, speed=1.0, direction=(1.0, 0.0, 0.0), stop_time=0.1
    )
    model = b.finalize()
    state = model.state()
    stepper, fluid = stepper_of(model)
    assert model.fluid_count == 13 * 11  # the default capacity: layers until stop_time, and one more
    dt = 1.0 / 240.0
    for step in range(1, 49):
        stepper.advance(state, dt, 1)
        live = alive(model, state)
        assert live.sum() == 13 * min(math.floor(step * dt / D + 1e-9), 10)
    x = state.positions()[model.fluid_particles][live]
    v = state.velocities()[model.fluid_particles][live]
    assert np.abs(v - [1.0, 0.0, 0.0]).max() < 1e-9
    layers = np.unique(np.round(x[:, 0] / (1e-6 * D)))
    assert len(layers) == 10 and np.allclose(np.diff(layers) * 1e-6 * D, D, atol=1e-9)
    assert np.abs(np.sort(np.unique(np.round(x[:, 1], 9)))).max() == pytest.approx(2 * D)
    assert fluid.stats()["mean_error_max"] == 0.0


def test_a_poured_container_fills_to_the_level_of_its_particles_volume():
    """A nozzle 6 cm above 4 cm of water in a 10 x 10 cm box pours 0.5 s at 0.5 m/s; after settling,
    the liquid's surface (its top particles plus half a spacing) stands at N d^3 / A, the particles'
    volume over the box's floor, within half a spacing (measured 0.4 mm of 1 cm). No particle leaves
    the box or rises above the jet's energy (the nozzle's height plus v^2 / 2g; measured 0.89 of it):
    the pool takes the impact. (Poured onto the bare floor, the splash reaches the nozzle, whose new
    layers are then placed into it and thrown out, up to 1.7-3.2 times that height: a nozzle does not
    check that its exit is clear.) Every step's mean density error stayed at or under the tolerance."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (0.1, 0.3, 0.1), restitution=0.0)
    b.add_fluid(spacing=D)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.1, 0.04, 0.1))
    b.add_fluid_emitter(center=(0.05, 0.1, 0.05), radius=2 * D, speed=0.5, stop_time=0.5)
    model = b.finalize()
    state = model.state()
    stepper, fluid = stepper_of(model)
    highest = 0.0
    for _ in range(90):
        stepper.advance(state, 1.0 / 60.0, 1)
        highest = max(highest, state.positions()[model.fluid_particles][alive(model, state), 1].max())
    live = alive(model, state)
    x = state.positions()[model.fluid_particles][live]
    assert live.sum() == 400 + 13 * 25
    level = live.sum() * D**3 / 0.1**2
    top = np.sort(x[:, 1])[-10:].mean() + 0.5 * D  # the top layer's particles, not one splashed drop
    assert top == pytest.approx(level, abs=0.5 * D)
    assert np.all((x > 0.0) & (x < [0.1, 0.3, 0.1]))
    assert highest < 0.1 + 0.5**2 / (2 * 9.81)
    assert fluid.stats()["mean_error_max"] <= 5e-4 + 1e-9


def test_a_box_mesh_fills_as_the_box_does():
    """add_fluid_mesh of a box's mesh places add_fluid_block's lattice of that box, point for point."""
    lo, hi = (0.01, 0.02, -0.03), (0.095, 0.1, 0.04)
    b = ta.Builder()
    b.add_fluid(spacing=D)
    mesh = b.add_fluid_mesh(box_mesh(lo, hi))
    block = b.add_fluid_block(lo, hi)
    x = b.finalize().state().positions()
    assert len(mesh) == len(block) == 8 * 8 * 7
    assert np.abs(x[np.asarray(mesh)] - x[np.asarray(block)]).max() < 1e-12


@pytest.mark.parametrize("radius", [0.08, 0.1])
def test_a_sphere_mesh_fills_with_its_volume(radius):
    """A ball of 8 and 10 spacings' radius (a 96 x 48 polygon): every particle inside, and the
    particles' volume N d^3 within 2 % of the polygon's (the lattice points counted against the
    volume: an error of the surface's share, measured 1.8 % and 1.0 %)."""
    v, f = uv_sphere((0.01, 0.02, 0.003), radius, rings=48, segments=96)
    b = ta.Builder()
    b.add_fluid(spacing=D)
    idx = b.add_fluid_mesh((v, f))
    x = b.finalize().state().positions()[np.asarray(idx)]
    assert np.linalg.norm(x - [0.01, 0.02, 0.003], axis=1).max() < radius
    volume = polyhedron_mass_properties(v, f, 1.0).mass
    assert len(idx) * D**3 == pytest.approx(volume, rel=0.02)


def test_a_glass_mesh_fills_its_walls_not_its_hollow():
    """A non-convex closed mesh (a glass, revolve_mesh): particles fill its walls and bottom; none lies
    in the hollow it holds."""
    R, H, t = 0.1, 0.2, 0.02
    v, f = revolve_mesh([(0, 0), (R, 0), (R, H), (R - t, H), (R - t, t), (0, t)], 64)
    b = ta.Builder()
    b.add_fluid(spacing=D)
    idx = b.add_fluid_mesh((v, f))
    x = b.finalize().state().positions()[np.asarray(idx)]
    r = np.hypot(x[:, 0], x[:, 2])
    assert not np.any((r < R - t) & (x[:, 1] > t))
    assert r.max() < R and x[:, 1].min() > 0.0
    volume = polyhedron_mass_properties(v, f, 1.0).mass
    assert len(idx) * D**3 == pytest.approx(volume, rel=0.1)  # thin walls: the surface's share is large


def test_bad_sources_are_refused_with_the_parameter_named():
    b = ta.Builder()
    with pytest.raises(ParameterError, match="add_fluid_emitter needs the liquid"):
        b.add_fluid_emitter(center=(0, 0, 0), radius=0.02, speed=1.0, stop_time=1.0)
    with pytest.raises(ParameterError, match="add_fluid_mesh needs the liquid"):
        b.add_fluid_mesh(box_mesh((0, 0, 0), (1, 1, 1)))
    b.add_fluid(spacing=D)
    with pytest.raises(ParameterError, match="stop_time or capacity"):
        b.add_fluid_emitter(center=(0, 0, 0), radius=0.02, speed=1.0)
    with pytest.raises(ParameterError, match="stop_time"):
        b.add_fluid_emitter(center=(0, 0, 0), radius=0.02, speed=1.0, start_time=1.0, stop_time=0.5)
    with pytest.raises(ParameterError, match="speed"):
        b.add_fluid_emitter(center=(0, 0, 0), radius=0.02, speed=0.0, stop_time=1.0)
    with pytest.raises(ParameterError, match="capacity"):
        b.add_fluid_emitter(center=(0, 0, 0), radius=0.02, speed=1.0, capacity=10**12)
    outside = ta.Builder()
    outside.add_collider_box((0.0, 0.0, 0.0), (0.1, 0.1, 0.1))
    outside.add_fluid(spacing=D)
    outside.add_fluid_emitter(center=(0.05, 0.5, 0.05), radius=0.02, speed=1.0, stop_time=1.0)
    with pytest.raises(ParameterError, match="center .* outside the liquid's domain"):
        outside.finalize()
    v, f = box_mesh((0, 0, 0), (0.1, 0.1, 0.1))
    with pytest.raises(ParameterError, match="closed"):
        b.add_fluid_mesh((v, f[:-1]))  # one triangle missing: open
    with pytest.raises(ParameterError, match="no lattice point"):
        b.add_fluid_mesh(
            revolve_mesh([(0, 0), (0.004, 0), (0.004, 0.008), (0.003, 0.008), (0.003, 0.001), (0, 0.001)])
        )  # a thimble: its box's one lattice point in its hollow
    with pytest.raises(ParameterError, match="profile"):
        revolve_mesh([(0.1, 0.0), (0.1, 1.0), (0.0, 1.0)])


@pytest.mark.slow  # the whole demo, 2 s: about 40 s on 2 cores
def test_the_pour_demo_fills_its_glass_and_floats_its_box():
    """The `pour` demo to its end: every particle the nozzle emitted is in the glass (inside its inner
    wall, above its bottom); the water stands at the level its volume and the box's submerged part give
    over the glass's inner section (the 48-gon's area), within a spacing (measured 0.3 spacing under
    it); the wooden box (500 kg/m^3) floats with its bottom within a spacing of half its height under
    that level (measured 1.09 times half its height)."""
    from taichi_anim.scenes import make_scene

    ta.init("cpu")
    scene = make_scene("pour")
    model, state = scene.model, scene.state
    for _ in range(scene.frames):
        scene.advance_frame()
    d = scene.options["spacing"]
    live = alive(model, state)
    x = state.positions()[model.fluid_particles][live]
    inner, bottom = 0.06 - 0.012, 0.012
    assert live.sum() > 1000 and np.hypot(x[:, 0], x[:, 2]).max() < inner and x[:, 1].min() > bottom
    area = 0.5 * 48 * inner**2 * np.sin(2 * np.pi / 48)
    box_bottom = state.rigid_snapshot().com[0, 1] - 0.02
    # (level - bottom) area = N d^3 + the box's submerged part, 0.04^2 (level - box_bottom)
    level = (bottom * area + live.sum() * d**3 - 0.04**2 * box_bottom) / (area - 0.04**2)
    top = np.sort(x[:, 1])[-20:].mean() + 0.5 * d
    assert top == pytest.approx(level, abs=d)
    assert level - box_bottom == pytest.approx(0.02, abs=d)
