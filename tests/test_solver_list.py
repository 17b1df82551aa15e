"""The Stepper's ordered list of solvers (solvers.py): a solver written outside the package joins the list
and acts after every substep in list order, exactly as the protocol says; the built-in contact solvers are
in the list when the scene asks for them; a user's force term joins through Builder.add_force."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta


@ti.kernel
def _scale(v: ti.template(), c: float):
    for i in v:
        v[i] *= c


@ti.kernel
def _add(v: ti.template(), dv: float):
    for i in v:
        v[i][0] += dv


class Damper:
    """A toy solver (duck-typed: no base class): after each substep, v <- c v; logs every hook."""

    def __init__(self, c: float, log: list, name: str = "damper"):
        self.c, self.log, self.name = c, log, name

    def substeps(self, model, state, dt):
        return 1

    def before_substep(self, model, state, h):
        self.log.append(("before", self.name))

    def after_substep(self, model, state, h, step):
        self.log.append(("after", self.name, step))
        _scale(state.particle_v, self.c)

    def check(self, state):
        self.log.append(("check", self.name))

    def settings(self):
        return {"factor": self.c}


class Kick(Damper):
    """After each substep, v_x <- v_x + dv."""

    def after_substep(self, model, state, h, step):
        self.log.append(("after", self.name, step))
        _add(state.particle_v, self.c)


def _free_particles(v0=(1.0, 0.0, 0.0)):
    b = ta.Builder()
    b.add_particles([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [v0, v0], 1.0)
    return b.finalize()


def test_toy_damper_is_exactly_the_closed_form():
    """Symplectic Euler without forces, then v <- v / 2 after each substep of h = 1/16 s:
    v_n = 2^-n v0 and x_n = x0 + h v0 sum_{k<n} 2^-k (each substep moves with the velocity the previous
    substep's damping left). Powers of two: the closed form is exact in f32, so the check is bitwise."""
    model = _free_particles()
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    assert stepper.frame_mode()["mode"] == "blocked"  # nothing between substeps yet
    log = []
    stepper.add_solver(Damper(0.5, log))
    mode = stepper.frame_mode()
    assert mode["mode"] == "steps" and "damper" in mode["reason"]  # a fused frame would skip the solver
    n = 3
    stepper.step(state, n / 16, substeps=n)  # three substeps of exactly 1/16 s
    v = state.velocities()
    x = state.positions()
    h = 1.0 / 16
    assert np.array_equal(v[:, 0], np.full(2, 0.5**n))
    assert np.array_equal(x[:, 0], np.array([0.0, 1.0]) + h * sum(0.5**k for k in range(n)))
    assert [e for e in log if e[0] == "after"] == [("after", "damper", k) for k in (1, 2, 3)]
    assert log.count(("check", "damper")) == n  # check_every = 1: read after every step


def test_solvers_act_in_list_order():
    """Gauss-Seidel coupling: each solver reads what the one before it wrote, so the order is the result.
    [halve, kick 1]: v = v0/2 + 1; [kick 1, halve] (the kick inserted first): v = (v0 + 1)/2."""
    results = {}
    for order in ("halve_first", "kick_first"):
        model = _free_particles(v0=(2.0, 0.0, 0.0))
        state = model.state()
        stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
        log = []
        stepper.add_solver(Damper(0.5, log, "halve"))
        stepper.add_solver(Kick(1.0, log, "kick"), index=0 if order == "kick_first" else None)
        stepper.step(state, 1.0 / 16)
        results[order] = state.velocities()[0, 0]
        first = "kick" if order == "kick_first" else "halve"
        assert [s.name for s in stepper.solvers][0] == first
        # Every hook in list order: both befores, the method, both afters.
        second = "halve" if first == "kick" else "kick"
        assert log[:4] == [("before", first), ("before", second), ("after", first, 1), ("after", second, 1)]
    assert results == {"halve_first": 2.0 / 2 + 1.0, "kick_first": (2.0 + 1.0) / 2}


def test_a_solver_lacking_a_hook_is_refused_naming_it():
    stepper = ta.make_integrator("symplectic_euler").stepper_for(_free_particles())

    class NoCheck:
        name = "incomplete"

        def substeps(self, model, state, dt):
            return 1

        def before_substep(self, model, state, h):
            pass

        def after_substep(self, model, state, h, step):
            pass

        def settings(self):
            return {}

    with pytest.raises(ta.ParameterError, match="'check'"):
        stepper.add_solver(NoCheck())
    assert stepper.solvers == []


def test_a_solver_check_error_rolls_the_step_back():
    """A solver's `check` raising DivergenceError is the Stepper's divergence: with keep_last_good the
    state goes back to the last good step (here the start: x = 0 for particle 0)."""

    class Refuses(Damper):
        def check(self, state):
            raise ta.DivergenceError("toy solver refuses", step=state.step_count)

    model = _free_particles()
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler", policy={"keep_last_good": True}).stepper_for(model)
    stepper.add_solver(Refuses(1.0, []))
    with pytest.raises(ta.DivergenceError, match="toy solver refuses"):
        stepper.step(state, 1.0 / 16)
    assert state.step_count == 0 and state.positions()[0, 0] == 0.0


def test_contact_solvers_are_in_the_list_when_the_scene_has_them():
    """Sphere contacts, then self-contact (last: its guard must see the final positions); the named
    accessors find them in the list; a scene without them has an empty list."""
    b = ta.Builder()
    b.add_cloth_grid(origin=(0.0, 1.0, 0.0), size=(0.2, 0.2), resolution=(3, 3), thickness=0.01)
    b.add_sphere_contacts()
    b.add_cloth_self_contact()
    model = b.finalize()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    assert [s.name for s in stepper.solvers] == ["sphere contacts", "self-contact"]
    assert stepper.contacts is stepper.solvers[0] and stepper.self_contact is stepper.solvers[1]
    reason = stepper.frame_mode()["reason"]
    assert "sphere contacts" in reason and "self-contact" in reason
    plain = ta.make_integrator("symplectic_euler").stepper_for(_free_particles())
    assert plain.solvers == [] and plain.contacts is None and plain.self_contact is None


@ti.data_oriented
class Push(ta.PointTerm):
    """A user's pointwise term: a constant force F [N] along x on every particle."""

    has_jacobian = False
    energy_kind = "potential"

    def __init__(self, f: float):
        self.f = f

    def settings(self) -> dict:
        return {"type": "push", "force": self.f}

    def energy(self, x, masses) -> float:
        return -self.f * float(np.sum(np.asarray(x)[:, 0]))

    def acceleration_bound(self) -> float:
        return self.f  # unit masses below

    @ti.func
    def force(self, i, m, x, v, t):
        return ti.Vector([self.f, 0.0, 0.0], dt=float)

    @ti.func
    def jacobian(self, i, m, x, v, t):
        return ti.Matrix.zero(float, 3, 3), ti.Matrix.zero(float, 3, 3)


def test_add_force_takes_a_users_term():
    """Symplectic Euler, one step of h from rest under F on unit masses: v1 = h F, x1 = h^2 F (exact for
    powers of two). The term is listed after the built-in pointwise terms."""
    b = ta.Builder()
    b.add_particles([[0.0, 0.0, 0.0]], mass=1.0)
    b.add_force_drag(0.0)
    b.add_force(Push(2.0))
    model = b.finalize()
    assert [f["type"] for f in model.settings["forces"]][-1] == "push"
    state = model.state()
    h = 1.0 / 16
    ta.make_integrator("symplectic_euler").step(model, state, h)
    assert state.velocities()[0, 0] == h * 2.0 and state.positions()[0, 0] == h * h * 2.0
    with pytest.raises(ta.ParameterError, match="PointTerm or ElementTerm"):
        b.add_force(lambda i: 0)
