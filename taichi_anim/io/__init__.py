"""Output that never feeds back into the simulation: Open3D export, reading it back, and run manifests."""

from .export import (
    area_weighted_normals,
    atomic_path,
    frame_path,
    read_line_set,
    read_point_cloud,
    read_triangle_mesh,
    trails_to_line_set,
    write_line_set,
    write_point_cloud,
    write_triangle_mesh,
)
from .manifest import environment, jsonable, read_manifest, write_manifest

__all__ = [
    "area_weighted_normals",
    "atomic_path",
    "environment",
    "frame_path",
    "jsonable",
    "read_line_set",
    "read_manifest",
    "read_point_cloud",
    "read_triangle_mesh",
    "trails_to_line_set",
    "write_line_set",
    "write_manifest",
    "write_point_cloud",
    "write_triangle_mesh",
]
