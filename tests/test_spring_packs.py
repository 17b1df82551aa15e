"""The spring pass in packs of eight on the CPU (terms/springs.py, Springs._pack): the same force per
spring as one spring at a time, in every frame mode that runs the pass (a serial frame summing into the
ends, a launch per substep storing per spring, the parallel frame's shares, whose bounds fall anywhere
in a pack), with a remainder of springs after the last full pack."""

import numpy as np
import pytest

import taichi_anim as ta
import taichi_anim.terms.springs as springs_module

from .helpers import ulp_tolerance

N = 23  # a 23 x 23 grid: 2,946 springs, 2 after the last full pack of 8


def _cloth():
    b = ta.Builder()
    material = ta.ClothMaterial(density=0.2, stretch_stiffness=1e3, shear_stiffness=1e3, bend_stiffness=1e3)
    b.add_cloth_grid(origin=(-0.5, 1.0, -0.5), size=(1.0, 1.0), resolution=(N, N), plane="xz",
                     pinned=[0, N - 1], material=material)  # fmt: skip
    b.add_force_gravity()
    b.add_collider_sphere((0.1, 0.7, 0.0), 0.25, friction=0.3)
    return b.finalize()


def _run(monkeypatch, packs: bool, mode: str):
    monkeypatch.setattr(springs_module, "SPRING_PACKS", packs)
    model = _cloth()
    assert model.element_terms[0].packed is packs
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler", check_every=16).stepper_for(model)
    stepper._frame_mode = {"mode": mode, "reason": "test"}
    for _ in range(6):
        stepper.advance(state, 1e-4, 16)
    return model, state.particle_x.to_numpy(), state.particle_v.to_numpy()


@pytest.mark.parametrize("mode", ["serial_frame", "launches", "parallel_frame"])
def test_packed_springs_equal_one_spring_at_a_time(monkeypatch, mode):
    """96 substeps of a pinned sheet falling onto a sphere, packs on and off: positions and velocities
    agree to the roundings of 96 substeps (kernels compiled apart; measured: the same bits)."""
    ta.init("cpu", precision="f64")
    model, x_off, v_off = _run(monkeypatch, False, mode)
    count = model.element_terms[0].count
    assert count % springs_module.PACK != 0  # the pass ends with a partial pack
    _, x_on, v_on = _run(monkeypatch, True, mode)
    for got, ref in ((x_on, x_off), (v_on, v_off)):
        np.testing.assert_allclose(got, ref, rtol=0, atol=ulp_tolerance(np.abs(ref).max(), 96 * 64))
    start = _cloth().state().positions()
    assert np.abs(x_off[: len(start)] - start).max() > 0.4 * 0.5 * 9.81 * (96e-4) ** 2  # it moved
    assert np.ptp(v_off[:, 1]) > 1e-3  # and not as one rigid fall: pins and springs acted


def test_packs_follow_the_spring_count(monkeypatch):
    """By default packs start at SPRING_PACKS_FROM springs (their compile time pays from there)."""
    ta.init("cpu", precision="f32")
    monkeypatch.setattr(springs_module, "SPRING_PACKS", None)
    monkeypatch.setattr(springs_module, "SPRING_PACKS_FROM", 2946)
    assert _cloth().element_terms[0].packed
    monkeypatch.setattr(springs_module, "SPRING_PACKS_FROM", 2947)
    assert not _cloth().element_terms[0].packed
