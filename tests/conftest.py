"""Each test starts from a fresh Taichi runtime in float64 on the CPU (closed-form checks need f64);
tests that need f32 call `ta.init` themselves."""

import pytest
from taichi.lang import impl

import taichi_anim as ta
from taichi_anim import capacity

_started = None  # the Taichi program the fixture last initialised


def _untouched() -> bool:
    """Whether the runtime is still the one the fixture started and nothing was put in it since: no
    ta.init or ti.init (a new program), no field, no SNode tree, no kernel launched."""
    rt = impl.get_runtime()
    prog = rt.prog
    return (
        _started is not None
        and prog is _started
        and not rt.materialized
        and not rt.global_vars
        and prog.get_snode_tree_size() == 0
    )


@pytest.fixture(autouse=True)
def taichi_f64():
    # A test that left the runtime as it found it (NumPy-only checks, validation errors, parsers) hands
    # it on: initialising Taichi costs 0.13 s, 2 minutes over the suite's 990 tests.
    global _started
    if _untouched():
        capacity.set_enabled(None)  # what ta.init would reset
    else:
        ta.init("cpu", precision="f64")
        _started = impl.get_runtime().prog
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
