"""Hard cases for honest solves: a linear solve that stops at its iteration cap is counted, warned and
raised by policy; RK45 and step doubling on stiff cloth stop quickly with a message instead of taking
thousands of rejected substeps; Newton with a line search removes the energy gain of the linearised
implicit step on stiff springs.

Each test's pass criterion is in its docstring.
"""

import time

import numpy as np
import pytest

import taichi_anim as ta

G = np.array([0.0, -9.81, 0.0])


def stiff_cloth(n, scale):
    """An n x n, 1 m cloth pinned at two corners with every spring family at `scale` x the default
    stiffness (stretch 1e3 N/m x scale), damped, under gravity: stiff at dt = 1/60 s for scale >= 10."""
    material = ta.ClothMaterial(
        stretch_stiffness=1e3 * scale,
        stretch_damping=0.05,
        shear_stiffness=1e2 * scale,
        shear_damping=0.01,
        bend_stiffness=10.0 * scale,
        bend_damping=0.005,
    )
    b = ta.Builder()
    b.add_cloth_grid(
        origin=(0, 1, 0), size=(1.0, 1.0), resolution=(n, n), material=material, pinned=[0, n - 1]
    )
    b.add_force_gravity(G)
    return b.finalize()


def energy(model, x, v):
    """E = sum m v^2 / 2 - sum m g.x + sum_s k (l - L)^2 / 2 [J]."""
    m = model.particle_masses()
    sp = model.springs
    length = np.linalg.norm(x[sp.pairs[:, 0]] - x[sp.pairs[:, 1]], axis=1)
    return (
        0.5 * np.sum(m * np.sum(v * v, axis=1))
        - np.sum(m * (x @ G))
        + 0.5 * np.sum(sp.stiffness * (length - sp.rest_length) ** 2)
    )


def test_pcg_at_its_cap_is_counted_warned_and_raised_by_policy():
    """Pass: on a 16x16 cloth at k = 1e5 N/m, dt = 1/60 s with PCG capped at 20 iterations, every step's
    solve that ends at the cap above tol is counted in Health ("linear_unconverged"; the count equals the
    number of steps whose `last_solve` has iterations == 20 and residual > tol, checked step by step), a
    single SolverWarning names the cap and the step, and under nonconvergence="raise" the first such
    solve raises ConvergenceError."""
    model = stiff_cloth(16, 100.0)
    state = model.state()
    integ = ta.IntegratorImplicitEuler(max_iterations=20)
    capped = []
    with pytest.warns(ta.SolverWarning, match=r"stopped at its cap of 20 iterations at step \d+") as warned:
        for _ in range(20):
            integ.step(model, state, 1 / 60)
            last = integ.last_solve
            capped.append(last.iterations == 20 and last.residual > 1e-4)
    health = integ.stepper_for(model).health
    assert len([w for w in warned if issubclass(w.category, ta.SolverWarning)]) == 1
    assert health.counts["linear_solves"] == 20
    assert health.counts["linear_unconverged"] == sum(capped) > 0
    steps = [e["step"] for e in health.events if e["kind"] == "linear_unconverged"]
    assert steps == [k + 1 for k, c in enumerate(capped) if c]
    assert health.to_dict()["counts"]["linear_unconverged"] == sum(capped)

    strict = ta.IntegratorImplicitEuler(max_iterations=20, policy={"nonconvergence": "raise"})
    state = model.state()
    with pytest.raises(ta.ConvergenceError, match="cap of 20 iterations"):
        for _ in range(20):
            strict.step(model, state, 1 / 60)


@pytest.mark.parametrize("name, cap", [("rk45", 10), ("adaptive", 3)])
def test_adaptive_methods_on_stiff_cloth_stop_quickly_with_a_message(name, cap):
    """Pass: a 6x6 cloth at k = 1e5 N/m stepped by dt = 1/60 s (about 300x its explicit stability limit)
    ends its first step with DivergenceError within 30 s, wall clock including compilation (without the
    cap RK45 spent ~30 s per step on a 32x32 cloth at k = 1e4 and did not stop); the message names the
    step, the time, the step size reached and the counts; Health holds exactly max_rejected + 1 rejected
    substeps (caps 10 for RK45, 3 for step doubling, which halves h per rejection) and an
    "adaptive_failed" event; under nonconvergence="raise" it is ConvergenceError."""
    model = stiff_cloth(6, 100.0)
    state = model.state()
    integ = ta.make_integrator(name, max_rejected=cap)
    start = time.perf_counter()
    with pytest.raises(ta.DivergenceError) as err:
        integ.step(model, state, 1 / 60)
    elapsed = time.perf_counter() - start
    message = str(err.value)
    print(f"{elapsed:.2f} s: {message}")
    assert elapsed < 30.0
    assert "step 1 (t=" in message and f"{cap + 1} rejected" in message and "h reached" in message
    assert err.value.step == 1 and err.value.quantity == "step_size" and 0 < err.value.value < 1 / 60
    health = integ.stepper_for(model).health
    assert health.counts["substeps_rejected"] == cap + 1 and integ.rejected == cap + 1
    assert health.counts["substeps_accepted"] == integ.accepted
    assert health.counts["adaptive_failed"] == 1 and health.events[-1]["kind"] == "adaptive_failed"

    strict = ta.make_integrator(name, max_rejected=cap, policy={"nonconvergence": "raise"})
    with pytest.raises(ta.ConvergenceError, match=f"max_rejected={cap}"):
        strict.step(model, model.state(), 1 / 60)


def test_newton_line_search_gains_no_energy_on_stiff_springs():
    """Pass: a 16x16 cloth at k = 1e5 N/m falling from rest at dt = 1/60 s for 30 steps (the window
    where the linearised step gains energy): the linearised step's energy exceeds its start by more than
    the slack 1e-3 W L (W the weight, L = 1 m; so the case is hard), while Newton with the line search
    (10 iterations, newton_tol 1e-2) never exceeds E_0 + 1e-3 W L at any step."""
    model = stiff_cloth(16, 100.0)
    m = model.particle_masses()
    slack = 1e-3 * m.sum() * 9.81 * 1.0
    excess = {}
    for label, options in (("linear", {}), ("newton", {"newton_iterations": 10, "line_search": True})):
        state = model.state()
        integ = ta.IntegratorImplicitEuler(policy={"nonconvergence": "ignore"}, **options)
        x = state.positions()
        e0 = energy(model, x, np.zeros_like(x))
        worst = -np.inf
        for _ in range(30):
            integ.step(model, state, 1 / 60)
            worst = max(worst, energy(model, state.positions(), state.velocities()) - e0)
        excess[label] = worst
        if label == "newton":
            counts = integ.stepper_for(model).health.counts
            assert counts["newton_solves"] == 30 and counts["newton_iterations"] >= 30
    print(f"max E - E0: {excess}, slack {slack:.3g} J")
    assert excess["linear"] > slack
    assert excess["newton"] <= slack
