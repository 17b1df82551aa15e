"""What a scene shows at one instant, as plain NumPy items that every output reads the same way.

A frame is a list of items: `Points` (particles or hard spheres), `Mesh` (cloth, blob surfaces,
colliders) and `Lines` (trails, guides). The PLY exporter, the USD stage writer and the renderer all
consume this one list, so a scene says once what it shows and every format shows the same thing (the
`scene description, then one writer per format` split of USD's own exporters and of Blender's).

Units: metres, seconds, Y up. Colours are linear RGB floats in [0, 1]."""

from dataclasses import dataclass, field

import numpy as np

from .errors import ParameterError

# Roles tell writers and the renderer what an item is, not how to draw it.
POINT_ROLES = ("particles", "spheres")
MESH_ROLES = ("cloth", "surface", "collider", "body")
LINE_ROLES = ("trails", "guide")


@dataclass(frozen=True)
class Points:
    """Particles at one instant.

    name: the item's name ("" for the scene's main item; files are `<scene>[_<name>]_NNNN.ply`, USD prims
    `/World/<scene>[_<name>]`); positions (N,3) [m]; colors (N,3) in [0,1]; radii (N,) [m] for hard
    spheres, None for point particles (drawn at `Scene.point_radius`); ids (N,) the model's particle
    index of each point (stable across frames, so a point keeps its identity while others are born and
    die); attributes: per-point arrays written beside the positions, e.g. "velocity" (N,3) [m/s],
    "age" (N,) [s], "radius" (N,) [m]; role: "particles" or "spheres"; export: written to PLY each frame.
    """

    name: str
    positions: np.ndarray
    colors: np.ndarray
    ids: np.ndarray
    radii: np.ndarray | None = None
    attributes: dict = field(default_factory=dict)
    role: str = "particles"
    export: bool = True

    def __post_init__(self):
        _check_role(self.role, POINT_ROLES)


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh at one instant.

    vertices (V,3) [m]; triangles (F,3) int, counter-clockwise seen from the side the normals face;
    normals (V,3) unit vertex normals or None (computed by whoever needs them); color (3,) in [0,1];
    role: "cloth" (two-sided, fixed topology, vertex i is a model particle), "surface" (a blob
    isosurface: topology changes every frame), "collider" (drawn for context) or "body" (rigid bodies
    at their poses); animated: False when the mesh is the same at every frame (a static collider:
    written once); export: written to PLY each frame; parts: the rigid bodies a "body" mesh is made of
    (RigidParts), or None.
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None = None
    color: tuple = (0.7, 0.7, 0.7)
    role: str = "cloth"
    animated: bool = True
    export: bool = True
    parts: "RigidParts | None" = None

    def __post_init__(self):
        _check_role(self.role, MESH_ROLES)

    @property
    def fixed_topology(self) -> bool:
        """True when the triangles are the same at every frame (cloth, colliders), False for surfaces."""
        return self.role != "surface"


@dataclass(frozen=True)
class RigidParts:
    """The rigid bodies a "body" Mesh is made of, for writers that keep bodies apart (USD: one prim per
    body, its mesh once and its pose per frame): meshes, one (vertices (V,3) [m], faces (F,3)) per body in
    its own frame; positions (B,3) [m] and orientations (B,4) (x, y, z, w) place those frames now."""

    meshes: list
    positions: np.ndarray
    orientations: np.ndarray


@dataclass(frozen=True)
class Lines:
    """Line segments at one instant: points (P,3) [m], segments (S,2) int indices into points, color
    (3,) in [0,1]; role "trails" (particle trails, exported) or "guide" (box edges, poles: drawn only)."""

    name: str
    points: np.ndarray
    segments: np.ndarray
    color: tuple = (0.35, 0.4, 0.45)
    role: str = "guide"
    export: bool = False

    def __post_init__(self):
        _check_role(self.role, LINE_ROLES)


def _check_role(role: str, allowed: tuple) -> None:
    if role not in allowed:
        raise ParameterError(f"role must be one of {allowed}, got {role!r}")


def segments_from_pairs(begin, end) -> tuple[np.ndarray, np.ndarray]:
    """(points (2S,3), segments (S,2)) from two (S,3) arrays of segment ends."""
    begin, end = np.asarray(begin, dtype=float), np.asarray(end, dtype=float)
    s = len(begin)
    return np.vstack([begin, end]), np.stack([np.arange(s), np.arange(s) + s], axis=1)


def pairs_from_segments(lines: Lines) -> tuple[np.ndarray, np.ndarray]:
    """The segments' (begin (S,3), end (S,3))."""
    return lines.points[lines.segments[:, 0]], lines.points[lines.segments[:, 1]]
