"""Blocked frames (integrators/blocked.py): a frame of substeps in one launch, each particle stepped
through it in registers, with emitters' births planned before any particle moves.

The plan must be the step-by-step path's exactly: the same slots taken at the same substeps (free bits,
scan cursors and birth times equal bit for bit), and the particles' arithmetic the same functions, so
positions and velocities agree to the roundings of two differently compiled kernels."""

import math

import numpy as np
import pytest

import taichi_anim as ta

from .helpers import ulp_tolerance


def _fountain(
    capacity: int, lifetime: float, jitter: float, *, emitters: int = 1, seed: int = 3, trails: int = 0
):
    b = ta.Builder()
    if trails:
        b.add_particle_trails(trails)
    for k in range(emitters):
        b.add_particle_emitter(
            capacity=capacity,
            rate=capacity / lifetime * (1.3 if k else 1.0),  # more than the pool takes: births wait
            shape="disc",
            center=(0.3 * k, 0.25, 0.0),
            radius=0.25,
            direction=(0, 1, 0),
            speed=4.0,
            speed_jitter=0.1,
            spread=0.5,
            lifetime=lifetime,
            lifetime_jitter=jitter,
        )
    b.add_force_gravity()
    b.add_force_drag(0.02)
    b.add_collider_box((-1, 0, -1), (1, 2, 1), restitution=0.5, friction=0.1)
    model = b.finalize(seed=seed)
    return model, model.state()


def _run(mode, h, frames, substeps, **scene):
    model, state = _fountain(**scene)
    stepper = ta.make_integrator("symplectic_euler", check_every=substeps).stepper_for(model)
    if mode is None:
        for _ in range(frames * substeps):
            stepper.step(state, h)
    else:
        stepper._frame_mode = {"mode": mode, "reason": "test"}
        for _ in range(frames):
            stepper.advance(state, h, substeps)
    return model, state, stepper


@pytest.mark.parametrize(
    "scene",
    [
        # A full pool: every birth waits for a death (the scan's cursor wraps).
        dict(capacity=500, lifetime=0.05, jitter=0.2),
        # Lifetimes shorter than a frame: slots are born, die and are born again within one launch.
        dict(capacity=300, lifetime=0.004, jitter=0.5),
        # Two emitters, the second asking for more than its pool holds.
        dict(capacity=200, lifetime=0.02, jitter=0.3, emitters=2),
        # Trails of 7 columns (not a divisor of the 10 substeps): every substep's column, births included.
        dict(capacity=300, lifetime=0.01, jitter=0.3, trails=7),
    ],
)
def test_blocked_frames_equal_step_by_step(scene):
    h, frames, substeps = 1.0 / 600.0, 12, 10
    model, ref, _ = _run(None, h, frames, substeps, **scene)
    _, got, stepper = _run("blocked", h, frames, substeps, **scene)
    assert stepper.frame_mode()["mode"] == "blocked"
    # The plan: bit for bit.
    np.testing.assert_array_equal(got.particle_free.to_numpy(), ref.particle_free.to_numpy())
    np.testing.assert_array_equal(got.emit_cursor.to_numpy(), ref.emit_cursor.to_numpy())
    np.testing.assert_array_equal(got.particle_birth.to_numpy(), ref.particle_birth.to_numpy())
    assert got.emit_carry == ref.emit_carry
    assert got.time == ref.time and got.step_count == ref.step_count == frames * substeps
    alive = ref.alive_mask()
    np.testing.assert_array_equal(got.alive_mask(), alive)
    assert 0.3 * model.particle_count < alive.sum() <= model.particle_count
    # Death times: the same lifetime draw added to the same birth time.
    death = ref.particle_death.to_numpy()
    np.testing.assert_allclose(got.particle_death.to_numpy(), death, rtol=0, atol=ulp_tolerance(1.0, 4))
    # The motion: 120 substeps of gravity, drag and the box, to round-off.
    names = ["particle_x", "particle_v"]
    if ref.trail_length:
        assert got.trail_head == ref.trail_head == (frames * substeps) % ref.trail_length
        names.append("trail")
    for name in names:
        want = getattr(ref, name).to_numpy()[alive]
        tol = ulp_tolerance(np.abs(want).max(), 64 * frames * substeps)
        np.testing.assert_allclose(getattr(got, name).to_numpy()[alive], want, rtol=0, atol=tol)


def test_blocked_frame_without_emitters_and_with_long_frames():
    """Static particles falling onto a plane: a frame of 150 substeps runs as three launches (at most
    MAX_STEPS each) and ends where 150 single steps do."""
    from taichi_anim.integrators.blocked import MAX_STEPS

    def run(blocked: bool):
        b = ta.Builder()
        rng = np.random.default_rng(1)
        b.add_particles(rng.uniform(-0.5, 0.5, (700, 3)) + [0, 1, 0], rng.normal(0, 1, (700, 3)), mass=0.01)
        b.add_force_gravity()
        b.add_collider_plane(normal=(0.0, 1.0, 0.0), offset=0.0, restitution=0.3, friction=0.2)
        model = b.finalize()
        state = model.state()
        stepper = ta.make_integrator("symplectic_euler", check_every=150).stepper_for(model)
        if blocked:
            assert stepper.frame_mode()["mode"] == "blocked"
            stepper.advance(state, 1e-3, 150)
        else:
            for _ in range(150):
                stepper.step(state, 1e-3)
        return state

    assert 150 > 2 * MAX_STEPS
    ref, got = run(False), run(True)
    assert got.step_count == 150 and got.time == ref.time
    want = ref.positions()
    assert want[:, 1].min() > -1e-6 and np.abs(want - run(False).positions()).max() == 0.0
    np.testing.assert_allclose(
        got.positions(), want, rtol=0, atol=ulp_tolerance(np.abs(want).max(), 64 * 150)
    )
    np.testing.assert_allclose(got.velocities(), ref.velocities(), rtol=0, atol=ulp_tolerance(10.0, 64 * 150))


def test_blocked_frame_stops_at_the_step_that_diverged():
    """Falling particles against a speed limit of 5 m/s: the particle with the largest downward start
    velocity crosses it first, at the step v0 + g t > 5 m/s predicts. The blocked frame raises the same
    DivergenceError (step, particle, quantity) as single steps, and keeps the frame's start."""
    v0 = np.zeros((50, 3))
    v0[:, 1] = -np.linspace(0.0, 2.0, 50)
    v0[[7, 31], 1] = -3.0, -3.5  # particle 31 leads
    h, g = 1e-3, 9.81
    first = int(np.floor((5.0 - 3.5) / (g * h))) + 1  # its speed after n steps: 3.5 + n g h (to f32 rounding)
    errors, starts = [], []
    for blocked in (False, True):
        b = ta.Builder()
        b.add_particles(np.random.default_rng(2).uniform(0, 1, (50, 3)) + [0, 100, 0], v0, mass=0.01)
        b.add_force_gravity((0.0, -g, 0.0))
        model = b.finalize()
        state = model.state()
        stepper = ta.make_integrator(
            "symplectic_euler", check_every=20, policy={"keep_last_good": True}
        ).stepper_for(model)
        stepper.watchdog.configure(speed=5.0, extent=math.inf, energy_tolerance=math.inf)
        with pytest.raises(ta.DivergenceError) as info:
            for _ in range(20):
                if blocked:
                    stepper.advance(state, h, 20)
                else:
                    for _ in range(20):
                        stepper.step(state, h)
        errors.append(info.value)
        starts.append(state.step_count)
        assert stepper.frame_mode()["mode"] == "blocked"
    ref, got = errors
    assert abs(ref.step - first) <= 1 and ref.particle == 31 and ref.quantity == "speed"
    assert (got.step, got.particle, got.quantity) == (ref.step, ref.particle, ref.quantity)
    assert starts[0] == starts[1] == 20 * ((first - 1) // 20)  # the last checked good step


def test_interrupted_blocked_frame_keeps_the_frame_start(monkeypatch):
    """Ctrl-C between the launches of a long frame (150 substeps: three launches) under keep_last_good:
    the state is the frame's start, bit for bit, emission carry, time and every trail column included
    (the first launch wrote all five)."""
    model, state = _fountain(capacity=400, lifetime=0.05, jitter=0.2, trails=5)
    stepper = ta.make_integrator("symplectic_euler", policy={"keep_last_good": True}).stepper_for(model)
    stepper.advance(state, 1e-3, 20)
    before = {k: getattr(state, k).to_numpy() for k in ("particle_x", "particle_v", "particle_free", "trail")}
    carry, t, steps, head = list(state.emit_carry), state.time, state.step_count, state.trail_head
    launch = stepper._blocked._launch
    calls = []

    def interrupted(*args):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return launch(*args)

    monkeypatch.setattr(stepper._blocked, "_launch", interrupted)
    with pytest.raises(KeyboardInterrupt):
        stepper.advance(state, 1e-3, 150)
    assert len(calls) == 2 and state.time == t and state.step_count == steps and state.emit_carry == carry
    assert state.trail_head == head
    for k, want in before.items():
        np.testing.assert_array_equal(getattr(state, k).to_numpy(), want)


def test_blocked_frames_are_the_same_on_one_and_two_threads():
    """A pool large enough for the parallel launch (capacity x substeps above SERIAL_BELOW): the same
    bits on one thread and on two (births planned serially, particles independent, bits set by OR)."""
    from taichi_anim.integrators.blocked import SERIAL_BELOW

    def run(threads):
        ta.init("cpu", precision="f32", cpu_threads=threads)
        model, state = _fountain(capacity=40_000, lifetime=0.02, jitter=0.3)
        stepper = ta.make_integrator("symplectic_euler", check_every=10).stepper_for(model)
        for _ in range(4):
            stepper.advance(state, 1.0 / 600.0, 10)
        assert model.particle_capacity * 10 >= SERIAL_BELOW
        return [getattr(state, k).to_numpy() for k in ("particle_x", "particle_v", "particle_free")]

    one, two = run(1), run(None)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)
