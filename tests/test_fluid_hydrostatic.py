"""Hydrostatics on a wide column: the pressure's slope against height is rho g within 1 % with
position-based fluids, and DFSPH's is steep by its floor layers.

The column of tests/test_fluid.py is 8 particles wide: beyond the walls' kernel support only its 4 x 4
middle columns are measured, and the slope of ten starts moved by 1e-10 m spreads over 4-6 points
(SLOPE_TOLERANCE there). The spread is that sample's. 24 particles wide (this test), the slope over the
same window and half second reads, for this test's start on two threads and then for it and three
starts moved by 1e-10 m on one thread (the launch-per-iteration solves, equal to round-off):
PBF +0.51 %; +0.75, +0.56, +0.64, +0.93 %; DFSPH +3.20 %; +3.47, +3.73, +3.51, +3.22 %.

DFSPH's excess comes from the layers next to the floor. Layer by layer over the middle columns of a
16-wide column (one start, 2026-12-01), its pressure is -230 Pa (-8 %) from rho g h at 1.5 spacings
above the floor and +52 Pa (+2 %) at 2.5, where PBF's is -4 and +22 Pa; above, both lie within about
30 Pa of rho g h (1 % of the floor's pressure). Fitted from three spacings off every wall instead of two,
the 24-wide column's DFSPH slope reads +0.28 to +0.66 % and PBF's -0.63 to -1.07 %. Without the walls'
guard (a scratch switch, one 16-wide start) DFSPH read +2.28 % against +3.90 %, the layer at 1.5
spacings -457 Pa: part of the excess, not all. A tighter tolerance does not remove it (1e-4 and 2e-5
read +1.2 to +5.5 % over two 16-wide starts). Slow: 9,216 particles for 1.2 s, about 50 s on 2 cores."""

import numpy as np
import pytest

import taichi_anim as ta

from .test_fluid import RHO, G, tank

WIDTH, HEIGHT, SPACING = 0.48, 0.32, 0.02


def wide_column_slope(method: str) -> float:
    """The relative error of the pressure's slope against -rho g: positions and pressures averaged over
    0.7-1.2 s, fitted over the particles beyond the walls' kernel support (two spacings from the side
    walls and the floor) and three spacings below the top, as tests/test_fluid.py fits."""
    ta.init("cpu", precision="f64")
    d, w = SPACING, WIDTH
    model, state, stepper, _ = tank(d, (w, HEIGHT, w), (w, 2 * HEIGHT, w), method=method)
    xs, ps = [], []
    for frame in range(72):
        stepper.advance(state, 1.0 / 60.0, 1)
        if frame >= 42:
            xs.append(state.positions()[model.fluid_particles])
            ps.append(state.fluid_pressures())
    x, p = np.mean(xs, axis=0), np.mean(ps, axis=0)
    inner = np.all(np.abs(x[:, [0, 2]] - 0.5 * w) < 0.5 * w - 2 * d, axis=1)
    inner &= (x[:, 1] > 2 * d) & (x[:, 1] < x[:, 1].max() - 3 * d)
    slope, _ = np.polyfit(x[inner, 1], p[inner], 1)
    return slope / (-RHO * G) - 1.0


@pytest.mark.slow
def test_position_based_fluids_hold_the_hydrostatic_slope_within_one_percent():
    """The issue's bound, 1 %, against +0.51 to +0.93 % measured (module docstring)."""
    assert abs(wide_column_slope("pbf")) < 0.01


@pytest.mark.slow
def test_dfsph_slope_is_steep_by_a_few_percent():
    """DFSPH's slope is steep, +3.2 to +3.7 % measured: between 1 % and 5 % (module docstring)."""
    assert 0.01 < wide_column_slope("dfsph") < 0.05
