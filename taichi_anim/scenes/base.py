"""Scene: a built model, its state and the integrator that steps it, plus what a frame exports.

Scenes are the examples that the CLI runs, the tests run for a few frames, and the benchmarks time
(Newton's "examples are demos, tests and benchmarks at once")."""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..integrators import Integrator
from ..io.export import frame_path, trails_to_line_set, write_line_set, write_point_cloud
from ..model import Model
from ..render import fit_camera, render_png
from ..state import State


@dataclass
class Scene:
    """name, description; model, state, integrator; dt [s] per step, substeps per frame; bounds: (lo, hi)
    [m] of the region worth looking at; point_radius [m] for rendering; options: the scene's own settings;
    frames: the demo's default length."""

    name: str
    description: str
    model: Model
    state: State
    integrator: Integrator
    dt: float
    substeps: int
    bounds: tuple
    point_radius: float
    options: dict = field(default_factory=dict)
    frames: int = 120  # what `taichi-anim demo NAME` runs without --frames

    @property
    def frame_dt(self) -> float:
        return self.dt * self.substeps

    def advance_frame(self) -> None:
        """Run one frame's substeps (raises DivergenceError on non-finite results)."""
        for _ in range(self.substeps):
            self.integrator.step(self.model, self.state, self.dt)

    def export_frame(self, out_dir, frame: int) -> list[Path]:
        """Write this frame's point cloud (with velocity and age) and, with trails, its line set."""
        snap = self.state.snapshot()
        paths = [
            write_point_cloud(
                frame_path(out_dir, self.name, frame),
                snap.x,
                snap.color,
                attributes={"velocity": snap.v, "age": snap.age},
            )
        ]
        if snap.trails is not None:
            points, lines = trails_to_line_set(snap.trails)
            paths.append(write_line_set(frame_path(out_dir, f"{self.name}_trails", frame), points, lines))
        return paths

    def render(self, path, resolution=(960, 720)) -> Path:
        """A PNG of the current state (headless; no display or Vulkan needed)."""
        snap = self.state.snapshot()
        camera = fit_camera(*self.bounds, resolution=resolution)
        lines = None
        if snap.trails is not None and len(snap.x):
            tr = snap.trails
            lines = (tr[:, :-1].reshape(-1, 3), tr[:, 1:].reshape(-1, 3))
        lo, hi = (np.asarray(b, dtype=float) for b in self.bounds)
        box = _box_edges(lo, hi)
        all_lines = box if lines is None else (np.vstack([lines[0], box[0]]), np.vstack([lines[1], box[1]]))
        return render_png(
            path,
            points=snap.x,
            colors=snap.color,
            radius_px=2.0,
            lines=all_lines,
            line_colors=(0.35, 0.4, 0.45),
            camera=camera,
        )

    def settings(self) -> dict:
        return {
            "scene": self.name,
            "dt": self.dt,
            "substeps": self.substeps,
            "frame_dt": self.frame_dt,
            "integrator": self.integrator.settings(),
            "model": self.model.settings,
            "options": self.options,
        }


def _box_edges(lo, hi):
    """The 12 edges of the box lo..hi as (begin (12,3), end (12,3))."""
    corners = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    pairs = [(i, i | 1 << k) for i in range(8) for k in range(3) if not i >> k & 1]
    a, b = zip(*pairs, strict=True)
    return corners[list(a)], corners[list(b)]
