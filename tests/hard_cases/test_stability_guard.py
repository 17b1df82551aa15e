"""Hard cases of the stability guard on the cloth that explodes silently: a 32 x 32 sheet (1 m, 0.2 kg/m²,
stretch springs k = 1e4 N/m, the other families at their defaults), pinned at two corners, under
gravity, stepped at dt = 1/60 s by symplectic Euler — about 180 times its stability limit."""

import warnings

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim import stability

FRAME_DT = 1 / 60


def stiff_cloth(n=32, k=1e4):
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(
        origin=(0.0, 1.0, 0.0),
        size=(1.0, 1.0),
        resolution=(n, n),
        plane="xz",
        material=ta.ClothMaterial(stretch_stiffness=k),
        pinned=[0, n - 1],
    )
    return b.finalize()


def total_energy(model, state):
    """Kinetic + spring + gravitational energy [J] (gravity along -y, 9.81 m/s²)."""
    x = state.positions().astype(np.float64)
    v = state.velocities().astype(np.float64)
    m = model.particle_masses()
    return 0.5 * np.sum(m[:, None] * v * v) + model.springs.energy(x) + 9.81 * np.sum(m * x[:, 1])


def test_warns_at_frame_step():
    """Pass: the first step at dt = 1/60 s raises one StabilityWarning naming the method, the step, the
    limit and the remedies (substeps, implicit Euler); the run summary counts the event with dt, limit
    and omega, and the limit lies below 1/60 s by more than 100x."""
    model = stiff_cloth()
    state = model.state()
    integ = ta.make_integrator("symplectic_euler")
    expected = r"symplectic_euler: dt = 0\.0167 s .*substeps.*implicit_euler"
    with pytest.warns(ta.StabilityWarning, match=expected):
        integ.step(model, state, FRAME_DT)
    health = integ.stepper_for(model).health.to_dict()
    assert health["counts"]["unstable_step"] == 1
    event = health["events"][0]
    assert event["dt"] == FRAME_DT and event["limit"] < FRAME_DT / 100 and event["omega"] > 1e4


def test_raises_under_policy():
    """Pass: with policy stability="raise" the same step raises StabilityError before the state moves."""
    model = stiff_cloth()
    state = model.state()
    x0 = state.positions()
    integ = ta.make_integrator("symplectic_euler", policy={"stability": "raise"})
    with pytest.raises(ta.StabilityError, match="stability limit"):
        integ.step(model, state, FRAME_DT)
    np.testing.assert_array_equal(state.positions(), x0)


@pytest.mark.parametrize("case", ["stable_dt", "implicit_euler", "ignore"])
def test_no_warning(case):
    """Pass: no StabilityWarning (warnings are errors here) for symplectic Euler at half its limit, for
    implicit Euler at 1/60 s (the guard called directly: an implicit step of this cloth costs seconds),
    or under policy stability="ignore" (no event recorded either)."""
    model = stiff_cloth()
    state = model.state()
    if case == "stable_dt":
        integ = ta.make_integrator("symplectic_euler")
        dt = 0.5 * stability.stability_limit("symplectic_euler", *_top(model, state))
    elif case == "implicit_euler":
        integ, dt = ta.make_integrator("implicit_euler", tol=1e-3), FRAME_DT
    else:
        integ, dt = ta.make_integrator("symplectic_euler", policy={"stability": "ignore"}), FRAME_DT
    with warnings.catch_warnings():
        warnings.simplefilter("error", ta.StabilityWarning)
        if case == "implicit_euler":
            stability.guard(integ.stepper_for(model), state, dt)
        else:
            integ.step(model, state, dt)
    assert integ.stepper_for(model).health.counts["unstable_step"] == 0


def _top(model, state):
    est = stability.state_frequency(model, state)
    return est.omega, est.zeta


def test_auto_substeps_keep_it_stable():
    """Pass: with auto_substeps the sheet runs 6 frames (1/60 s each) without a StabilityWarning or a
    DivergenceError, its total energy (kinetic + springs + gravity) never exceeds its start plus
    0.01 M g (1 m) and no vertex moves faster than 10 m/s; the same 6 frames at one step per frame end
    non-finite, beyond 1 km or with energy gain above 1 MJ (the explosion the guard warns about)."""
    model = stiff_cloth()
    mass = model.particle_masses().sum()
    state = model.state()
    integ = ta.make_integrator("symplectic_euler", check_every=50)
    n, record = stability.auto_substeps(model, integ, FRAME_DT, state=state)
    assert record["substeps"] == n and n > 100
    e0 = total_energy(model, state)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ta.StabilityWarning)
        for _ in range(6):
            for _ in range(n):
                integ.step(model, state, FRAME_DT / n)
            integ.stepper_for(model).check(state)
            assert total_energy(model, state) <= e0 + 0.01 * mass * 9.81
            assert np.linalg.norm(state.velocities(), axis=1).max() < 10.0

    fixed = model.state()
    integ = ta.make_integrator("symplectic_euler", policy={"stability": "ignore"}, check_every=10**9)
    for _ in range(6):
        integ.step(model, fixed, FRAME_DT)
    x = fixed.positions()
    exploded = not np.all(np.isfinite(x)) or np.abs(x).max() > 1e3 or total_energy(model, fixed) > e0 + 1e6
    assert exploded
