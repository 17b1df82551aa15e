"""The engine's earlier renderer, kept as the peer of benchmarks/render_cost.py: ti.GUI (show_gui=False)
painting flat discs of a fixed pixel radius, lines and flat-shaded triangles back to front (painter's
algorithm, no depth buffer) and writing the PNG itself. Same camera (taichi_anim.render.Camera)."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import taichi as ti

from taichi_anim import validate
from taichi_anim.errors import ParameterError
from taichi_anim.io.export import atomic_path
from taichi_anim.render import Camera, fit_camera
from taichi_anim.render.camera import DEFAULT_RESOLUTION
from taichi_anim.render.image import _segments  # the same input forms as the new renderer

POINT_COLOR = 0xF2C66D
LINE_COLOR = 0x7FB2FF
TRIANGLE_COLOR = 0xB8C0C8
# Lambert shading of triangles: ambient share, the rest scaled by |n . l| (two-sided, cloth has no inside).
AMBIENT = 0.25


# ------------------------------------------------------------------------------------------- colours


def _color_int(name: str, value) -> int:
    """One colour as 0xRRGGBB: an int, or 3 floats in [0,1]."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if not 0 <= int(value) <= 0xFFFFFF:
            raise ParameterError(f"{name} must be a colour 0xRRGGBB, got {value!r}")
        return int(value)
    rgb = validate.colors(name, np.asarray(value).reshape(1, 3), 1)[0]
    r, g, b = (int(round(c * 255.0)) for c in rgb)
    return (r << 16) | (g << 8) | b


def _color_array(name: str, value, n: int, default: int) -> int | np.ndarray:
    """None -> default; one colour -> int; (n,3) RGB in [0,1] or uint8 -> (n,) uint32 0xRRGGBB."""
    if value is None:
        return default
    if isinstance(value, (int, np.integer)) or np.shape(value) == (3,):
        return _color_int(name, value)
    rgb = np.round(validate.colors(name, value, n) * 255.0).astype(np.uint32)
    return (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


def _take(color: int | np.ndarray, idx: np.ndarray) -> int | np.ndarray:
    # ti.GUI accepts a Python int for one colour (not a NumPy scalar) or a (k,) array.
    return color if isinstance(color, int) else np.ascontiguousarray(color[idx])


# --------------------------------------------------------------------------------------------- inputs


def _mesh(triangles):
    if not isinstance(triangles, (tuple, list)) or len(triangles) not in (2, 3):
        raise ParameterError(
            "triangles must be (vertices (V,3), faces (F,3) int) or (vertices, faces, face_colors (F,3))"
        )
    v = validate.finite_array("triangles[0] (vertices)", triangles[0], (3,))
    f = validate.indices("triangles[1] (faces)", triangles[1], 3, len(v), "vertices")
    fc = triangles[2] if len(triangles) == 3 else None
    return v, f, _color_array("triangles[2] (face colors)", fc, len(f), TRIANGLE_COLOR)


def _radius(radius_px, n: int) -> float | np.ndarray:
    if np.ndim(radius_px) == 0:
        return validate.non_negative("radius_px", radius_px)
    r = np.asarray(radius_px, dtype=np.float64)
    if r.shape != (n,) or not np.all(np.isfinite(r)) or np.any(r < 0):
        raise ParameterError(
            f"radius_px must be a number >= 0 or an array of shape ({n},) >= 0, got shape {r.shape}"
        )
    return r


# --------------------------------------------------------------------------------------------- render


def render_png(
    path: str | os.PathLike,
    *,
    points=None,
    colors=None,
    radius_px=2.0,
    lines=None,
    line_colors=None,
    line_width_px: float = 1.0,
    triangles=None,
    camera: Camera | None = None,
    resolution: tuple[int, int] | None = None,
    background=0x101418,
) -> Path:
    """Render points, line segments and triangles to a PNG (atomic write), headless, and return the path.

    points: (N,3) [m], drawn as discs of radius_px pixels (a number or (N,)); colors: (N,3) RGB in [0,1],
    one colour (0xRRGGBB or 3 floats), or None.
    lines: (begin (M,3), end (M,3)) or (points (P,3), indices (L,2) int); line_colors: (M,3) or one
    colour; line_width_px: width in pixels.
    triangles: (vertices (V,3), faces (F,3) int) or (vertices, faces, face_colors (F,3)); shaded flat
    with a Lambert headlight.
    Everything is drawn back to front by depth (painter's algorithm: no depth buffer, so interpenetrating
    triangles may overlap wrongly). Geometry crossing the near plane: lines are clipped, triangles dropped.
    camera: None fits one to the bounding box of what is drawn; resolution: (width, height), even
    (overrides the camera's). background: 0xRRGGBB or 3 floats in [0,1].
    """
    bg = _color_int("background", background)
    pts = None if points is None else validate.finite_array("points", points, (3,))
    n = 0 if pts is None else len(pts)
    pcol = _color_array("colors", colors, n, POINT_COLOR)
    prad = _radius(radius_px, n)
    seg = None if lines is None else _segments(lines)
    lcol = None if seg is None else _color_array("line_colors", line_colors, len(seg[0]), LINE_COLOR)
    lwidth = validate.non_negative("line_width_px", line_width_px)
    mesh = None if triangles is None else _mesh(triangles)

    if camera is None:
        cloud = [
            a
            for a in (pts, *(seg or ()), None if mesh is None else mesh[0][np.unique(mesh[1])])
            if a is not None
        ]
        cloud = np.concatenate(cloud) if cloud else np.zeros((0, 3))
        lo, hi = (cloud.min(0), cloud.max(0)) if len(cloud) else (np.full(3, -1.0), np.ones(3))
        camera = fit_camera(lo, hi, resolution=resolution or DEFAULT_RESOLUTION)
    elif resolution is not None:
        camera = dataclasses.replace(camera, resolution=tuple(resolution))
    width, height = camera.resolution

    # Each drawable becomes (depth key, draw function on a subset); all are merged into one painter's order.
    layers = []
    if mesh is not None and len(mesh[1]):
        layers.append(_triangle_layer(camera, *mesh))
    if seg is not None and len(seg[0]):
        layers.append(_line_layer(camera, seg[0], seg[1], lcol, lwidth))
    if pts is not None and n:
        layers.append(_point_layer(camera, pts, pcol, prad))

    gui = ti.GUI("taichi_anim render", res=(width, height), background_color=bg, show_gui=False)
    try:
        gui.clear(bg)
        _paint(gui, layers)
        with atomic_path(path) as tmp:
            gui.show(str(tmp))
            if not tmp.exists() or tmp.stat().st_size == 0:
                raise OSError(f"ti.GUI wrote no image to {path}")
    finally:
        gui.close()
    return Path(path)


def _point_layer(camera: Camera, pts, color, radius):
    uv, depth, _ = camera.project(pts)
    # Keep discs whose centre is just outside the image too: their rim may still show.
    r_max = float(np.max(radius)) if np.ndim(radius) else float(radius)
    mu, mv = r_max / camera.resolution[0], r_max / camera.resolution[1]
    keep = (
        (depth > camera.near)
        & (uv[:, 0] >= -mu)
        & (uv[:, 0] <= 1 + mu)
        & (uv[:, 1] >= -mv)
        & (uv[:, 1] <= 1 + mv)
    )
    idx = np.nonzero(keep)[0]
    uv = uv[idx]

    def draw(gui, sel):
        r = radius if np.ndim(radius) == 0 else np.ascontiguousarray(radius[idx[sel]])
        gui.circles(uv[sel], radius=r, color=_take(color, idx[sel]))

    return depth[idx], draw


def _line_layer(camera: Camera, begin, end, color, width):
    a, b = camera.to_camera(begin), camera.to_camera(end)
    near = camera.near
    keep = (a[:, 2] > near) | (b[:, 2] > near)
    idx = np.nonzero(keep)[0]
    a, b = a[idx], b[idx]
    # Clip the part behind the near plane: projecting a point behind the eye would mirror it.
    for p, q in ((a, b), (b, a)):
        behind = p[:, 2] <= near
        if behind.any():
            t = (near * 1.0001 - p[behind, 2]) / (q[behind, 2] - p[behind, 2])
            p[behind] += t[:, None] * (q[behind] - p[behind])
    ua, ub = camera._uv(a), camera._uv(b)
    depth = 0.5 * (a[:, 2] + b[:, 2])

    def draw(gui, sel):
        gui.lines(ua[sel], ub[sel], radius=width, color=_take(color, idx[sel]))

    return depth, draw


def _triangle_layer(camera: Camera, v, f, color):
    c = camera.to_camera(v)
    keep = np.all(c[f, 2] > camera.near, axis=1)
    idx = np.nonzero(keep)[0]
    f = f[idx]
    uv = camera._uv(c)
    depth = c[f, 2].mean(axis=1)
    # Flat Lambert shading from a headlight above and to the left of the camera, two-sided.
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    r, u, fw = camera.basis()
    light = -fw + 0.5 * u - 0.3 * r
    light /= np.linalg.norm(light)
    shade = AMBIENT + (1.0 - AMBIENT) * np.abs(n @ light)
    base = np.full(len(f), color, dtype=np.uint32) if isinstance(color, int) else color[idx]
    rgb = np.stack([(base >> 16) & 255, (base >> 8) & 255, base & 255], axis=1).astype(np.float64)
    rgb = np.clip(np.round(rgb * shade[:, None]), 0, 255).astype(np.uint32)
    shaded = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]

    def draw(gui, sel):
        fs = f[sel]
        gui.triangles(uv[fs[:, 0]], uv[fs[:, 1]], uv[fs[:, 2]], color=np.ascontiguousarray(shaded[sel]))

    return depth, draw


def _paint(gui, layers) -> None:
    """Draw all layers far to near; consecutive primitives of one layer go in one batched call."""
    depth = np.concatenate([d for d, _ in layers]) if layers else np.zeros(0)
    if not len(depth):  # everything culled (behind the camera or off-screen)
        return
    layer = np.concatenate([np.full(len(d), i) for i, (d, _) in enumerate(layers)])
    local = np.concatenate([np.arange(len(d)) for d, _ in layers])
    # Stable sort: at equal depth, later layers (points after lines after triangles) end up on top.
    order = np.argsort(-depth, kind="stable")
    layer, local = layer[order], local[order]
    cuts = np.flatnonzero(np.diff(layer)) + 1
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(layer)], strict=True):
        layers[layer[lo]][1](gui, local[lo:hi])
