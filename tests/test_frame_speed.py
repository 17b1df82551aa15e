"""A frame in few launches (Stepper.advance / frame_mode) and integrator="auto" (integrators/choice.py).

Fused frames must be the same computation as step-by-step stepping: states equal to round-off for
forces that do not depend on time, the same divergence verdict, the same counters; the automatic method
choice must pick the stable method with the fewest force evaluations per frame, which on an oscillator
has a closed-form answer."""

import math

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim import DivergenceError, ParameterError
from taichi_anim.integrators.choice import choose_integrator, implicit_iterations, make_chosen
from taichi_anim.scenes import make_scene
from taichi_anim.scenes.runner import run_scene
from taichi_anim.stability import AUTO_SAFETY

from .helpers import ulp_tolerance


def _sheet(n: int = 12, *, stiffness: float = 1e3, colliders: bool = True, drag: bool = True):
    b = ta.Builder()
    b.add_cloth_grid(
        origin=(-0.5, 1.0, -0.5),
        size=(1.0, 1.0),
        resolution=(n, n),
        plane="xz",
        pinned=[0, n - 1],
        material=ta.ClothMaterial(
            density=0.2, stretch_stiffness=stiffness, shear_stiffness=stiffness, bend_stiffness=stiffness
        ),
    )
    b.add_force_gravity()
    if drag:
        b.add_force_drag(1e-4)
    if colliders:
        b.add_collider_plane(normal=(0.0, 1.0, 0.0), offset=0.3, friction=0.2)
        b.add_collider_sphere((0.1, 0.5, 0.0), 0.25, friction=0.3)
    return b.finalize()


def _run(mode: str | None, method: str, h: float, frames: int, substeps: int, **sheet):
    model = _sheet(**sheet)
    state = model.state()
    integ = ta.make_integrator(method, check_every=7)
    stepper = integ.stepper_for(model)
    if mode is None:  # step by step, the reference
        for _ in range(frames * substeps):
            stepper.step(state, h)
    else:
        stepper._frame_mode = {"mode": mode, "reason": "test"}
        for _ in range(frames):
            stepper.advance(state, h, substeps)
    return state, stepper


@pytest.mark.parametrize(
    "mode, method",
    [(m, e) for m in ("serial_frame", "launches") for e in ("symplectic_euler", "explicit_euler")]
    + [("parallel_frame", "symplectic_euler")],  # the default pass and update only (parallel_frame.py)
)
def test_fused_frames_equal_step_by_step(mode, method):
    """Springs, drag, a plane and a sphere with friction: 3 frames of 16 substeps equal 48 single steps
    to round-off, with the same time, step count and evaluation count.

    The fused frame and the single step are different kernels built from the same functions; LLVM may
    contract or vectorise their arithmetic differently, so the states agree within the roundings of 48
    steps (`ulp_tolerance` per step, at the state's scale), not bit for bit."""
    h = 2e-4 if method == "symplectic_euler" else 2e-5
    ref, ref_stepper = _run(None, method, h, 3, 16)
    got, got_stepper = _run(mode, method, h, 3, 16)
    for name in ("particle_x", "particle_v"):
        want = getattr(ref, name).to_numpy()
        tol = ulp_tolerance(np.abs(want).max(), 64 * 48)
        np.testing.assert_allclose(getattr(got, name).to_numpy(), want, rtol=0, atol=tol)
    assert got.step_count == ref.step_count == 48 and got.time == ref.time
    assert got_stepper.integrator.evaluations == ref_stepper.integrator.evaluations
    # Not a trivial comparison: the sheet moved, and not as one rigid fall (the pins and springs acted).
    moved = np.abs(ref.positions() - _sheet().state().positions()).max()
    assert moved > 1e-6 and np.ptp(ref.velocities()[:, 1]) > 1e-4


def test_frame_mode_is_chosen_by_size_and_needs():
    small = _sheet(8)
    stepper = ta.make_integrator("symplectic_euler").stepper_for(small)
    assert stepper.frame_mode()["mode"] == "serial_frame"
    assert str(small.work) in stepper.frame_mode()["reason"]
    # A multi-stage method prepares stages between substeps: stepped one by one, and it says why.
    rk4 = ta.make_integrator("rk4").stepper_for(_sheet(8))
    assert rk4.frame_mode()["mode"] == "steps" and "rk4" in rk4.frame_mode()["reason"]
    # So does a recovering divergence policy (a rollback point per step).
    retry = ta.make_integrator("symplectic_euler", policy={"divergence": "retry"}).stepper_for(_sheet(8))
    assert retry.frame_mode()["mode"] == "steps" and "rollback" in retry.frame_mode()["reason"]
    # Particles that do not act on each other go through the frame one by one, emitters' births planned
    # first and trails written per particle (tests/test_blocked_frame.py); sphere contacts act between
    # substeps.
    for contacts, want in ((False, "blocked"), (True, "steps")):
        b = ta.Builder()
        b.add_particle_emitter(capacity=64, rate=100.0)
        b.add_particle_trails(4)
        b.add_force_gravity()
        if contacts:
            b.add_particles([[0.0, 0.0, 0.0]], radius=0.01)
            b.add_sphere_contacts()
        mode = ta.make_integrator("symplectic_euler").stepper_for(b.finalize()).frame_mode()
        assert mode["mode"] == want, mode
    assert "contacts" in mode["reason"]


def test_fused_frame_stops_at_the_step_that_diverged():
    """k = 1e6 N/m at h = 2e-3 s is far beyond symplectic Euler's limit: the fused frame raises the same
    DivergenceError (same step and particle) as step-by-step stepping."""
    errors = []
    for mode in (None, "serial_frame"):
        with pytest.raises(DivergenceError) as info:
            _run(mode, "symplectic_euler", 2e-3, 2, 8, stiffness=1e6, colliders=False)
        errors.append(info.value)
    assert errors[0].step <= 8 and errors[1].step == errors[0].step
    assert errors[1].particle == errors[0].particle and errors[1].quantity == errors[0].quantity


def test_advance_rejects_bad_counts():
    stepper = ta.make_integrator("symplectic_euler").stepper_for(_sheet(6))
    state = stepper.model.state()
    with pytest.raises(ParameterError, match="substeps"):
        stepper.advance(state, 1e-3, 0)
    with pytest.raises(ParameterError, match="dt"):
        stepper.step(state, -1.0, 4)


def _oscillator(k: float, c: float, m: float = 0.5):
    """A particle on a spring to a pinned one: omega = sqrt(k / m), damping ratio c / (2 sqrt(k m))."""
    b = ta.Builder()
    b.add_particles([[0.0, 0.0, 0.0], [1.1, 0.0, 0.0]], mass=[0.0, m])
    b.add_springs([[0, 1]], stiffness=k, damping=c, rest_length=1.0)
    return b.finalize()


def test_auto_choice_on_an_oscillator_matches_the_closed_form():
    """Undamped: symplectic Euler is stable for h < 2 / omega (Hairer et al., I.1.2), so it needs
    ceil(frame_dt omega / (2 AUTO_SAFETY)) substeps; RK4 (limit 2 sqrt(2) / omega) costs 4 evaluations
    per substep; implicit Euler with one particle converges in one CG iteration. The cheapest is chosen."""
    k, m, frame_dt = 1e4, 0.5, 1 / 60
    omega = math.sqrt(k / m)
    choice = choose_integrator(_oscillator(k, 0.0, m), frame_dt, candidates=("symplectic_euler", "rk4"))
    n = math.ceil(frame_dt * omega / (2 * AUTO_SAFETY))
    assert choice.omega == pytest.approx(omega, rel=1e-6)
    assert choice.name == "symplectic_euler" and choice.substeps == n
    assert choice.candidates["rk4"]["substeps"] == pytest.approx(n / math.sqrt(2), abs=1.01)
    assert "symplectic_euler" in choice.reason and "rk4" in choice.reason
    # Heavily damped (zeta = 20): symplectic Euler's limit shrinks to ~2 / (2 zeta omega) while implicit
    # Euler stays stable at the frame's step: it wins.
    c = 40.0 * math.sqrt(k * m)
    damped = choose_integrator(_oscillator(k, c, m), frame_dt, implicit_substeps=1)
    assert damped.name == "implicit_euler" and damped.substeps == 1
    assert damped.candidates["symplectic_euler"]["substeps"] > 10 * n


def test_implicit_iteration_estimate_is_capped_and_grows_with_stiffness():
    assert implicit_iterations(1e6, 1e-4, 200) == 200
    assert implicit_iterations(10.0, 1e-4, 200) < implicit_iterations(40.0, 1e-4, 200)
    assert implicit_iterations(0.0, 1e-4, 200) >= 1.0


def test_auto_demos_choose_per_scene_and_record_it(tmp_path):
    """The cloth sheet runs symplectic Euler at its stable substeps (cheaper than PCG per frame), the
    flag's aerodynamic damping makes implicit Euler the cheaper one; the choice is in run.json and the
    summary, with the frame's launch mode."""
    ta.init("cpu")
    cloth = make_scene("cloth", resolution=16)
    record = cloth.integrator_choice
    assert cloth.integrator.name == record["chosen"] == "symplectic_euler"
    assert cloth.substeps == record["substeps"] > 4
    costs = {k: v["evaluations_per_frame"] for k, v in record["candidates"].items()}
    assert costs["symplectic_euler"] == min(costs.values())
    summary = run_scene(cloth, frames=2, out_dir=tmp_path / "cloth", progress=False)
    manifest = (tmp_path / "cloth" / "run.json").read_text()
    assert '"integrator_choice"' in manifest and '"frame_mode"' in manifest
    assert summary["frame_mode"]["mode"] == "serial_frame"
    assert summary["steps"] == 2 * cloth.substeps
    flag = make_scene("flag", resolution=10, integrator="auto")
    assert flag.integrator.name == flag.integrator_choice["chosen"] == "implicit_euler"
    assert flag.integrator_choice["candidates"]["symplectic_euler"]["substeps"] > 10 * flag.substeps
    with pytest.raises(ParameterError, match="substeps"):
        make_scene("cloth", resolution=8, substeps=10)


THREADS_SCRIPT = """
import hashlib, sys, taichi_anim as ta
ta.init("cpu", cpu_threads=int(sys.argv[1]))
n = 96  # 9216 rows: the PCG block loops and the spring loops run as parallel tasks on 2 threads
b = ta.Builder()
b.add_cloth_grid(origin=(0, 1, 0), size=(1.0, 1.0), resolution=(n, n), plane="xz", pinned=[0, n - 1])
b.add_force_gravity()
model = b.finalize()
runs = (("implicit_euler", 1 / 240, 3, None), ("symplectic_euler", 1e-5, 16, "launches"),
        ("symplectic_euler", 1e-5, 16, "parallel_frame"))  # forced: on one thread it is not chosen
for name, h, count, forced in runs:
    s = model.state()
    stepper = ta.make_integrator(name).stepper_for(model)
    if forced:
        stepper._frame_mode = {"mode": forced, "reason": "test"}
    stepper.advance(s, h, count)
    print(name, stepper.frame_mode()["mode"], hashlib.sha256(s.positions().tobytes()).hexdigest())
"""


# exhaustive; covered by thread counts: the cloth's implicit step and the blocked frames, default
@pytest.mark.slow
def test_large_solves_and_frames_give_the_same_bits_on_1_and_2_threads():
    """The parallel paths (block loops spread over tasks, per-substep launches, the parallel frame's
    workers) keep every reduction in a fixed order: 1 and 2 threads give bitwise equal states (gathers,
    no float atomics; a worker alone runs every chunk of the parallel frame)."""
    import subprocess
    import sys

    procs = [
        subprocess.Popen([sys.executable, "-c", THREADS_SCRIPT, str(t)], stdout=subprocess.PIPE, text=True)
        for t in (1, 2)
    ]
    outs = [p.communicate()[0] for p in procs]
    assert all(p.returncode == 0 for p in procs)
    one, two = ([ln for ln in o.splitlines() if not ln.startswith("[Taichi]")] for o in outs)
    assert len(one) == 3 and one == two
    assert [ln.split()[1] for ln in one[1:]] == ["launches", "parallel_frame"]


def test_auto_choice_with_an_error_tolerance_meets_it_on_the_closed_form():
    """error_tolerance [m]: the chosen method's one-frame position error (step doubling, Richardson) is
    within it; checked against the closed form x(t) = L + A cos(omega t) of the undamped oscillator. A
    loose tolerance keeps the stability-only choice; a tight one raises the substeps beyond it."""
    k, m, frame_dt = 1e4, 0.5, 1 / 60
    omega = math.sqrt(k / m)
    exact = 1.0 + 0.1 * math.cos(omega * frame_dt)
    loose = choose_integrator(_oscillator(k, 0.0, m), frame_dt, candidates=("symplectic_euler", "rk4"))
    for tol in (0.2, 1e-5):  # 0.2 m: twice the amplitude, met by any stable step
        model = _oscillator(k, 0.0, m)
        choice = choose_integrator(
            model, frame_dt, candidates=("symplectic_euler", "rk4"), error_tolerance=tol
        )
        record = choice.candidates[choice.name]["tolerance"]
        assert record["met"] and record["estimated_error"] <= tol
        state = model.state()
        integ = make_chosen(model, choice)
        integ.step(model, state, frame_dt, choice.substeps)
        error = abs(state.positions()[1, 0] - exact)
        assert error <= 2.0 * tol  # Richardson's estimate is asymptotically exact: a factor 2 of slack
        if tol == 0.2:
            assert (choice.name, choice.substeps) == (loose.name, loose.substeps)
        else:
            assert choice.substeps > loose.candidates[choice.name]["substeps"]
    with pytest.raises(ParameterError, match="error_tolerance"):
        choose_integrator(_oscillator(k, 0.0, m), frame_dt, error_tolerance=-1.0)


@pytest.mark.parametrize("mode", ["serial_frame", None])
def test_serial_spring_pass_sums_into_its_ends_with_the_gathers_bits(monkeypatch, mode):
    """On one thread the spring pass adds each force to both of its ends (terms/springs.py): springs
    sorted by their ends reach every particle in its adjacency's order, so the sums, and the whole run,
    are the per-spring array's and gather's bit for bit (same kernel arithmetic, other memory)."""
    import taichi_anim.terms.springs as springs_module

    out = {}
    for scatter in (True, False):
        ta.init("cpu", precision="f64")
        monkeypatch.setattr(springs_module, "SCATTER_WHEN_SERIAL", scatter)
        state, stepper = _run(mode, "symplectic_euler", 2e-4, 3, 16)
        assert stepper.model.serial  # the serial pass is the one under test
        out[scatter] = (state.particle_x.to_numpy(), state.particle_v.to_numpy())
    np.testing.assert_array_equal(out[True][0], out[False][0])
    np.testing.assert_array_equal(out[True][1], out[False][1])
    assert np.abs(out[True][0] - _sheet().state().particle_x.to_numpy()).max() > 1e-6
