"""Hard cases for the divergence watchdog and the divergence policies (Stepper, watchdog.py).

Explosions that stay finite (an overflowing spring's force vanishes, the state sits near 1e25) must stop
with a DivergenceError naming the step, the particle, the quantity and its value, long before the
positions leave the watchdog's extent; energy growth is caught where the scene has an energy; normal
demos never trip it; the "retry" and "implicit" policies roll back and recover, recording what they did.
"""

import math

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.scenes import make_scene


def spring_pair():
    """The explosion example: a pinned particle and a 10 g particle on a k = 1e5 N/m spring, moving at
    1 m/s; at dt = 1/60 s, h w = 53 (symplectic Euler is stable only for h w < 2)."""
    b = ta.Builder()
    b.add_particles(np.array([[0, 0, 0], [0.1, 0, 0]]), np.array([[0, 0, 0], [1.0, 0, 0]]), mass=[0, 0.01])
    b.add_springs([[0, 1]], stiffness=1e5)
    model = b.finalize()
    return model, model.state()


def stiff_cloth(n: int = 32):
    """An n x n cloth (1 m, 0.2 kg/m^2) at stretch stiffness k = 1e4 N/m pinned at two corners, under
    gravity: at dt = 1/60 s every explicit method is far past its stability limit."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(
        origin=(-0.5, 1.0, -0.5),
        resolution=(n, n),
        material=ta.ClothMaterial(stretch_stiffness=1e4),
        pinned=[0, n - 1],
    )
    model = b.finalize()
    return model, model.state()


def test_spring_explosion_stops_early_naming_step_particle_quantity_value():
    """Pass: the issue's example (f32, symplectic Euler, dt = 1/60, 3000 steps requested) raises
    DivergenceError by step 5 (the speed bound: 10 x the scene's 1 m/s), naming particle 1, quantity
    "speed" and its value (above the limit), while |x| is still below the extent limit and finite (it
    reached ~6e25 without the watchdog); the message states step, particle and quantity."""
    ta.init("cpu", precision="f32")
    model, state = spring_pair()
    integ = ta.make_integrator("symplectic_euler")
    with pytest.raises(ta.DivergenceError) as err:
        for _ in range(3000):
            integ.step(model, state, 1 / 60)
    e = err.value
    watchdog = integ.stepper_for(model).watchdog
    lo, hi, speed = watchdog.limits_at(state.time)
    assert e.step == state.step_count <= 5
    assert e.particle == 1 and e.quantity == "speed" and e.value > speed
    assert f"step {e.step}" in str(e) and "particle 1" in str(e) and "speed" in str(e)
    x = state.positions()
    assert np.all(np.isfinite(x)) and np.all((lo < x) & (x < hi))


@pytest.mark.parametrize("method", ["symplectic_euler", "explicit_euler", "rk4"])
def test_stiff_cloth_explosion_stops_early(method):
    """Pass: a 32^2 cloth at k = 1e4 N/m, dt = 1/60 s (which reached max |x| = 2e27 after 2000 steps)
    raises DivergenceError within 10 steps for symplectic Euler, explicit Euler and RK4, naming a
    particle index in range and a finite value; positions are still finite and inside the extent limit
    (the explosion grows ~(h w)^2 = 1e4-fold per step, so one step can carry a vertex tens of metres)."""
    ta.init("cpu", precision="f32")
    model, state = stiff_cloth()
    integ = ta.make_integrator(method)
    with pytest.raises(ta.DivergenceError) as err:
        for _ in range(2000):
            integ.step(model, state, 1 / 60)
    e = err.value
    assert e.step == state.step_count <= 10
    assert 0 <= e.particle < model.particle_count and e.quantity in ("speed", "position")
    assert math.isfinite(e.value)
    lo, hi, _ = integ.stepper_for(model).watchdog.limits_at(state.time)
    x = state.positions()
    assert np.all(np.isfinite(x)) and np.all((lo < x) & (x < hi))
    print(f"{method}: stopped at step {e.step}, particle {e.particle}, {e.quantity} = {e.value:.3g}")


def _bead_run(integ, model, state, steps: int = 3000):
    """Step the spring example until it raises; the state after every step that returned, and the
    error."""
    good = [(state.positions(), state.velocities(), state.step_count, state.time)]
    with pytest.raises(ta.DivergenceError) as err:
        for _ in range(steps):
            integ.step(model, state, 1 / 60)
            good.append((state.positions(), state.velocities(), state.step_count, state.time))
    return good, err.value


@pytest.mark.parametrize("check_every", [1, 3])
def test_a_divergence_error_leaves_the_state_at_the_last_good_step(check_every):
    """Pass: the spring example (a bead on a stiff spring that explodes) under policy "raise" with
    keep_last_good: after the DivergenceError the state's positions, velocities, step count and time equal,
    bitwise, those after the last good step that was checked (the step before the bad one with
    check_every 1; the last multiple of 3 before it with check_every 3), the message says so, the watch
    is cleared (stepping on with a stable dt works and counts from there). Without the rollback the
    state held the bad step (the bead at 468 m/s, step 2), as it still does by default (checked below)."""
    ta.init("cpu", precision="f32")
    model, state = spring_pair()
    keep = {"keep_last_good": True}
    integ = ta.make_integrator("symplectic_euler", check_every=check_every, policy=keep)
    good, e = _bead_run(integ, model, state)
    last = (e.step - 1) // check_every * check_every  # the last checked step before the bad one
    x, v, count, t = good[last]
    assert e.step >= 2 and state.step_count == count == last and state.time == t
    assert np.array_equal(state.positions(), x) and np.array_equal(state.velocities(), v)
    assert f"left at the last good step checked, step {last}" in str(e)
    assert np.abs(state.velocities()).max() < 10.0  # not the exploding step
    assert int(state.nonfinite_count[None]) == 0
    integ.step(model, state, 1e-5)  # h w = 0.03: stable
    assert state.step_count == last + 1
    # By default no copy is kept: the state holds the bad step, and the message says how to keep one.
    model, state = spring_pair()
    good, e = _bead_run(ta.make_integrator("symplectic_euler", check_every=check_every), model, state)
    # (with check_every 3 the watch is read at step 3, after the bad step 2 and one more)
    assert state.step_count == (e.step + check_every - 1) // check_every * check_every
    assert "keep_last_good=True" in str(e)


def test_energy_growth_is_caught_before_the_speed_bound():
    """Pass: explicit Euler on an undamped anchor spring at h w = 0.3 grows the energy by 1 + (h w)^2
    = 1.09 per step, slowly enough that the speed bound (10 x v_ref, 100 x the energy) is not reached
    first: with the energy evaluated every 10 steps the run stops with quantity "energy" by step 40, the
    reported energy exceeds the start by more than the allowed gain (10 x the energy scale) and the
    closed-form growth (1.09^step) agrees with the reported value within 1%."""
    ta.init("cpu", precision="f64")
    k, m = 100.0, 1.0
    h = 0.3 / math.sqrt(k / m)
    b = ta.Builder()
    b.add_particle((10.5, 0.0, 0.0), mass=m)
    b.add_force_anchor_spring(0, (0.0, 0.0, 0.0), stiffness=k, rest_length=10.0)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator("explicit_euler")
    integ.stepper_for(model).watchdog.configure(energy_every=10)
    e0 = 0.5 * k * 0.5**2
    with pytest.raises(ta.DivergenceError) as err:
        for _ in range(200):
            integ.step(model, state, h)
    e = err.value
    assert e.quantity == "energy" and e.step <= 40 and e.particle is None
    allowed = integ.stepper_for(model).watchdog.energy_limit()
    assert e.value > e0 + allowed
    # Forward Euler on a linear oscillator: E_n = (1 + (h w)^2)^n E_0 exactly (radial motion here).
    assert e.value == pytest.approx(e0 * 1.09**e.step, rel=1e-2)


@pytest.mark.parametrize(
    "name, options, frames",
    [
        ("drape", {"resolution": 16, "integrator": "symplectic_euler"}, 40),
        ("drape", {"resolution": 16, "integrator": "explicit_euler"}, 20),
        ("cloth", {"resolution": 16, "integrator": "rk4"}, 30),
        ("cloth", {"resolution": 16}, 15),
        ("fountain", {"particles": 2000}, 30),
    ],
)
def test_no_false_positive_on_demos(name, options, frames):
    """Pass: the drape (symplectic and explicit Euler), cloth (RK4 and its implicit default) and fountain
    demos, small, run `frames` frames (through the ball contact, the swing, the fountain's bounces)
    with the energy evaluated at every check, and no bound is broken."""
    ta.init("cpu", precision="f32")
    scene = make_scene(name, **options)
    stepper = scene.integrator.stepper_for(scene.model)
    stepper.watchdog.configure(energy_every=1)
    for _ in range(frames):
        scene.advance_frame()
        stepper.check(scene.state)
    assert int(scene.state.nonfinite_count[None]) == 0


def test_retry_policy_recovers_the_spring_example():
    """Pass: with policy divergence="retry" (max_retries 6) the spring example runs 120 steps without
    error: the first step stores 14 J in the spring (0.005 J at the start) before anything moves fast, the
    energy (evaluated every step under a recovering policy) trips, and the step is rolled back and redone
    in 32 substeps (h w = 1.65 < 2, the first stable halving), which is recorded as one
    "divergence_recovered" event (method, substeps, quantity "energy") and kept for the following steps;
    the spring length stays within 1 cm of its rest length and the energy within symplectic Euler's
    bounded swing, |E - E0| <= 2a / (1 - a) E0 with a = h w / 2 of the substep (no growth)."""
    ta.init("cpu", precision="f64")
    model, state = spring_pair()
    integ = ta.make_integrator("symplectic_euler", policy={"divergence": "retry", "max_retries": 6})
    for _ in range(120):
        integ.step(model, state, 1 / 60)
    health = integ.stepper_for(model).health.to_dict()
    events = [e for e in health["events"] if e["kind"] == "divergence_recovered"]
    assert len(events) == 1 and events[0]["step"] == 1
    assert events[0]["substeps"] == 32 and events[0]["method"] == "symplectic_euler"
    assert events[0]["quantity"] == "energy"
    x = state.positions()
    v = state.velocities()
    assert state.step_count == 120 and abs(np.linalg.norm(x[1] - x[0]) - 0.1) < 0.01
    # The modified energy of symplectic Euler bounds the swing: |E - E0| <= a / (1 - a) E0, a = h w / 2.
    a = 0.5 * math.sqrt(1e5 / 0.01) / 60 / 32
    energy = 0.5 * 0.01 * v[1] @ v[1] + 0.5 * 1e5 * (np.linalg.norm(x[1] - x[0]) - 0.1) ** 2
    assert abs(energy - 0.005) <= 2 * a / (1 - a) * 0.005


def test_retry_policy_gives_up_and_leaves_the_last_good_state():
    """Pass: with max_retries 2 (4 substeps: h w = 13, still unstable) the step is not recovered: a
    DivergenceError says so, names the step, and the state is left at the step's start, bitwise the
    initial state (nothing after the last good state survives)."""
    ta.init("cpu", precision="f64")
    model, state = spring_pair()
    x0, v0 = state.positions(), state.velocities()
    # stability "ignore": no estimate, so no stable substep count to fall back on (see the next test)
    policy = {"divergence": "retry", "max_retries": 2, "stability": "ignore"}
    integ = ta.make_integrator("symplectic_euler", policy=policy)
    with pytest.raises(ta.DivergenceError, match="not recovered") as err:
        integ.step(model, state, 1 / 60)
    assert err.value.step == 1 and state.step_count == 0 and state.time == 0.0
    assert np.array_equal(state.positions(), x0) and np.array_equal(state.velocities(), v0)


def test_retry_takes_the_stable_substep_count_when_halvings_run_out():
    """Pass: with max_retries 2 (2 and 4 substeps, both unstable) but the stability guard's estimate at
    hand, the retry policy redoes the step in ceil(dt / (0.8 x limit)) substeps, symplectic Euler's limit
    being 2 / w with w = sqrt(k / m): the step recovers, with that count recorded."""
    ta.init("cpu", precision="f64")
    model, state = spring_pair()
    integ = ta.make_integrator("symplectic_euler", policy={"divergence": "retry", "max_retries": 2})
    with pytest.warns(ta.StabilityWarning):
        integ.step(model, state, 1 / 60)
    events = integ.stepper_for(model).health.to_dict()["events"]
    recovered = [e for e in events if e["kind"] == "divergence_recovered"]
    limit = 2.0 / math.sqrt(1e5 / 0.01)
    assert len(recovered) == 1 and recovered[0]["substeps"] == math.ceil((1 / 60) / (0.8 * limit))
    assert state.step_count == 1 and abs(np.linalg.norm(np.diff(state.positions(), axis=0)) - 0.1) < 0.01


def test_a_solver_giving_up_under_a_recovering_policy_leaves_the_last_good_state():
    """Pass: RK45 capped at 3 rejections per step on the spring example, with policy nonconvergence =
    "raise" and divergence = "retry": the ConvergenceError propagates and the state is bitwise the state
    before the step (no half-done emission, substeps or time)."""
    ta.init("cpu", precision="f64")
    model, state = spring_pair()
    x0, v0 = state.positions(), state.velocities()
    policy = {"divergence": "retry", "nonconvergence": "raise", "stability": "ignore"}
    integ = ta.make_integrator("rk45", max_rejected=3, policy=policy)
    with pytest.raises(ta.ConvergenceError):
        integ.step(model, state, 1 / 60)
    assert state.step_count == 0 and state.time == 0.0
    assert np.array_equal(state.positions(), x0) and np.array_equal(state.velocities(), v0)


def test_implicit_fallback_recovers_and_records_it():
    """Pass: with policy divergence="implicit" the spring example runs 120 steps: the first step is redone
    with implicit Euler in one step (recorded once as "divergence_recovered", method implicit_euler), the
    spring stays within 1 cm of its rest length and the energy does not grow (backward Euler only
    dissipates on a linear spring)."""
    ta.init("cpu", precision="f64")
    model, state = spring_pair()
    integ = ta.make_integrator("symplectic_euler", policy={"divergence": "implicit"})
    for _ in range(120):
        integ.step(model, state, 1 / 60)
    events = [e for e in integ.stepper_for(model).health.events if e["kind"] == "divergence_recovered"]
    assert len(events) == 1 and events[0]["method"] == "implicit_euler" and events[0]["substeps"] == 1
    x = state.positions()
    v = state.velocities()
    assert abs(np.linalg.norm(x[1] - x[0]) - 0.1) < 0.01
    energy = 0.5 * 0.01 * v[1] @ v[1] + 0.5 * 1e5 * (np.linalg.norm(x[1] - x[0]) - 0.1) ** 2
    assert energy <= 0.005 * (1 + 1e-9)


def test_rollback_restores_every_dynamic_field():
    """Pass: a scene with an emitter (lifetimes, free-slot bits, emission carry and cursor), trails and
    gravity is saved, stepped 7 steps, restored and stepped the same 7 steps again: positions,
    velocities, birth and death times, trails, time and step count equal the first pass bitwise."""
    ta.init("cpu", precision="f32")
    b = ta.Builder()
    b.add_force_gravity()
    b.add_particle_emitter(capacity=64, rate=300.0, speed=3.0, spread=0.4, lifetime=0.05)
    b.add_collider_plane(offset=-0.05)
    b.add_particle_trails(4)
    model = b.finalize(seed=5)
    state, backup = model.state(), model.state()
    integ = ta.make_integrator("symplectic_euler")
    for _ in range(5):
        integ.step(model, state, 1 / 120)

    def run():
        for _ in range(7):
            integ.step(model, state, 1 / 120)
        snap = state.snapshot()
        return snap, state.trail.to_numpy(), state.particle_death.to_numpy(), state.time, state.step_count

    state.save(backup)
    first = run()
    state.restore(backup)
    second = run()
    for a, b_ in zip(first[0].__dict__.values(), second[0].__dict__.values(), strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b_))
    assert np.array_equal(first[1], second[1]) and np.array_equal(first[2], second[2])
    assert first[3:] == second[3:]


def test_overrides_and_bad_values():
    """Pass: a fixed speed limit below the motion trips on the first step (quantity speed, the limit in
    the message); a fixed extent box that excludes a particle trips with quantity position; turning every
    bound off (math.inf) lets the spring run; bad values raise ParameterError naming the option."""
    ta.init("cpu", precision="f64")
    model, state = spring_pair()
    integ = ta.make_integrator("symplectic_euler")
    wd = integ.stepper_for(model).watchdog
    wd.configure(speed=0.5)
    with pytest.raises(ta.DivergenceError, match=r"limit 0.5 m/s") as err:
        integ.step(model, state, 1e-5)
    assert err.value.quantity == "speed" and err.value.particle == 1

    model, state = spring_pair()
    integ = ta.make_integrator("symplectic_euler")
    integ.stepper_for(model).watchdog.configure(extent=((-1, -1, -1), (0.05, 1, 1)))
    with pytest.raises(ta.DivergenceError) as err:
        integ.step(model, state, 1e-5)
    assert err.value.quantity == "position" and err.value.particle == 1

    model, state = spring_pair()
    integ = ta.make_integrator("symplectic_euler")
    wd = integ.stepper_for(model).watchdog
    wd.configure(extent=math.inf, speed=math.inf, energy_tolerance=math.inf)
    for _ in range(5):
        integ.step(model, state, 1 / 60)
    with pytest.raises(ta.ParameterError, match="speed"):
        wd.configure(speed=-1.0)
    with pytest.raises(ta.ParameterError, match="extent"):
        wd.configure(extent=((0, 0, 0), (0, 1, 1)))
    with pytest.raises(ta.ParameterError, match="energy_every"):
        wd.configure(energy_every=0)
