"""Headless rendering: projection; spheres at their true pixel radius; depth test against a per-pixel
ray-cast reference; smooth shading against Lambert's law; colour-by and its legend; viewer diagnosis."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import taichi as ti

from taichi_anim.content import Points
from taichi_anim.errors import ParameterError
from taichi_anim.render import (
    Camera,
    ColorBy,
    DrawList,
    Lighting,
    colormap,
    fit_camera,
    render_image,
    render_items,
    render_png,
)
from taichi_anim.render.colormap import VIRIDIS, legend_box
from taichi_anim.scenes.drape import uv_sphere

BG = (0.0, 0.0, 0.0)
W, H = 160, 120
FLAT = Lighting(ambient=1.0, key=0.0, fill=0.0, specular=0.0)  # colour = base: coverage tests


def read_png(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 with row 0 at the top."""
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def pixel(uv) -> tuple[int, int]:
    """(row from the top, column) of the pixel containing image point uv."""
    u, v = uv
    return min(int((1.0 - v) * H), H - 1), min(int(u * W), W - 1)


def rays(cam: Camera) -> np.ndarray:
    """(H, W, 3) unit directions through the pixel centres (the renderer's convention)."""
    r, u, f = cam.basis()
    t = math.tan(math.radians(cam.fov_deg) / 2)
    w, h = cam.resolution
    x = ((np.arange(w) + 0.5) / w * 2 - 1) * t * cam.aspect
    y = (1 - (np.arange(h) + 0.5) / h * 2) * t
    d = f + x[None, :, None] * r + y[:, None, None] * u
    return d / np.linalg.norm(d, axis=2, keepdims=True)


def sphere_t(cam: Camera, center, radius) -> np.ndarray:
    """(H, W) ray parameter of each pixel's ray at the sphere's near side (inf for a miss)."""
    d = rays(cam)
    oc = np.asarray(center) - np.asarray(cam.eye)
    tc = d @ oc
    h2 = radius**2 - (oc @ oc - tc**2)
    return np.where(h2 >= 0, tc - np.sqrt(np.maximum(h2, 0)), np.inf)


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


# ---------------------------------------------------------------------------------- spheres, depth


def test_sphere_pixel_extent_is_the_pinhole_projection_of_its_true_radius():
    # 400 x 300 pixels and spheres tens of pixels across, so that +-1 px tells a radius 3 % off.
    w, h = 400, 300
    cam = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), fov_deg=60.0, resolution=(w, h))
    t = math.tan(math.radians(30.0))
    # Off axis the image is an ellipse whose extreme columns are where the tangent planes through the
    # eye touch the sphere: x/z = (cx cz -+ r sqrt(cx^2 + cz^2 - r^2)) / (cz^2 - r^2) (camera coordinates).
    c, r = np.array([1.4, 0.0, 0.0]), 0.7
    d = DrawList()
    d.add_spheres([c], r, (1.0, 1.0, 1.0))
    lit = render_image(d, cam, background=BG, samples=1, lighting=FLAT)[..., 0] > 127
    cx, cz = c[0], 5.0 - c[2]
    s = math.sqrt(cx * cx + cz * cz - r * r)
    x_lo, x_hi = ((cx * cz - r * s) / (cz * cz - r * r), (cx * cz + r * s) / (cz * cz - r * r))
    to_col = lambda xz: (xz / (t * w / h) + 1) / 2 * w  # noqa: E731
    cols = np.flatnonzero(lit.any(axis=0))
    assert abs(cols.min() - to_col(x_lo)) <= 1.0 and abs(cols.max() + 1 - to_col(x_hi)) <= 1.0
    # On axis: the disc's radius in pixels is f tan(asin(r/d)), f = (H/2) / tan(fov/2).
    d2 = DrawList()
    d2.add_spheres([[0.0, 0.0, 0.0]], r, (1.0, 1.0, 1.0))
    disc = render_image(d2, cam, background=BG, samples=1, lighting=FLAT)[..., 0] > 127
    want = (h / 2) / t * math.tan(math.asin(r / 5.0))
    rows, cols = np.flatnonzero(disc.any(axis=1)), np.flatnonzero(disc.any(axis=0))
    assert abs((rows.max() + 1 - rows.min()) / 2 - want) <= 1.0
    assert abs((cols.max() + 1 - cols.min()) / 2 - want) <= 1.0
    assert abs(disc.sum() - math.pi * want**2) < 2 * math.pi * want  # a disc, not a square


@pytest.mark.parametrize("separate_calls", [False, True])
def test_a_nearer_sphere_hides_a_farther_one_whatever_the_draw_order(cam, separate_calls):
    near, far = ([0.0, 0.0, 1.0], 0.3, (1.0, 0.0, 0.0)), ([0.2, 0.0, -1.0], 0.6, (0.0, 1.0, 0.0))
    images = []
    for order in ((near, far), (far, near)):
        d = DrawList()
        if separate_calls:
            for c, r, col in order:
                d.add_spheres([c], r, col)
        else:
            d.add_spheres(
                [o[0] for o in order], np.array([o[1] for o in order]), np.array([o[2] for o in order])
            )
        images.append(render_image(d, cam, background=BG, samples=1, lighting=FLAT))
    np.testing.assert_array_equal(images[0], images[1])
    img = images[0]
    np.testing.assert_array_equal(img[pixel((0.5, 0.5))], [255, 0, 0])
    # Every pixel against the ray-cast reference: red where the near sphere's hit is nearer.
    t_near, t_far = sphere_t(cam, near[0], near[1]), sphere_t(cam, far[0], far[1])
    want = np.where(np.isfinite(t_near) & (t_near <= t_far), 0, np.where(np.isfinite(t_far), 1, 2))
    got = np.where(img[..., 0] > 127, 0, np.where(img[..., 1] > 127, 1, 2))
    assert (got != want).sum() <= 4, (got != want).sum()  # only ties at the rims may differ


def test_a_sphere_half_inside_a_floor_is_cut_by_it():
    # Looking down at a floor quad (y = 0) through a sphere centred on it: where a pixel's ray meets the
    # floor before the sphere, the floor shows; the reference is a ray cast per pixel in float64.
    cam = Camera(eye=(0.0, 2.0, 3.0), target=(0.0, 0.0, 0.0), fov_deg=40.0, resolution=(W, H))
    c, r = np.array([0.0, 0.0, 0.0]), 0.6
    quad = np.array([[-3.0, 0.0, -3.0], [3.0, 0.0, -3.0], [3.0, 0.0, 3.0], [-3.0, 0.0, 3.0]])
    d = DrawList()
    d.add_mesh(quad, [[0, 2, 1], [0, 3, 2]], colors=(0.0, 1.0, 0.0))
    d.add_spheres([c], r, (1.0, 0.0, 0.0))
    img = render_image(d, cam, background=BG, samples=1, lighting=FLAT)
    ray = rays(cam)
    t_floor = np.where(ray[..., 1] < 0, -cam.eye[1] / np.minimum(ray[..., 1], -1e-12), np.inf)
    t_sph = sphere_t(cam, c, r)
    want_sphere = t_sph < t_floor
    got_sphere = img[..., 0] > 127
    assert want_sphere.sum() > 500 and (sphere_t(cam, c, r) < np.inf).sum() > want_sphere.sum() + 300
    assert (got_sphere != want_sphere).sum() <= 6, (got_sphere != want_sphere).sum()


def test_lines_are_depth_tested_and_clipped_at_the_near_plane(cam):
    d = DrawList()
    d.add_spheres([[0.0, 0.0, 0.0]], 0.5, (1.0, 0.0, 0.0))
    d.add_lines([[-2.0, 0.2, -1.0], [-2.0, -0.2, 1.0]], [[2.0, 0.2, -1.0], [2.0, -0.2, 1.0]], (0.0, 1.0, 0.0))
    img = render_image(d, cam, background=BG, samples=1, lighting=FLAT)
    behind = pixel(cam.project([[0.0, 0.2, -1.0]])[0][0])
    front = pixel(cam.project([[0.0, -0.2, 1.0]])[0][0])
    np.testing.assert_array_equal(img[behind], [255, 0, 0])  # the sphere hides the far line
    np.testing.assert_array_equal(img[front], [0, 255, 0])  # the near line crosses the sphere
    outside = pixel(cam.project([[-1.5, 0.2, -1.0]])[0][0])
    np.testing.assert_array_equal(img[outside], [0, 255, 0])
    # From in front of the camera to behind it: only the visible half may appear, below the centre.
    d = DrawList()
    d.add_lines([[0.0, -1.0, 0.0]], [[0.0, -1.0, 10.0]], (1.0, 1.0, 1.0))
    lit = np.argwhere(render_image(d, cam, background=BG, samples=1).max(axis=2) > 0)
    assert len(lit) and lit[:, 0].min() > H // 2


# ------------------------------------------------------------------------------------------ shading


def test_mesh_shading_follows_lambert_of_the_true_normal_without_face_plateaus():
    # A tessellated unit sphere lit by one light (no ambient, fill or highlight): each pixel's intensity
    # is max(n . l, 0) of the true sphere's normal where the pixel's ray meets it, to within the
    # tessellation's error; flat shading would give one value per face (plateaus and steps).
    cam = Camera(eye=(0.0, 0.0, 4.0), target=(0.0, 0.0, 0.0), fov_deg=40.0, resolution=(W, H))
    light = np.array([0.5, 0.5, 0.7071])
    v, f = uv_sphere((0.0, 0.0, 0.0), 1.0, rings=16, segments=32)
    d = DrawList()
    d.add_mesh(v, f, colors=(1.0, 1.0, 1.0))
    lit = Lighting(
        direction=tuple(light / np.linalg.norm(light)), ambient=0.0, key=1.0, fill=0.0, specular=0.0
    )
    img = render_image(d, cam, background=BG, samples=1, lighting=lit).astype(float)[..., 0] / 255.0
    t = sphere_t(cam, (0.0, 0.0, 0.0), 1.0)
    inside = np.isfinite(t)
    hit = np.asarray(cam.eye) + rays(cam) * np.where(inside, t, 0.0)[..., None]
    want = np.maximum(hit @ (light / np.linalg.norm(light)), 0.0)
    core = inside & (np.linalg.norm(hit[..., :2], axis=2) < 0.9)  # away from the polygonal rim
    err = np.abs(img - want)[core]
    assert err.max() < 0.06 and err.mean() < 0.015, (err.max(), err.mean())
    # No plateaus: along the centre row neighbouring pixels rarely share a value and never jump.
    row = img[H // 2][core[H // 2]]
    steps = np.abs(np.diff(row))
    assert (steps == 0).mean() < 0.25 and steps.max() < 0.05


def test_cloth_back_faces_take_the_back_colour(cam):
    quad = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    for faces, want in (([[0, 1, 2], [0, 2, 3]], [255, 0, 0]), ([[0, 2, 1], [0, 3, 2]], [0, 0, 255])):
        d = DrawList()
        d.add_mesh(quad, faces, colors=(1.0, 0.0, 0.0), back_color=(0.0, 0.0, 1.0))
        np.testing.assert_array_equal(render_image(d, cam, samples=1, lighting=FLAT)[H // 2, W // 2], want)


# -------------------------------------------------------------------------------- colour, legend, png


def test_colormap_ends_clamping_and_rising_lightness():
    c = colormap([0.0, 1.0, -5.0, 9.0, 0.5], 0.0, 1.0)
    np.testing.assert_allclose(c[[0, 2]], [VIRIDIS[0]] * 2)
    np.testing.assert_allclose(c[[1, 3]], [VIRIDIS[-1]] * 2)
    luma = colormap(np.linspace(0, 1, 200), 0, 1) @ [0.2126, 0.7152, 0.0722]
    assert np.all(np.diff(luma) > 0)
    with pytest.raises(ParameterError, match="color range"):
        colormap([0.0], 1.0, 0.0)
    with pytest.raises(ParameterError, match="color_by"):
        ColorBy("temperature")


def test_colour_by_speed_colours_points_and_draws_the_legend(cam):
    pts = np.array([[-0.6, 0.0, 0.0], [0.3, 0.0, 0.0]])  # clear of the legend at the right edge
    vel = np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 4.0]])  # speeds 0 and 5 m/s
    item = Points("", pts, np.full((2, 3), 0.5), np.arange(2), attributes={"velocity": vel})
    plain = render_items([item], cam, point_radius=0.2, lighting=FLAT, samples=1, background=BG)
    img = render_items(
        [item],
        cam,
        point_radius=0.2,
        color_by=ColorBy("speed", 0.0, 5.0),
        lighting=FLAT,
        samples=1,
        background=BG,
    )
    for k, end in ((0, VIRIDIS[0]), (1, VIRIDIS[-1])):
        np.testing.assert_allclose(img[pixel(cam.project(pts[k : k + 1])[0][0])], np.round(end * 255), atol=1)
    r0, r1, c0, c1 = legend_box(img.shape)
    bar = img[r0:r1, c0:c1].astype(float) / 255
    np.testing.assert_allclose(bar[0, 2], VIRIDIS[-1], atol=0.01)  # the top is the maximum
    np.testing.assert_allclose(bar[-1, 2], VIRIDIS[0], atol=0.01)
    assert np.all(plain[r0:r1, c0:c1] == 0)  # no colour-by, no legend
    assert np.any(img[:r0, c0 - 40 :] > 0)  # the label above the bar


def test_render_png_writes_atomically_and_validates(tmp_path, cam, monkeypatch):
    path = render_png(tmp_path / "p.png", points=[[0.0, 0.0, 0.0]], radius=0.3, camera=cam)
    assert path == tmp_path / "p.png" and read_png(path).shape == (H, W, 3)
    with pytest.raises(ParameterError, match="points"):
        render_png(tmp_path / "x.png", points=[[0.0, np.inf, 0.0]], camera=cam)
    with pytest.raises(ParameterError, match="colors"):
        render_png(tmp_path / "x.png", points=np.zeros((2, 3)), colors=np.zeros((3, 3)), camera=cam)
    with pytest.raises(ParameterError, match="faces"):
        render_png(tmp_path / "x.png", triangles=(np.zeros((3, 3)), [[0, 1, 3]]), camera=cam)
    with pytest.raises(ParameterError, match="resolution"):
        render_png(tmp_path / "x.png", points=np.zeros((1, 3)), camera=cam, resolution=(161, 120))
    from PIL import Image

    def crash(self, fp, *args, **kwargs):
        Path(fp).write_bytes(b"\x89PNG partial")
        raise RuntimeError("simulated crash while saving")

    monkeypatch.setattr(Image.Image, "save", crash)
    with pytest.raises(RuntimeError, match="simulated"):
        render_png(tmp_path / "x.png", points=np.zeros((1, 3)), camera=cam)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png"]


def test_empty_scene_is_the_background_and_the_auto_camera_frames_points():
    empty = render_image(DrawList(), resolution=(W, H), background=(0.2, 0.4, 0.6))
    np.testing.assert_array_equal(empty, np.broadcast_to([51, 102, 153], (H, W, 3)))
    d = DrawList()
    d.add_spheres(np.random.default_rng(3).normal(size=(200, 3)) + [10.0, 5.0, -3.0], 0.05)
    img = render_image(d, resolution=(W, H), background=BG)
    lit = np.argwhere(img.max(axis=2) > 0)
    assert len(lit) > 100
    assert abs(lit[:, 0].mean() - H / 2) < H / 6 and abs(lit[:, 1].mean() - W / 2) < W / 6
    assert not img[0].any()


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
