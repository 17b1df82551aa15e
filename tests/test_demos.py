"""Every demo runs for a few frames through the CLI and exports what it promises."""

import json

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.cli import main
from taichi_anim.io.export import read_line_set, read_point_cloud
from taichi_anim.scenes import SCENES, make_scene


@pytest.mark.parametrize("name", sorted(SCENES))
def test_demo_runs_and_exports(name, tmp_path, capsys):
    assert main(["demo", name, "--frames", "4", "--out", str(tmp_path), "--quiet", "--seed", "3"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith(f"{name}: 4 frames") and "ms/step" in line and "compile" in line
    manifest = json.loads((tmp_path / "run.json").read_text())
    assert manifest["settings"]["seed"] == 3 and manifest["settings"]["frames"] == 4
    assert manifest["settings"]["dt"] > 0 and "integrator" in manifest["settings"]
    assert manifest["timings"]["steps"] == 4 * manifest["settings"]["substeps"]
    assert (tmp_path / f"{name}_last.png").stat().st_size > 1000
    cloud = read_point_cloud(tmp_path / f"{name}_0003.ply")
    assert len(cloud["points"]) == manifest["timings"]["particles_alive"] > 0
    assert np.all(np.isfinite(cloud["points"]))


def test_fountain_particles_stay_in_box_and_trails_export(tmp_path):
    ta.init("cpu")
    scene = make_scene("fountain", particles=4000)
    for _ in range(90):  # 1.5 s: particles have hit the floor and walls
        scene.advance_frame()
    snap = scene.state.snapshot()
    lo, hi = scene.bounds
    assert np.all(snap.x >= np.array(lo) - 1e-5) and np.all(snap.x <= np.array(hi) + 1e-5)
    assert (snap.x[:, 1] < 0.05).sum() > 100  # some rest on the floor
    paths = scene.export_frame(tmp_path, 0)
    lines = read_line_set(paths[1])
    assert len(lines["lines"]) > len(snap.x)  # several segments per particle


def test_spheres_demo_exports_radii_and_keeps_spheres_in_the_box(tmp_path):
    ta.init("cpu")
    scene = make_scene("spheres", particles=5000)
    assert scene.model.contacts.neighbors.method.value == "grid"  # 5000 > crossover, box given
    for _ in range(12):  # 0.4 s: the column has hit the floor
        scene.advance_frame()
    cloud = read_point_cloud(scene.export_frame(tmp_path, 0)[0])
    r = scene.options["radius"]
    assert np.allclose(cloud["radius"], r)
    lo, hi = (np.array(b) for b in scene.bounds)
    assert np.all(cloud["points"] >= lo + r - 1e-4) and np.all(cloud["points"] <= hi - r + 1e-4)
    assert cloud["points"][:, 1].min() < 2 * r  # some lie on the floor
    overlap, contacts = scene.model.contacts.overlap_stats(scene.state)
    assert contacts > 1000 and overlap < 0.25 * r  # mid-impact, one sweep per 1/2400 s step


def test_cli_lists_demos_and_rejects_bad_input(capsys):
    assert main(["demo", "--list"]) == 0
    assert "fountain" in capsys.readouterr().out
    assert main(["demo", "nope", "--frames", "1"]) == 2
    assert "unknown demo 'nope'" in capsys.readouterr().err
    assert main(["demo", "--frames", "0"]) == 2
    assert "--frames must be >= 1, got 0" in capsys.readouterr().err


def test_view_without_display_says_what_is_missing(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["demo", "--view", "--frames", "1"]) == 2
    err = capsys.readouterr().err
    assert "--view is not possible here" in err and "display" in err.lower()


def test_unavailable_backend_is_a_clear_error(capsys):
    try:
        ta.init("cuda")
        pytest.skip("CUDA is available here")
    except RuntimeError:
        pass
    assert main(["demo", "--arch", "cuda", "--frames", "1", "--quiet"]) == 2
    assert "arch='cuda' was requested but Taichi could not start it" in capsys.readouterr().err


def test_view_opens_a_window_under_xvfb(tmp_path):
    import shutil
    import subprocess
    import sys

    from taichi_anim.viewer import vulkan_problem

    if shutil.which("xvfb-run") is None or vulkan_problem(show_window=False):
        pytest.skip(
            "needs xvfb-run and a Vulkan driver (apt-get install xvfb libvulkan1 mesa-vulkan-drivers)"
        )
    cmd = [
        "xvfb-run",
        "-a",
        sys.executable,
        "-m",
        "taichi_anim",
        "demo",
        "--view",
        "--frames",
        "5",
        "--quiet",
        "--out",
        str(tmp_path),
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "fountain: 5 frames" in out.stdout
    assert json.loads((tmp_path / "run.json").read_text())["timings"]["frames"] == 5
