"""The GPU's free-slot scan (particles/slot_scan.py: counts, prefix sum, parallel takes) run on the CPU
against the serial scan: the same slots in the same order, bits, cursors and particles, bit for bit."""

import numpy as np
import pytest

import taichi_anim as ta
import taichi_anim.particles.emitters as emitters_module

from .test_blocked_frame import _fountain


def _stepped(monkeypatch, parallel: bool, steps: int, **scene):
    monkeypatch.setattr(emitters_module, "PARALLEL_SCAN", parallel)
    model, state = _fountain(**scene)
    assert all(e.parallel_scan == parallel for e in model.emitters)
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    for _ in range(steps):
        stepper.step(state, 1.0 / 600.0)
    return state


@pytest.mark.parametrize(
    "scene",
    [
        # A full pool: every birth waits for a death and the cursor wraps; fewer free than asked for.
        dict(capacity=500, lifetime=0.05, jitter=0.2),
        # Slots reborn every few steps, deaths scattered by a wide jitter.
        dict(capacity=300, lifetime=0.004, jitter=0.5),
        # Two emitters sharing a word at their boundary (200 is not a multiple of 32).
        dict(capacity=200, lifetime=0.02, jitter=0.3, emitters=2),
        # A pool of thousands of words, for the prefix sum's several blocks.
        dict(capacity=40_000, lifetime=0.03, jitter=0.4),
    ],
)
def test_parallel_slot_scan_equals_the_serial_scan(monkeypatch, scene):
    ref = _stepped(monkeypatch, False, 90, **scene)
    got = _stepped(monkeypatch, True, 90, **scene)
    for name in (
        "particle_free",
        "emit_cursor",
        "emit_found",
        "emit_slot",
        "particle_birth",
        "particle_death",
    ):
        np.testing.assert_array_equal(getattr(got, name).to_numpy(), getattr(ref, name).to_numpy(), name)
    np.testing.assert_array_equal(got.positions(), ref.positions())
    assert ref.alive_mask().sum() > 0.5 * sum(e.capacity for e in got.model.emitters)
