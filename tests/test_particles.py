"""Reeves particle systems: emission rate, lifetimes, pool recycling, shapes, determinism, forces."""

import numpy as np
import pytest

import taichi_anim as ta


def fountain(*, seed=0, capacity=2000, rate=1000.0, lifetime=0.5, jitter=0.0, shape="point", **kw):
    b = ta.Builder()
    b.add_force_gravity()
    b.add_particle_emitter(
        capacity=capacity,
        rate=rate,
        shape=shape,
        lifetime=lifetime,
        lifetime_jitter=jitter,
        speed=3.0,
        spread=0.4,
        **kw,
    )
    model = b.finalize(seed=seed)
    return model, model.state()


def test_emission_rate_lifetime_and_recycling():
    # rate R, fixed lifetime L, particles born at the start of each step and dead once age >= L:
    # alive(t) = R t for t < L, then R (L - dt) in steady state (give or take one step's emission where
    # the accumulated time lands on a death time).
    dt, rate, life = 1 / 100, 1000.0, 0.5
    model, state = fountain(rate=rate, lifetime=life, capacity=600)
    integ = ta.IntegratorSymplecticEuler()
    alive = []
    for _ in range(150):
        integ.step(model, state, dt)
        alive.append(len(state.snapshot().x))
    assert alive[29] == 300  # t = 0.30 s
    assert abs(alive[-1] - rate * (life - dt)) <= rate * dt  # t = 1.5 s: only those younger than L
    snap = state.snapshot()
    assert snap.age.max() <= life + 1e-9 and snap.age.min() >= dt - 1e-9
    # Every slot used (600 > 500 needed), none beyond the pool.
    assert snap.index.max() < 600


def test_pool_capacity_caps_alive_count():
    model, state = fountain(rate=5000.0, lifetime=1.0, capacity=300)
    integ = ta.IntegratorSymplecticEuler()
    for _ in range(50):
        integ.step(model, state, 0.01)
    assert len(state.snapshot().x) == 300


def test_emitter_shapes_and_attribute_ranges():
    b = ta.Builder()
    kw = dict(
        capacity=4000,
        rate=4000 / 0.01,
        speed=2.0,
        speed_jitter=0.25,
        spread=0.3,
        lifetime=10.0,
        lifetime_jitter=0.2,
    )
    b.add_particle_emitter(shape="disc", center=(1, 2, 3), radius=0.5, direction=(0, 0, 1), **kw)
    b.add_particle_emitter(shape="sphere", center=(-1, 0, 0), radius=0.25, **kw)
    b.add_particle_emitter(shape="box", center=(0, 5, 0), half_extents=(0.1, 0.2, 0.3), **kw)
    model = b.finalize()
    state = model.state()
    model.emit(state, 0.01)  # spawn only: positions and velocities as sampled
    x = state.positions()
    v = state.velocities()
    disc, ball, box = x[:4000], x[4000:8000], x[8000:]
    assert np.allclose(disc[:, 2], 3.0) and np.linalg.norm(disc[:, :2] - [1, 2], axis=1).max() <= 0.5
    assert np.linalg.norm(ball - [-1, 0, 0], axis=1).max() <= 0.25 + 1e-12
    assert np.all(np.abs(box - [0, 5, 0]) <= [0.1, 0.2, 0.3])
    # Uniform in the disc's area: about a quarter of the points within half the radius.
    inner = (np.linalg.norm(disc[:, :2] - [1, 2], axis=1) < 0.25).mean()
    assert abs(inner - 0.25) < 0.03
    speed = np.linalg.norm(v, axis=1)
    assert speed.min() >= 1.5 - 1e-9 and speed.max() <= 2.5 + 1e-9
    axis = np.repeat([[0, 0, 1], [0, 1, 0], [0, 1, 0]], 4000, axis=0)
    angle = np.arccos(np.clip((v * axis).sum(1) / speed, -1, 1))
    assert angle.max() <= 0.3 + 1e-9 and angle.max() > 0.25
    life = state.snapshot().lifetime
    assert life.min() >= 8.0 - 1e-9 and life.max() <= 12.0 + 1e-9


def test_same_seed_same_particles_any_thread_count():
    def run(seed, threads):
        ta.init("cpu", precision="f32", cpu_threads=threads)
        model, state = fountain(seed=seed, jitter=0.3, shape="disc", radius=0.2)
        integ = ta.IntegratorSymplecticEuler()
        for _ in range(60):
            integ.step(model, state, 1 / 120)
        return state.positions()

    a, b, c, d = run(7, None), run(7, None), run(7, 1), run(8, None)
    assert np.array_equal(a, b) and np.array_equal(a, c)  # gather kernels + counter-based RNG
    assert not np.array_equal(a, d)


def test_colour_over_life_ramps_from_start_to_end():
    b = ta.Builder()
    b.add_particle_emitter(capacity=100, rate=100, lifetime=1.0, color_start=(1, 0, 0), color_end=(0, 0, 1))
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorSymplecticEuler()
    for _ in range(50):
        integ.step(model, state, 0.01)
    snap = state.snapshot()
    s = snap.age / snap.lifetime
    np.testing.assert_allclose(snap.color, np.stack([1 - s, 0 * s, s], 1), atol=1e-12)


def test_drag_reaches_terminal_velocity():
    # m v' = m g - k v  =>  v(t) = (m g / k) (1 - e^{-k t / m})
    m, k, t = 2.0, 4.0, 1.5
    b = ta.Builder()
    b.add_particle((0, 0, 0), mass=m)
    b.add_force_gravity((0, -9.81, 0))
    b.add_force_drag(k)
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorRK4()
    for _ in range(150):
        integ.step(model, state, t / 150)
    v = state.velocities()[0, 1]
    np.testing.assert_allclose(v, -9.81 * m / k * (1 - np.exp(-k * t / m)), rtol=1e-8)


def test_wind_drags_particles_to_air_velocity():
    # m v' = k (w - v)  =>  v(t) = w + (v0 - w) e^{-k t / m}
    w, k, t = np.array([3.0, 0.0, -1.0]), 1.5, 2.0
    b = ta.Builder()
    b.add_particles(np.zeros((4, 3)), v=np.ones((4, 3)))
    b.add_force_wind(w, k)
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorRK4()
    for _ in range(200):
        integ.step(model, state, t / 200)
    expected = w + (1.0 - w) * np.exp(-k * t)
    np.testing.assert_allclose(state.velocities(), np.tile(expected, (4, 1)), rtol=1e-8)


def test_trails_hold_last_positions_oldest_first():
    b = ta.Builder()
    b.add_particle((0, 0, 0), (1, 2, 0))
    b.add_force_gravity()
    b.add_particle_trails(5)
    model = b.finalize()
    state = model.state()
    integ = ta.IntegratorSymplecticEuler()
    history = []
    for _ in range(9):
        integ.step(model, state, 0.05)
        history.append(state.positions()[0])
    np.testing.assert_allclose(state.snapshot().trails[0], np.array(history[-5:]), atol=1e-14)


def test_particle_count_and_mass_validation():
    b = ta.Builder()
    with pytest.raises(ta.ParameterError, match="capacity"):
        b.add_particle_emitter(capacity=-5, rate=10)
    with pytest.raises(ta.ParameterError, match="x contains 1 non-finite"):
        b.add_particles([[0, np.nan, 0]])
    with pytest.raises(ta.ParameterError, match="mass"):
        b.add_particles([[0, 0, 0]], mass=-1)
    with pytest.raises(ta.ParameterError, match="emitter shape"):
        b.add_particle_emitter(capacity=5, rate=1, shape="torus")
    with pytest.raises(ta.ParameterError, match="rate"):
        b.add_particle_emitter(capacity=5, rate=float("nan"))
    with pytest.raises(ta.ParameterError, match="normal"):
        b.add_collider_plane((0, 0, 0))
    with pytest.raises(ta.ParameterError, match="empty"):
        b.finalize()


def test_recycling_with_scattered_deaths_and_unaligned_pools():
    # Three static particles, then two emitters whose slot ranges straddle 32-slot words: jittered
    # lifetimes free slots in random order; the free bits must match the death times exactly, no emitter
    # may write outside its range, and static particles are never reused.
    b = ta.Builder()
    b.add_particles(np.array([[5.0, 5, 5], [6, 6, 6], [7, 7, 7]]))
    kw = dict(rate=3000.0, lifetime=0.2, lifetime_jitter=0.9, speed=1.0, spread=1.0)
    b.add_particle_emitter(capacity=45, center=(0, 0, 0), **kw)
    b.add_particle_emitter(capacity=70, center=(0, -10, 0), **kw)
    model = b.finalize(seed=4)
    state = model.state()
    integ = ta.IntegratorSymplecticEuler()
    for _ in range(200):
        integ.step(model, state, 0.005)
        death = state.particle_death.to_numpy()[: model.particle_count]  # capacity rows under buckets
        bits = np.unpackbits(state.particle_free.to_numpy().view(np.uint8), bitorder="little")[:118]
        np.testing.assert_array_equal(bits.astype(bool), death <= state.time)
    snap = state.snapshot()
    np.testing.assert_allclose(snap.x[:3], [[5, 5, 5], [6, 6, 6], [7, 7, 7]])
    first = (snap.index >= 3) & (snap.index < 48)
    assert np.all(np.abs(snap.x[first, 1]) < 5) and np.all(snap.x[~first & (snap.index >= 48), 1] < -5)
    # Demand (3000/s x ~0.2 s) exceeds both pools, so no slot stays idle for a whole step: every slot is
    # alive or died within the last step (it is refilled at the start of the next one).
    assert np.all(state.particle_death.to_numpy()[: model.particle_count] > state.time - 0.005)


def test_motion_reads_what_positions_velocities_and_alive_mask_read():
    """state.motion() (one launch, the snapshot's fields) gives positions(), velocities() and
    alive_mask(): with emitters (some slots dead) and without."""
    model, state = fountain(rate=600.0, capacity=60, lifetime=0.05)
    integ = ta.make_integrator("symplectic_euler")
    for _ in range(9):
        integ.step(model, state, 1 / 60)
    x, v, alive = state.motion()
    assert 0 < alive.sum() < len(alive)  # some slots dead, some alive
    np.testing.assert_array_equal(x, state.positions())
    np.testing.assert_array_equal(v, state.velocities())
    np.testing.assert_array_equal(alive, state.alive_mask())
    b = ta.Builder()
    b.add_particles(np.arange(12.0).reshape(4, 3), np.ones((4, 3)))
    still = b.finalize().state()
    x, v, alive = still.motion()
    np.testing.assert_array_equal(x, still.positions())
    np.testing.assert_array_equal(v, still.velocities())
    assert alive.all() and x.dtype == v.dtype == np.float64


def test_two_states_of_one_model_emit_independently():
    """The fractional-birth carry and the free-slot cursor belong to the state: stepping one state
    does not change what another state of the same model emits (rate 50/s at dt = 1/60: 0.83 per step,
    so the carry decides every step's count)."""
    model, a = fountain(rate=50.0, capacity=200, lifetime=10.0)
    integ = ta.make_integrator("symplectic_euler")
    for _ in range(7):
        integ.step(model, a, 1 / 60)
    b = model.state()
    counts = []
    for _ in range(6):
        integ.step(model, b, 1 / 60)
        counts.append(int(b.alive_mask().sum()))
    # floor(k * 50/60) particles after k steps, exactly as a fresh model's first state emits them
    assert counts == [int(k * 50 / 60 + 1e-9) for k in range(1, 7)]
    assert int(a.alive_mask().sum()) == int(7 * 50 / 60 + 1e-9)
