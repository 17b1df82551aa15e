"""The example scripts in demos/ run for a few frames and do what they say."""

import importlib.util
from pathlib import Path

import numpy as np

from taichi_anim.io.export import read_point_cloud

DEMOS = Path(__file__).resolve().parent.parent / "demos"


def load(name):
    spec = importlib.util.spec_from_file_location(name, DEMOS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_sparks_script(tmp_path):
    result = load("sparks").main(["--frames", "40", "--out", str(tmp_path)])
    snap, integ = result["snapshot"], result["integrator"]
    assert len(snap.x) > 1000 and integ.accepted >= 40
    assert np.all(snap.x[:, 1] >= 0.0)  # nothing below the floor
    lo, hi = np.array([0.4, 0.6, -0.5]), np.array([1.4, 0.65, 0.5])
    in_slab = np.all((snap.x > lo + 1e-6) & (snap.x < hi - 1e-6), axis=1)
    assert not in_slab.any()
    cloud = read_point_cloud(tmp_path / "sparks_0039.ply")
    np.testing.assert_allclose(cloud["points"], snap.x, atol=1e-6)
    assert (tmp_path / "sparks_last.png").exists()
