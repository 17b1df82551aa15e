"""A State owns its run: two states of one model, stepped in turn by one integrator, end bitwise where
each would alone (emission carry and cursor, adaptive step sizes, implicit warm starts), and the
NumPy access to a state reads and writes what the kernels see."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.errors import ParameterError


def _fountain():
    b = ta.Builder()
    b.add_force_gravity()
    # 3000.3 particles/s at 1/600 s: 5.0005 per step, so the fractional carry decides every 2000th birth
    b.add_particle_emitter(capacity=600, rate=3000.3, shape="disc", radius=0.1, speed=3.0, lifetime=0.15)
    b.add_collider_box((-1, 0, -1), (1, 3, 1), restitution=0.6, friction=0.1)
    return b.finalize(seed=1)


def _cloth():
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(origin=(0, 1, 0), size=(1, 1), resolution=(10, 10), pinned=[0, 9])
    return b.finalize()


def _two_runs(model, make, dt, steps, kick):
    """(alone, interleaved): the first state stepped alone by one integrator, and the same start stepped
    by another integrator in turn with a second state that starts differently (`kick` m/s upwards) and
    takes half-size steps, so anything the two runs shared would show."""
    alone = model.state()
    solo = make()
    for _ in range(steps):
        solo.step(model, alone, dt)
    a, b = model.state(), model.state()
    b.set_velocities(b.velocities() + [0.0, kick, 0.0])
    both = make()
    for _ in range(steps):
        both.step(model, a, dt)
        both.step(model, b, 0.5 * dt)
    return alone, a, b


@pytest.mark.parametrize(
    "case",
    # The adaptive methods' carry (11-16 s each on 2 cores) is slow; the emitter's and the implicit
    # solve's stay in the default suite.
    [
        "emitter",
        "implicit_warm_start",
        pytest.param("rk45_adaptive", marks=pytest.mark.slow),
        pytest.param("step_doubling", marks=pytest.mark.slow),
    ],
)
def test_two_states_of_one_model_evolve_independently(case):
    if case == "emitter":
        model, make, dt = _fountain(), lambda: ta.make_integrator("symplectic_euler"), 1 / 600
    elif case == "implicit_warm_start":
        model, dt = _cloth(), 1 / 100
        make = lambda: ta.make_integrator("implicit_euler", tol=1e-3)  # loose: the start point matters
    elif case == "rk45_adaptive":
        model, dt = _cloth(), 1 / 60
        make = lambda: ta.make_integrator("rk45", rtol=1e-3, atol=1e-4)
    else:
        model, dt = _cloth(), 1 / 120
        make = lambda: ta.IntegratorAdaptive("symplectic_euler", tol=1e-3)
    alone, a, b = _two_runs(model, make, dt, 30, kick=2.0)
    sa, sr = a.snapshot(), alone.snapshot()
    assert a.time == alone.time and a.step_count == alone.step_count
    assert np.array_equal(sa.index, sr.index)  # the same particles were born and died
    assert np.array_equal(sa.x, sr.x) and np.array_equal(sa.v, sr.v)
    # ... while the other run really was different (else the test could not fail)
    assert b.time == pytest.approx(0.5 * a.time)
    assert not np.array_equal(b.positions(), a.positions())
    if case == "emitter":
        # each state emitted rate x its own time: 3000.3/s x 0.05 s = 150 and x 0.025 s = 75 (none died yet)
        assert len(sa.index) == 150 and len(b.snapshot().index) == 75


def test_emission_carry_is_the_states():
    """Births per step follow floor(rate dt + carry) in each state, from its own carry."""
    model = _fountain()
    integ = ta.make_integrator("symplectic_euler")
    a, b = model.state(), model.state()
    for _ in range(7):
        integ.step(model, a, 1 / 600)
    integ.step(model, b, 1 / 600)
    # a: 7 steps of 5.0005 particles = 35.0035 -> 35 born, carry 0.0035; b: one step -> 5, carry 0.0005
    assert len(a.snapshot().x) == 35 and len(b.snapshot().x) == 5
    assert a.emit_carry[0] == pytest.approx(0.0035, abs=1e-9)
    assert b.emit_carry[0] == pytest.approx(0.0005, abs=1e-9)


def test_positions_and_velocities_round_trip_and_drive_the_step():
    model = _cloth()
    state = model.state()
    x = state.positions()
    assert x.shape == (100, 3) and x.dtype == np.float64
    # grid vertex (i, j) is j * 10 + i: row j = 0 is the first 10 vertices, along +x from the origin
    assert np.allclose(x[:10, 0], np.linspace(0, 1, 10)) and np.allclose(x[:10, 1], 1.0)
    lifted = x[[5, 6]] + [0.0, 0.1, 0.0]
    state.set_positions(lifted, indices=[5, 6])
    assert np.array_equal(state.positions()[[5, 6]], lifted)
    assert np.array_equal(state.positions()[[4, 7]], x[[4, 7]])
    v = np.zeros((100, 3))
    v[:, 2] = 0.5
    state.set_velocities(v)
    integ = ta.make_integrator("symplectic_euler")
    before = state.positions()
    integ.step(model, state, 1e-4)
    moved = state.positions() - before
    # a pinned vertex keeps the velocity it was given: 0.5 m/s along z for 1e-4 s, exactly
    assert np.allclose(moved[0], [0.0, 0.0, 0.5e-4], atol=1e-15)
    assert list(model.pinned_indices()) == [0, 9]


@pytest.mark.parametrize(
    "args, words",
    [
        ((np.zeros((99, 3)),), ["x", "(100, 3)", "(99, 3)"]),
        ((np.full((100, 3), np.nan),), ["x", "non-finite"]),
        ((np.zeros((2, 3)), [1, 100]), ["indices", "100"]),
        ((np.zeros((1, 3)), [1.5]), ["indices", "1.5"]),
    ],
)
def test_set_positions_rejects_bad_input_naming_it(args, words):
    state = _cloth().state()
    with pytest.raises(ParameterError) as err:
        state.set_positions(*args)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_spring_table_gives_the_model_springs_and_their_energy():
    model = _cloth()
    table = model.spring_table()
    n = 10
    # Provot's grid: structural 2 n (n-1), shear 2 (n-1)^2, bend 2 n (n-2)
    counts = np.bincount(table["family"], minlength=3)
    assert counts.tolist() == [2 * n * (n - 1), 2 * (n - 1) ** 2, 2 * n * (n - 2)]
    x = model.state().positions()
    x[:, 1] += np.linspace(0.0, 0.05, 100) ** 2  # a little strain
    i, j = table["pairs"].T
    length = np.linalg.norm(x[i] - x[j], axis=1)
    by_hand = 0.5 * np.sum(table["stiffness"] * (length - table["rest_length"]) ** 2)
    assert model.energy(x)["springs"] == pytest.approx(by_hand, rel=1e-12)
    # rest lengths are the rest shape's
    x0 = model.state().positions()
    assert np.allclose(table["rest_length"], np.linalg.norm(x0[i] - x0[j], axis=1))
