"""Each test starts from a fresh Taichi runtime in float64 on the CPU (closed-form checks need f64);
tests that need f32 call `ta.init` themselves."""

import pytest

import taichi_anim as ta
from taichi_anim import capacity


@pytest.fixture(autouse=True)
def taichi_f64():
    ta.init("cpu", precision="f64")
    yield


@pytest.fixture
def size_buckets(taichi_f64):
    """Capacity buckets on (capacity.py) for a test: scenes of a few bodies then lay out their fields
    alike, so a test finds most kernels an earlier one compiled in Taichi's offline cache instead of
    compiling them again, and the many scenes one test builds reuse the first one's fields (a rigid scene's
    first step compiles for 6-8 s in f64). The physics is the same either way (test_size_buckets.py)."""
    capacity.set_enabled(True)
    yield
    capacity.set_enabled(None)
