"""Headless PNG rendering of points, lines and shaded triangles with a look-at camera (ti.GUI, no display)."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import taichi as ti

from . import validate
from .errors import ParameterError
from .io.export import atomic_path

DEFAULT_RESOLUTION = (800, 600)
POINT_COLOR = 0xF2C66D
LINE_COLOR = 0x7FB2FF
TRIANGLE_COLOR = 0xB8C0C8
# Lambert shading of triangles: ambient share, the rest scaled by |n . l| (two-sided, cloth has no inside).
AMBIENT = 0.25


@dataclass(frozen=True)
class Camera:
    """Look-at perspective camera; the engine is Y-up.

    eye, target [m]: camera position and the point it looks at; up: a vector not parallel to the view
    direction (default +Y); fov_deg: vertical field of view in degrees, in (0, 180);
    resolution: (width, height) in pixels, both even (video encoders need even sizes); near [m]: points
    closer than this along the view axis are not drawn.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 45.0
    resolution: tuple[int, int] = DEFAULT_RESOLUTION
    near: float = 1e-3

    def __post_init__(self):
        set_ = object.__setattr__  # frozen: normalise the fields once, here
        set_(self, "eye", validate.vec3("eye", self.eye))
        set_(self, "target", validate.vec3("target", self.target))
        set_(self, "up", validate.unit3("up", self.up))
        fov = float(self.fov_deg)
        if not (0.0 < fov < 180.0):
            raise ParameterError(f"fov_deg must lie strictly between 0 and 180, got {self.fov_deg!r}")
        set_(self, "fov_deg", fov)
        set_(self, "near", validate.positive("near", self.near))
        res = tuple(self.resolution)
        if len(res) != 2 or any(isinstance(r, bool) or int(r) != r or r < 2 or int(r) % 2 for r in res):
            raise ParameterError(
                f"resolution must be two even integers >= 2 (width, height), got {self.resolution!r}"
            )
        set_(self, "resolution", (int(res[0]), int(res[1])))
        forward = np.subtract(self.target, self.eye)
        if np.linalg.norm(forward) < 1e-12:
            raise ParameterError(f"eye and target must differ, both are {self.eye}")
        forward = forward / np.linalg.norm(forward)
        if np.linalg.norm(np.cross(forward, self.up)) < 1e-6:
            raise ParameterError(f"up {self.up} must not be parallel to the view direction {tuple(forward)}")

    @property
    def aspect(self) -> float:
        """Width / height."""
        return self.resolution[0] / self.resolution[1]

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit vectors (right, up, forward) of the camera in world coordinates."""
        forward = np.subtract(self.target, self.eye)
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right /= np.linalg.norm(right)
        return right, np.cross(right, forward), forward

    def to_camera(self, points) -> np.ndarray:
        """(N,3) world points [m] -> (N,3) camera coordinates (x right, y up, z depth along the view) [m]."""
        r, u, f = self.basis()
        d = np.asarray(points, dtype=np.float64).reshape(-1, 3) - np.asarray(self.eye)
        return d @ np.stack([r, u, f], axis=1)

    def project(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project (N,3) world points [m].

        Returns uv (N,2): u to the right, v upwards, the image spans [0,1]^2 (pixel column u*W, row from
        the top (1-v)*H; NaN behind the near plane); depth (N,) [m] along the view axis; visible (N,)
        bool: in front of the near plane and inside the image.
        """
        c = self.to_camera(points)
        depth = c[:, 2]
        uv = self._uv(c)
        visible = (depth > self.near) & np.all((uv >= 0.0) & (uv <= 1.0), axis=1)
        return uv, depth, visible

    def _uv(self, c: np.ndarray) -> np.ndarray:
        t = math.tan(math.radians(self.fov_deg) / 2.0)
        z = c[:, 2:3]
        ok = z > self.near
        scale = np.array([t * self.aspect, t])
        ndc = np.divide(c[:, :2], z * scale, out=np.full((len(c), 2), np.nan), where=ok)
        return 0.5 * (ndc + 1.0)


def fit_camera(
    bounds_min,
    bounds_max,
    *,
    direction=(0.6, 0.45, 1.0),
    up=(0.0, 1.0, 0.0),
    fov_deg: float = 40.0,
    resolution: tuple[int, int] = DEFAULT_RESOLUTION,
    margin: float = 1.1,
) -> Camera:
    """A camera looking at the centre of the box [bounds_min, bounds_max] ([m], 3 each) from `direction`.

    The distance makes the box's bounding sphere, enlarged by `margin`, fit both the vertical and the
    horizontal field of view. The default direction looks from the front (+Z), right and above (+Y up).
    """
    lo = np.asarray(validate.vec3("bounds_min", bounds_min))
    hi = np.asarray(validate.vec3("bounds_max", bounds_max))
    if np.any(hi < lo):
        raise ParameterError(f"bounds_max {tuple(hi)} must be >= bounds_min {tuple(lo)} in every axis")
    d = np.asarray(validate.unit3("direction", direction))
    margin = validate.positive("margin", margin)
    center = 0.5 * (lo + hi)
    # A single point or a flat, thin set still needs a finite distance.
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3 * max(1.0, float(np.abs(center).max())))
    half_v = math.radians(float(fov_deg)) / 2.0
    aspect = resolution[0] / resolution[1]
    half = min(half_v, math.atan(math.tan(half_v) * aspect))
    distance = margin * radius / math.sin(half)
    return Camera(
        eye=tuple(center + d * distance),
        target=tuple(center),
        up=up,
        fov_deg=fov_deg,
        resolution=resolution,
        near=1e-3 * distance,
    )


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


def _segments(lines) -> tuple[np.ndarray, np.ndarray]:
    """`lines` as (begin (M,3), end (M,3)) or (points (P,3), indices (L,2) int) -> begin, end."""
    if not isinstance(lines, (tuple, list)) or len(lines) != 2:
        raise ParameterError(
            "lines must be a pair: (begin (M,3), end (M,3)) or (points (P,3), lines (L,2) int)"
        )
    a, b = np.asarray(lines[0]), np.asarray(lines[1])
    if np.issubdtype(b.dtype, np.integer) and b.ndim == 2 and b.shape[1] == 2:
        pts = validate.finite_array("lines[0] (points)", a, (3,))
        idx = validate.indices("lines[1] (indices)", b, 2, len(pts), "points")
        return pts[idx[:, 0]], pts[idx[:, 1]]
    begin = validate.finite_array("lines[0] (begin)", a, (3,))
    end = validate.finite_array("lines[1] (end)", b, (3,))
    if begin.shape != end.shape:
        raise ParameterError(
            f"lines begin and end must have the same shape, got {begin.shape} and {end.shape}"
        )
    return begin, end


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
