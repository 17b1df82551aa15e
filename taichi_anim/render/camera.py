"""The pinhole camera of the renderer: a look-at camera (eye, target, up, vertical field of view) and the
perspective projection u = 1/2 + x / (2 z tan(fov/2) aspect), v = 1/2 + y / (2 z tan(fov/2)) of camera
coordinates (x right, y up, z along the view); `fit_camera` frames a box."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import validate
from ..errors import ParameterError

DEFAULT_RESOLUTION = (800, 600)


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
