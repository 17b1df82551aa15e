"""Output that never feeds back into the simulation: Open3D export (each file published atomically and
verified complete), reading it back, one USD stage per run (usd.py), run manifests and the output-folder
policy."""

from .atomic import atomic_path, file_record, recording_files, remove_stale_temporaries
from .export import (
    area_weighted_normals,
    frame_digits,
    frame_numbering,
    frame_path,
    read_line_set,
    read_point_cloud,
    read_triangle_mesh,
    trails_to_line_set,
    write_line_set,
    write_point_cloud,
    write_triangle_mesh,
)
from .manifest import (
    check_output_folder,
    environment,
    jsonable,
    prepare_run_folder,
    read_manifest,
    write_manifest,
)
from .usd import UsdStageWriter, write_usd

__all__ = [
    "UsdStageWriter",
    "area_weighted_normals",
    "atomic_path",
    "check_output_folder",
    "environment",
    "file_record",
    "frame_digits",
    "frame_numbering",
    "frame_path",
    "jsonable",
    "prepare_run_folder",
    "read_line_set",
    "read_manifest",
    "read_point_cloud",
    "read_triangle_mesh",
    "recording_files",
    "remove_stale_temporaries",
    "trails_to_line_set",
    "write_line_set",
    "write_manifest",
    "write_point_cloud",
    "write_triangle_mesh",
    "write_usd",
]
