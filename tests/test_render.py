"""Headless rendering: projection, PNG content at projected pixels, painter's order; viewer diagnosis."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import taichi as ti

from taichi_anim.errors import ParameterError
from taichi_anim.render import Camera, fit_camera, render_png

BG = 0x101418
BG_RGB = (0x10, 0x14, 0x18)
W, H = 160, 120


def read_png(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 with row 0 at the top (ti.tools.imread gives [x, y] with y upwards)."""
    img = ti.tools.imread(str(path))
    return np.ascontiguousarray(img[:, ::-1, :3].transpose(1, 0, 2))


def pixel(uv) -> tuple[int, int]:
    """(row from the top, column) of the pixel containing image point uv."""
    u, v = uv
    return min(int((1.0 - v) * H), H - 1), min(int(u * W), W - 1)


@pytest.fixture
def cam():
    # Looking down -Z from z = 5: +X is to the right, +Y up.
    return Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), fov_deg=60.0, resolution=(W, H))


# --------------------------------------------------------------------------------------------- camera


def test_project_matches_the_pinhole_formula(cam):
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [-1.0, 0.0, 2.0], [0.0, 0.0, 6.0], [100.0, 0.0, 0.0]])
    uv, depth, visible = cam.project(pts)
    t = math.tan(math.radians(30.0))
    np.testing.assert_allclose(depth, [5.0, 5.0, 3.0, -1.0, 5.0])
    np.testing.assert_allclose(uv[0], [0.5, 0.5])
    # u = 1/2 + x / (2 z tan(fov/2) aspect), v = 1/2 + y / (2 z tan(fov/2))
    np.testing.assert_allclose(uv[1], [0.5 + 1.0 / (2 * 5 * t * W / H), 0.5 + 0.5 / (2 * 5 * t)])
    np.testing.assert_allclose(uv[2], [0.5 - 1.0 / (2 * 3 * t * W / H), 0.5])
    assert np.all(np.isnan(uv[3]))  # behind the camera
    np.testing.assert_array_equal(visible, [True, True, True, False, False])


def test_camera_validation_names_the_field():
    with pytest.raises(ParameterError, match="resolution"):
        Camera(eye=(0, 0, 5), resolution=(161, 120))
    with pytest.raises(ParameterError, match="eye and target"):
        Camera(eye=(1, 2, 3), target=(1, 2, 3))
    with pytest.raises(ParameterError, match="up"):
        Camera(eye=(0, 5, 0), target=(0, 0, 0))  # looking straight down along the default up
    with pytest.raises(ParameterError, match="fov_deg"):
        Camera(eye=(0, 0, 5), fov_deg=180)


def test_fit_camera_sees_every_corner_of_the_box():
    lo, hi = np.array([-1.0, 0.0, -2.0]), np.array([3.0, 1.0, 0.5])
    cam = fit_camera(lo, hi, resolution=(W, H))
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    uv, _, visible = cam.project(corners)
    assert visible.all()
    np.testing.assert_allclose(cam.project([(lo + hi) / 2])[0][0], [0.5, 0.5], atol=1e-12)
    assert cam.eye[1] > cam.target[1] and cam.eye[2] > cam.target[2]  # above and in front (Y up)
    assert fit_camera([1, 1, 1], [1, 1, 1]).project([[1, 1, 1]])[2][0]  # a single point still works


# -------------------------------------------------------------------------------------------- render


def test_render_points_at_their_projected_pixels(tmp_path, cam):
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [-1.0, -0.5, 0.0]])
    colors = np.array([[1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    path = render_png(tmp_path / "p.png", points=pts, colors=colors, radius_px=3.0, camera=cam, background=BG)
    assert path == tmp_path / "p.png" and sorted(p.name for p in tmp_path.iterdir()) == ["p.png"]
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = read_png(path)
    assert img.shape == (H, W, 3)
    uv, _, _ = cam.project(pts)
    for k, want in enumerate([(255, 255, 255), (255, 0, 0), (0, 0, 255)]):
        np.testing.assert_array_equal(img[pixel(uv[k])], want)
    # Far from every point: background.
    for corner in [(0, 0), (0, W - 1), (H - 1, 0), (H - 1, W - 1)]:
        np.testing.assert_array_equal(img[corner], BG_RGB)
    # Right of the centre and up in the world is right and up in the image.
    (r1, c1), (r0, c0) = pixel(uv[1]), pixel(uv[0])
    assert c1 > c0 and r1 < r0


def test_points_are_painted_back_to_front(tmp_path, cam):
    # Both on the view axis; the near (red) one is listed first, so only a depth sort puts it on top.
    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    colors = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    img = read_png(
        render_png(tmp_path / "o.png", points=pts, colors=colors, radius_px=np.array([3.0, 8.0]), camera=cam)
    )
    row, col = pixel((0.5, 0.5))
    np.testing.assert_array_equal(img[row, col], [255, 0, 0])
    np.testing.assert_array_equal(img[row, col + 6], [0, 255, 0])  # the far disc's rim shows around it


def test_triangles_are_shaded_and_occlude_what_is_behind(tmp_path, cam):
    quad = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    pts = np.array([[0.5, 0.5, 1.0], [-0.5, -0.5, -1.0]])  # one in front of the quad, one behind
    img = read_png(
        render_png(
            tmp_path / "t.png",
            points=pts,
            colors=np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
            radius_px=3.0,
            triangles=(quad, faces, np.tile([0.0, 0.0, 1.0], (2, 1))),
            camera=cam,
        )
    )
    uv, _, _ = cam.project(pts)
    np.testing.assert_array_equal(img[pixel(uv[0])], [255, 0, 0])  # in front: drawn over the quad
    hidden = img[pixel(uv[1])]
    assert hidden[1] == 0 and hidden[2] > 100  # behind: the blue quad covers it
    # Lambert: the quad faces the camera; the headlight is off-axis, so 0.25 + 0.75 |n.l| < 1.
    centre = img[pixel((0.5, 0.5))]
    n_dot_l = 1.0 / math.sqrt(1.0 + 0.25 + 0.09)
    assert centre[0] == 0 and abs(int(centre[2]) - round(255 * (0.25 + 0.75 * n_dot_l))) <= 1
    np.testing.assert_array_equal(img[0, 0], BG_RGB)


def test_lines_in_both_forms(tmp_path, cam):
    begin, end = np.array([[-1.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    a = read_png(
        render_png(tmp_path / "a.png", lines=(begin, end), line_colors=0x00FF00, line_width_px=2, camera=cam)
    )
    b = read_png(
        render_png(
            tmp_path / "b.png",
            lines=(np.vstack([begin, end]), np.array([[0, 1]])),
            line_colors=0x00FF00,
            line_width_px=2,
            camera=cam,
        )
    )
    np.testing.assert_array_equal(a, b)
    row, col = pixel(cam.project([[0.5, 0.0, 0.0]])[0][0])
    assert a[row, col, 1] > 200
    np.testing.assert_array_equal(a[0, 0], BG_RGB)


def test_lines_crossing_the_near_plane_are_clipped_not_mirrored(tmp_path, cam):
    # From in front of the camera to behind it: only the visible half may appear, below the centre.
    img = read_png(
        render_png(tmp_path / "c.png", lines=([[0.0, -1.0, 0.0]], [[0.0, -1.0, 10.0]]), camera=cam)
    )
    lit = np.argwhere(np.any(img != BG_RGB, axis=2))
    assert len(lit) and lit[:, 0].min() > H // 2


def test_empty_or_culled_scenes_render_the_background(tmp_path, cam):
    empty = read_png(render_png(tmp_path / "e.png", points=np.zeros((0, 3)), resolution=(W, H)))
    behind = read_png(
        render_png(
            tmp_path / "b.png", points=[[0.0, 0.0, 9.0]], triangles=([[0, 0, 9]] * 3, [[0, 1, 2]]), camera=cam
        )
    )
    for img in (empty, behind):
        assert img.shape == (H, W, 3)
        np.testing.assert_array_equal(img, np.broadcast_to(BG_RGB, (H, W, 3)))


def test_auto_camera_frames_the_scene(tmp_path):
    pts = np.random.default_rng(3).normal(size=(200, 3)) + [10.0, 5.0, -3.0]
    img = read_png(render_png(tmp_path / "a.png", points=pts, colors=(1.0, 1.0, 0.0), resolution=(W, H)))
    lit = np.argwhere(np.any(img != BG_RGB, axis=2))
    assert len(lit) > 100
    # Centred: the lit pixels' mean lies near the image centre, and nothing touches the border.
    assert abs(lit[:, 0].mean() - H / 2) < H / 6 and abs(lit[:, 1].mean() - W / 2) < W / 6
    np.testing.assert_array_equal(img[0], np.tile(BG_RGB, (W, 1)))


def test_render_bad_inputs_and_failed_write(tmp_path, cam, monkeypatch):
    with pytest.raises(ParameterError, match="points"):
        render_png(tmp_path / "x.png", points=[[0.0, np.inf, 0.0]], camera=cam)
    with pytest.raises(ParameterError, match="colors"):
        render_png(tmp_path / "x.png", points=np.zeros((2, 3)), colors=np.zeros((3, 3)), camera=cam)
    with pytest.raises(ParameterError, match="faces"):
        render_png(tmp_path / "x.png", triangles=(np.zeros((3, 3)), [[0, 1, 3]]), camera=cam)

    def crash(self, file=None):
        Path(file).write_bytes(b"\x89PNG partial")
        raise RuntimeError("simulated crash while saving")

    monkeypatch.setattr(ti.GUI, "show", crash)
    with pytest.raises(RuntimeError, match="simulated"):
        render_png(tmp_path / "x.png", points=np.zeros((1, 3)), camera=cam)
    assert list(tmp_path.iterdir()) == []


def test_render_works_before_and_after_ti_init(tmp_path):
    # ti.GUI(show_gui=False) needs no Taichi runtime; the render must neither require nor start one.
    script = textwrap.dedent(
        f"""
        import numpy as np, taichi as ti
        from taichi.lang import impl
        from taichi_anim.render import render_png
        render_png({str(tmp_path / "before.png")!r}, points=np.zeros((1, 3)), resolution=(64, 48))
        assert impl.get_runtime().prog is None, "render_png initialised Taichi"
        ti.init(arch=ti.cpu, log_level=ti.WARN)
        render_png({str(tmp_path / "after.png")!r}, points=np.zeros((1, 3)), resolution=(64, 48))
        """
    )
    root = Path(__file__).resolve().parents[1]
    env = {"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", "HOME": str(Path.home())}
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    before, after = read_png(tmp_path / "before.png"), read_png(tmp_path / "after.png")
    assert before.shape == (48, 64, 3)
    np.testing.assert_array_equal(before, after)
    assert np.any(before != BG_RGB)


# ------------------------------------------------------------------------------------- viewer (GGUI)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display check is Linux-only")
def test_vulkan_problem_names_the_missing_piece(monkeypatch):
    from taichi_anim import viewer

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    problem = viewer.vulkan_problem(show_window=True)
    assert "DISPLAY" in problem and "xvfb-run -a" in problem

    monkeypatch.setattr(viewer, "_loader_names", lambda: ("libvulkan_missing_for_test.so.1",))
    viewer._vulkan_device_problem.cache_clear()
    try:
        problem = viewer.vulkan_problem(show_window=False)
        assert (
            "libvulkan_missing_for_test.so.1" in problem
            and "apt-get install libvulkan1 mesa-vulkan-drivers" in problem
        )
    finally:
        viewer._vulkan_device_problem.cache_clear()


def test_viewer_turns_ggui_errors_into_viewer_unavailable(monkeypatch):
    from taichi_anim import viewer

    monkeypatch.setattr(viewer, "vulkan_problem", lambda **kw: "no Vulkan loader (test)")
    with pytest.raises(viewer.ViewerUnavailable, match="no Vulkan loader"):
        viewer.Viewer("t", (64, 48))

    def no_vulkan(*args, **kwargs):
        raise RuntimeError("Vulkan must be available for GGUI")

    monkeypatch.setattr(viewer, "vulkan_problem", lambda **kw: None)
    monkeypatch.setattr(ti.ui, "Window", no_vulkan)
    with pytest.raises(viewer.ViewerUnavailable, match="mesa-vulkan-drivers") as info:
        viewer.Viewer("t", (64, 48), show_window=False)
    assert isinstance(info.value, RuntimeError)


def test_viewer_offscreen_draws_particles_where_lavapipe_exists(tmp_path, monkeypatch):
    from taichi_anim import viewer

    problem = viewer.vulkan_problem(show_window=False)
    if problem:
        pytest.skip(problem)
    monkeypatch.chdir(tmp_path)  # GGUI's ImGui drops an imgui.ini in the working folder
    cam = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), fov_deg=45.0, resolution=(W, H))
    with viewer.Viewer("test", (W, H), capacity=4, show_window=False, camera=cam) as v:
        pts = np.array([[-1.0, 1.0, 0.0], [1.0, -1.0, 0.0]] + [[0.0, 0.0, -50.0]] * 8)  # 10 > capacity: grows
        colors = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] + [[0.0, 0.0, 1.0]] * 8)
        assert v.draw(pts, colors, 0.15)
        img = v.last_image
        assert img.shape == (H, W, 3)
        red = np.argwhere((img[..., 0] > 150) & (img[..., 1] < 80))
        green = np.argwhere((img[..., 1] > 150) & (img[..., 0] < 80))
        assert len(red) and len(green)
        # Red at world (-1, 1) is top-left, green at (1, -1) bottom-right.
        assert red[:, 0].mean() < H / 2 < green[:, 0].mean() and red[:, 1].mean() < W / 2 < green[:, 1].mean()
        assert v.draw(pts, colors, 0.15, screenshot=tmp_path / "shot.png")
        np.testing.assert_array_equal(read_png(tmp_path / "shot.png"), img)
    assert not v.running and v.draw(pts) is False
