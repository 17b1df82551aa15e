"""What the rigid kind shows in a frame: every body's shape mesh placed at its pose, as one content
item (content.py) that PLY, USD and the renderer read."""

import numpy as np

from ...content import Mesh, RigidParts
from ...io.export import area_weighted_normals
from .quaternion import quat_to_matrix

BODY_COLOR = (0.55, 0.62, 0.75)


def shape_meshes(model) -> list:
    """Each body's (vertices, faces) in its shape's frame, made once per model."""
    meshes = getattr(model, "_rigid_meshes", None)
    if meshes is None:
        meshes = model._rigid_meshes = [s.triangles() for s in model.rigid_shapes]
    return meshes


def rigid_items(model, state) -> list:
    """One Mesh (role "body", name "bodies") holding every body's surface at its pose now."""
    if not model.rigid_count:
        return []
    snap = state.rigid_snapshot()
    rotations = quat_to_matrix(snap.orientation)
    vertices, faces, start = [], [], 0
    for (v, f), r, p in zip(shape_meshes(model), rotations, snap.position, strict=True):
        vertices.append(v @ r.T + p)
        faces.append(f + start)
        start += len(v)
    v, f = np.concatenate(vertices), np.concatenate(faces)
    parts = RigidParts(shape_meshes(model), snap.position, snap.orientation)
    return [Mesh("bodies", v, f, area_weighted_normals(v, f), BODY_COLOR, role="body", parts=parts)]
