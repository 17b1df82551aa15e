"""Scene: a built model, its state and the integrator that steps it, plus what a frame exports.

Scenes are the examples that the CLI runs, the tests run for a few frames, and the benchmarks time
(Newton's "examples are demos, tests and benchmarks at once")."""

import numbers
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..bodies.particles.output import cloth_mesh
from ..content import Lines, Mesh, Points, segments_from_pairs
from ..errors import ParameterError
from ..integrators import Integrator
from ..io.export import (
    area_weighted_normals,
    frame_path,
    write_line_set,
    write_point_cloud,
    write_triangle_mesh,
)
from ..model import Model
from ..render import Camera, ColorBy, fit_camera, render_items, write_png
from ..stability import auto_substeps
from ..state import ParticleSnapshot, State

# Cloth: the front colour (the renderer lightens it for the back, so folds read clearly); props
# (colliders drawn for context) in grey.
PROP_COLOR = np.array([0.55, 0.58, 0.62])
GUIDE_COLOR = (0.35, 0.4, 0.45)
RESOLUTION = (960, 720)  # [px] of pictures and videos (even: H.264 needs it)


def check_substeps(substeps):
    """substeps: a positive integer or "auto" (ParameterError otherwise)."""
    if substeps == "auto":
        return substeps
    if isinstance(substeps, bool) or not isinstance(substeps, numbers.Integral) or substeps < 1:
        raise ParameterError(f"substeps must be a positive integer or 'auto', got {substeps!r}")
    return int(substeps)


def frame_step(frame_dt: float, substeps) -> float:
    """The Scene's dt for `substeps` per frame of frame_dt [s]: frame_dt / substeps, or frame_dt itself
    for "auto" (the Scene splits it)."""
    return frame_dt if check_substeps(substeps) == "auto" else frame_dt / substeps


@dataclass
class Scene:
    """name, description; model, state, integrator; dt [s] per step, substeps per frame; bounds: (lo, hi)
    [m] of the region worth looking at; point_radius [m] for rendering; options: the scene's own settings;
    frames: the demo's default length.

    substeps="auto": dt is then the frame's duration [s], split into the smallest number of substeps
    whose step is within the integrator's stability limit on this model (stability.auto_substeps); the
    choice (count, highest frequency, limit) is kept in `substeps_auto` and in settings()."""

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
    props: list = field(default_factory=list)
    guides: tuple | None = None
    view: tuple = (0.6, 0.45, 1.0)
    zoom: float = 1.0
    camera: dict | None = None  # {"eye", "target" [m], "fov_deg"}: a fixed camera instead of view/zoom
    color_by: str | None = None  # what the pictures colour points by by default (None: their colours)
    color_ranges: dict = field(default_factory=dict)  # attribute -> (lo, hi) fixed for every frame
    substeps_auto: dict | None = None  # how substeps="auto" chose the substeps (None: fixed by the scene)
    integrator_choice: dict | None = None  # how integrator="auto" chose the method (choice.Choice.record)

    def __post_init__(self):
        check_substeps(self.substeps)
        if self.substeps == "auto":
            n, self.substeps_auto = auto_substeps(self.model, self.integrator, self.dt, state=self.state)
            self.dt, self.substeps = self.dt / n, n

    @property
    def frame_dt(self) -> float:
        """Duration of one frame [s]: dt x substeps."""
        return self.dt * self.substeps

    def advance_frame(self) -> None:
        """Run one frame's substeps (raises DivergenceError on non-finite results)."""
        self.integrator.stepper_for(self.model).advance(self.state, self.dt, self.substeps)

    def cloth_mesh(self, snap: ParticleSnapshot | None = None):
        """The cloth surface now, or None without cloth: (vertices (V,3) [m], triangles (F,3) int into
        them, particle (V,) model index of each vertex), in the model's particle order (pin indices stay
        valid)."""
        return cloth_mesh(self.model, self.state.snapshot() if snap is None else snap)

    def frame_content(self) -> list:
        """What this instant shows, as content items (content.py) that PLY, USD and the renderer
        all read: each body kind's items (bodies/: for particles the cloth mesh, the particles that are
        no cloth vertex, trails), props as collider meshes and guides as lines."""
        items = [item for kind in self.model.kinds for item in kind.output_items(self.model, self.state)]
        return items + self.prop_items() + self.guide_items()

    def prop_items(self) -> list:
        """The scene's props (colliders drawn for context) as static collider meshes."""
        items = []
        for k, (v, f) in enumerate(self.props):
            v, f = np.asarray(v, dtype=float), np.asarray(f)
            name = "collider" if len(self.props) == 1 else f"collider{k}"
            items.append(
                Mesh(name, v, f, area_weighted_normals(v, f), tuple(PROP_COLOR), "collider", False, False)
            )
        return items

    def guide_items(self) -> list:
        """Guides (the bounds' box edges unless the scene gives its own) as lines that are only drawn."""
        lo, hi = (np.asarray(b, dtype=float) for b in self.bounds)
        begin, end = _box_edges(lo, hi) if self.guides is None else self.guides
        if not len(begin):
            return []
        points, segments = segments_from_pairs(begin, end)
        return [Lines("guides", points, segments, GUIDE_COLOR)]

    def export_frame(self, out_dir, frame: int, items: list | None = None) -> list[Path]:
        """Write this frame's exported items as PLY: the cloth mesh with its normals as `<name>_NNNN.ply`,
        particles (with velocity and age) as a point cloud (`<name>_particles_NNNN.ply` beside cloth),
        trails as a line set, blob surfaces and moving colliders as meshes. NNNN has 4 digits, or as many
        as the run's frame count needs (the runner sets io.export.frame_numbering); every file is
        published only once complete and flushed (io.atomic)."""
        items = self.frame_content() if items is None else items  # the runner's, shared with USD
        return write_items_ply(items, out_dir, self.name, frame)

    def view_camera(self, resolution=RESOLUTION) -> Camera:
        """The demo's camera: `camera` (eye, target, fov_deg) if the scene sets one, else one fitted to
        `bounds` from the direction `view`, closer by `zoom`."""
        if self.camera is not None:
            return Camera(resolution=tuple(resolution), **self.camera)
        lo, hi = (np.asarray(b, dtype=float) for b in self.bounds)
        return fit_camera(lo, hi, direction=self.view, resolution=resolution, margin=1.1 / self.zoom)

    def color_spec(self, color_by: str | None = None) -> ColorBy | None:
        """ColorBy for `color_by` ("speed", "height", "age"; None: the scene's default; "none": the
        items' own colours) with the scene's fixed range for it (height: the bounds' y range)."""
        name = self.color_by if color_by is None else color_by
        if name is None or name == "none":
            return None
        lo, hi = self.color_ranges.get(name, (None, None))
        if name == "height" and name not in self.color_ranges:
            lo, hi = float(self.bounds[0][1]), float(self.bounds[1][1])
        return ColorBy(name, lo, hi)

    def render_frame(
        self,
        resolution=RESOLUTION,
        *,
        color_by: str | None = None,
        samples: int = 2,
        items: list | None = None,
    ):
        """The picture of the current state, (H, W, 3) uint8 (headless; no display or Vulkan needed):
        spheres at their radius and particles as balls of `point_radius`, shaded; cloth smooth-shaded
        with a lighter back; props, trails and guides; colour by an attribute with its legend. items:
        this instant's frame_content(), if the caller has it already."""
        return render_items(
            self.frame_content() if items is None else items,
            self.view_camera(resolution),
            point_radius=self.point_radius,
            color_by=self.color_spec(color_by),
            samples=samples,
        )

    def render(self, path, resolution=RESOLUTION, *, color_by: str | None = None) -> Path:
        """A PNG of the current state (render_frame), written atomically."""
        return write_png(path, self.render_frame(resolution, color_by=color_by))

    def settings(self) -> dict:
        """Everything that defines the run (dt, substeps, their choice, integrator, model, options)."""
        return {
            "scene": self.name,
            "dt": self.dt,
            "substeps": self.substeps,
            "frame_dt": self.frame_dt,
            "substeps_auto": self.substeps_auto,
            "integrator_choice": self.integrator_choice,
            "integrator": self.integrator.settings(),
            "model": self.model.settings,
            "options": self.options,
        }


def floor_outline(lo, hi) -> tuple:
    """Guides: the floor's rectangle (y = 0) under the region lo..hi [m], as (begin (4,3), end (4,3))."""
    floor = np.array([[lo[0], 0.0, lo[2]], [hi[0], 0.0, lo[2]], [hi[0], 0.0, hi[2]], [lo[0], 0.0, hi[2]]])
    return floor, np.roll(floor, -1, axis=0)


def _box_edges(lo, hi):
    """The 12 edges of the box lo..hi as (begin (12,3), end (12,3))."""
    corners = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    pairs = [(i, i | 1 << k) for i in range(8) for k in range(3) if not i >> k & 1]
    a, b = zip(*pairs, strict=True)
    return corners[list(a)], corners[list(b)]


def write_items_ply(items, out_dir, scene: str, frame: int) -> list[Path]:
    """Write every item with `export` set as one PLY file `<scene>[_<item.name>]_NNNN.ply`: meshes with
    their normals, points with their colours and attributes, lines as line sets."""
    paths = []
    for item in items:
        if not item.export:
            continue
        path = frame_path(out_dir, scene if not item.name else f"{scene}_{item.name}", frame)
        if isinstance(item, Mesh):
            paths.append(write_triangle_mesh(path, item.vertices, item.triangles, item.normals))
        elif isinstance(item, Points):
            paths.append(write_point_cloud(path, item.positions, item.colors, attributes=item.attributes))
        else:
            paths.append(write_line_set(path, item.points, item.segments))
    return paths
