"""Hydrostatics on a wide column settled for a second: the pressure's slope against height is rho g
within 1 % with both solvers.

The column of tests/test_fluid.py is 8 particles wide: beyond the walls' kernel support only its 4 x 4
middle columns are measured, and the slope of ten starts moved by 1e-10 m spreads over 4-5 points
(SLOPE_TOLERANCE there). The spread is that sample's. 24 particles wide (this test), the slope over the
same window, averaged over 1-2.5 s, reads for this test's start and blocks moved by k 1e-10 m,
k = 1 ... 9 (2026-12-01, two threads): DFSPH +0.86, +0.01, +0.04, +0.44, -0.17, +0.54, +0.27, +0.03,
+0.57, -0.46 %; PBF +0.42 %. Over 0.7-1.2 s, the column still swaying,
the spread is about twice as wide.

DFSPH read +3.2 to +3.7 % (0.7-1.2 s) before its walls pushed with the mirrored pressure and its
hydrostatic part (wall_pressure.py). The excess came from the layers next to the floor: over the middle
columns of a 16-wide column its pressure was +328, -255 and +14 Pa from the fitted line at 0.5, 1.5 and
2.5 spacings above the floor (the floor layer carrying about twice its share under Akinci's push with
the particle's own pressure), and is now -82, -19 and -9 Pa. PBF's walls push with the particle's own
lambda (its floor layers +493, -111, +32 Pa on that column), and its slope on this wide column is within
1 % all the same. Slow: 9,216 particles for 2.5 s, about 30 s each on 2 cores."""

import numpy as np
import pytest

import taichi_anim as ta

from .test_fluid import RHO, G, tank

WIDTH, HEIGHT, SPACING = 0.48, 0.32, 0.02


def wide_column_slope(method: str) -> float:
    """The relative error of the pressure's slope against -rho g: positions and pressures averaged over
    1-2.5 s, fitted over the particles beyond the walls' kernel support (two spacings from the side
    walls and the floor) and three spacings below the top, as tests/test_fluid.py fits."""
    ta.init("cpu", precision="f64")
    d, w = SPACING, WIDTH
    model, state, stepper, _ = tank(d, (w, HEIGHT, w), (w, 2 * HEIGHT, w), method=method)
    xs, ps = [], []
    for frame in range(150):
        stepper.advance(state, 1.0 / 60.0, 1)
        if frame >= 60:
            xs.append(state.positions()[model.fluid_particles])
            ps.append(state.fluid_pressures())
    x, p = np.mean(xs, axis=0), np.mean(ps, axis=0)
    inner = np.all(np.abs(x[:, [0, 2]] - 0.5 * w) < 0.5 * w - 2 * d, axis=1)
    inner &= (x[:, 1] > 2 * d) & (x[:, 1] < x[:, 1].max() - 3 * d)
    slope, _ = np.polyfit(x[inner, 1], p[inner], 1)
    return slope / (-RHO * G) - 1.0


@pytest.mark.slow
def test_position_based_fluids_hold_the_hydrostatic_slope_within_one_percent():
    """The issue's bound, 1 %, against +0.42 % measured (module docstring)."""
    assert abs(wide_column_slope("pbf")) < 0.01


@pytest.mark.slow
def test_dfsph_holds_the_hydrostatic_slope_within_one_percent():
    """The issue's bound, 1 %, against +0.86 % for this start (module docstring: -0.46 to +0.86 % over
    ten)."""
    assert abs(wide_column_slope("dfsph")) < 0.01
