"""Bad input gets a clear error naming the parameter and value; a diverging run stops with one."""

import math
import subprocess
import sys

import numpy as np
import pytest

import taichi_anim as ta

from .helpers import spring_particle


def test_import_does_not_initialise_taichi():
    code = "import taichi_anim as ta; assert not ta.is_initialized(); print('ok')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().endswith("ok")


def test_init_rejects_unknown_arch_and_precision():
    with pytest.raises(ta.ParameterError, match="unknown arch 'tpu'"):
        ta.init("tpu")
    with pytest.raises(ta.ParameterError, match="precision"):
        ta.init("cpu", precision="f16")
    assert ta.init("cpu") == "cpu"


@pytest.mark.parametrize("dt", [0.0, -0.01, float("nan"), float("inf")])
def test_non_positive_or_non_finite_dt_is_rejected(dt):
    model, state = spring_particle(k=1.0)
    with pytest.raises(ta.ParameterError, match=f"dt must be a finite number > 0, got {dt!r}"):
        ta.IntegratorRK4().step(model, state, dt)


def test_unknown_integrator_and_collision_mode():
    with pytest.raises(
        ta.ParameterError, match="unknown integrator 'leapfrog'; choose one of: explicit_euler"
    ):
        ta.make_integrator("leapfrog")
    with pytest.raises(ta.ParameterError, match="unknown collision_mode 'teleport'"):
        ta.IntegratorSymplecticEuler(collision_mode="teleport")


def test_nan_in_initial_state_is_rejected():
    b = ta.Builder()
    with pytest.raises(ta.ParameterError, match=r"v contains 1 non-finite values \(first at index \(1, 2\)"):
        b.add_particles(np.zeros((3, 3)), v=[[0, 0, 0], [0, 0, np.inf], [0, 0, 0]])


def test_box_with_inverted_corners_is_rejected():
    with pytest.raises(ta.ParameterError, match="hi must exceed lo"):
        ta.Builder().add_collider_box((0, 0, 0), (1, -1, 1))


def test_diverging_explicit_euler_stops_at_the_first_bad_step_naming_particle_and_quantity():
    # Explicit Euler on a stiff spring grows the energy by 1 + (h w)^2 = 1e4 per step: the watchdog's
    # speed bound (10 x the 2240 m/s the springs' initial energy can give a particle) trips within a few
    # steps, long before float32 overflows (~20 steps); the run stops at that step and names it, the
    # lowest particle that broke a bound, the quantity and its value.
    ta.init("cpu", precision="f32")
    b = ta.Builder()
    b.add_particles([[11.0, 0, 0], [12.0, 0, 0]])
    b.add_force_anchor_spring(0, (0, 0, 0), stiffness=1e6, rest_length=10.0)
    b.add_force_anchor_spring(1, (0, 0, 0), stiffness=1e6, rest_length=10.0)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator("explicit_euler")
    with pytest.raises(
        ta.DivergenceError, match=r"diverged at step (\d+): particle 0 reached a speed"
    ) as err:
        for _ in range(200):
            integ.step(model, state, 0.1)
    e = err.value
    assert e.step == state.step_count and e.step < 10
    assert e.particle == 0 and e.quantity == "speed"
    v = state.velocities()
    assert e.value == pytest.approx(np.linalg.norm(v[0]), rel=1e-6) and np.all(np.isfinite(v))


def test_nonfinite_state_names_the_quantity():
    # With every bound switched off, only the non-finite test is left: a NaN velocity put in by hand is
    # reported as quantity "velocity" of that particle at the step it was finished.
    model, state = spring_particle(k=1.0)
    integ = ta.IntegratorSymplecticEuler()
    integ.stepper_for(model).watchdog.configure(extent=math.inf, speed=math.inf, energy_tolerance=math.inf)
    integ.step(model, state, 0.01)
    state.particle_v[0] = [float("nan"), 0.0, 0.0]
    with pytest.raises(ta.DivergenceError, match="step 2: particle 0 reached a non-finite") as err:
        integ.step(model, state, 0.01)
    assert err.value.quantity in ("position", "velocity") and err.value.particle == 0


def test_rk45_reports_step_size_underflow():
    model, state = spring_particle(k=1e12)
    integ = ta.IntegratorRK45(atol=1e-12, h_min=1e-6)
    with pytest.raises(ta.DivergenceError, match="fell below h_min"):
        integ.step(model, state, 0.1)
