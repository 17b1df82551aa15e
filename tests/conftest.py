"""Each test starts from a fresh Taichi runtime in float64 on the CPU (closed-form checks need f64);
tests that need f32 call `ta.init` themselves."""

import pytest

import taichi_anim as ta


@pytest.fixture(autouse=True)
def taichi_f64():
    ta.init("cpu", precision="f64")
    yield
