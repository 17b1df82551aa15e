"""A self-contact start that already crosses is named (collision/self_contact.py, check_start): the
guard keeps every pair on the side it starts on, so crossed sheets stay hooked (two interpenetrating
sheets hung in mid-air, 0.10 m of fall in 0.5 s instead of 1.24 m, with no word). By default the first
step raises ParameterError naming the count and the first pair; start_crossings="warn" runs anyway."""

import re
import warnings

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.spatial.crossings import intersecting_triangle_pairs, triangles_meet


def crossing_sheets(**options):
    """A horizontal 9 x 9 sheet (0.5 m) at y = 0.5 and a vertical one through it at z = 0.01."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(origin=(-0.25, 0.5, -0.25), size=(0.5, 0.5), resolution=(9, 9))
    b.add_cloth_grid(origin=(-0.2, 0.3, 0.01), size=(0.4, 0.4), resolution=(9, 9), plane="xy")
    b.add_cloth_self_contact(thickness=0.005, **options)
    return b.finalize()


def test_a_crossing_start_raises_naming_the_count_and_the_first_pair():
    """Pass: the first step raises ParameterError before anything moves; the message holds the exact
    count (spatial.crossings), an edge of one triangle that meets the other (checked here exactly) and
    the option to pass; the state is unchanged (step 0, the start positions)."""
    ta.init("cpu", precision="f64")
    model = crossing_sheets()
    state = model.state()
    x0 = state.positions()
    expected = len(intersecting_triangle_pairs(x0, model.triangles))
    assert expected > 0
    with pytest.raises(ta.ParameterError, match="start_crossings") as err:
        ta.make_integrator("implicit_euler").step(model, state, 1 / 120)
    message = str(err.value)
    assert f"has {expected} pair(s)" in message
    a, b, f, g = map(
        int, re.search(r"edge \((\d+), (\d+)\) of triangle (\d+) meets triangle (\d+)", message).groups()
    )
    tri = np.asarray(model.triangles)
    assert {a, b} <= set(tri[f]) and not set(tri[f]) & set(tri[g])
    assert triangles_meet(np.array([[x0[a], x0[b], x0[b]]]), x0[tri[g]][None])[0]
    assert state.step_count == 0 and np.array_equal(state.positions(), x0)


def test_start_crossings_warn_runs_and_says_how_many():
    """Pass: with start_crossings="warn" the step runs (step count 1) and one RuntimeWarning gives the
    exact count; the next steps do not warn again (only a State's first step is checked)."""
    ta.init("cpu", precision="f64")
    model = crossing_sheets(start_crossings="warn")
    state = model.state()
    expected = len(intersecting_triangle_pairs(state.positions(), model.triangles))
    integ = ta.make_integrator("implicit_euler")
    with pytest.warns(RuntimeWarning, match=f"has {expected} pair"):
        integ.step(model, state, 1 / 120)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        integ.step(model, state, 1 / 120)
    assert state.step_count == 2
    assert integ.stepper_for(model).self_contact.start_crossing_pairs == expected


def test_bad_start_crossings_option():
    b = ta.Builder()
    b.add_cloth_grid(resolution=(3, 3))
    with pytest.raises(ta.ParameterError, match="start_crossings"):
        b.add_cloth_self_contact(start_crossings="fix")
