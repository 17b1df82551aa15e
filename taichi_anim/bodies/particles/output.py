"""What the particle kind shows in a frame, as content items (content.py) that PLY, USD and the renderer
all read: the cloth surface (vertex normals area-weighted), the particles that are no cloth vertex (with
velocity and age, and their radius where they have one) and the trails."""

import numpy as np

from ...content import Lines, Mesh, Points
from ...io.export import area_weighted_normals, trails_to_line_set

CLOTH_FRONT = (0.95, 0.42, 0.3)  # the cloth's colour where a picture does not colour it by a quantity
TRAIL_COLOR = (0.5, 0.7, 1.0)


def cloth_mesh(model, snap):
    """The cloth surface in snapshot `snap`, or None without cloth: (vertices (V,3) [m], triangles (F,3)
    int into them, particle (V,) model index of each vertex). Vertices keep the model's particle order, so
    a model of cloth only exports its particles as they are numbered (pin indices stay valid)."""
    tri = model.triangles
    if tri is None:
        return None
    used = np.unique(tri)
    rows = np.searchsorted(snap.index, used)  # cloth vertices never die, so every one is in snap
    return snap.x[rows], np.searchsorted(used, tri), used


def particle_items(model, state) -> list:
    """The particle kind's content items now: the cloth mesh (role "cloth"), the other particles as
    points, and the trails (role "trails")."""
    if not model.particle_count:  # a scene of rigid bodies only
        return []
    snap = state.snapshot()
    mesh = cloth_mesh(model, snap)
    items = []
    keep = np.ones(len(snap.x), dtype=bool)
    if mesh is not None:
        vertices, triangles, particle = mesh
        normals = area_weighted_normals(vertices, triangles)
        items.append(Mesh("", vertices, triangles, normals, CLOTH_FRONT, role="cloth"))
        keep = ~np.isin(snap.index, particle)
    if mesh is None or keep.any():
        index = snap.index[keep]
        # particles given a radius are balls of that radius in every output; points have none
        radii = model.particle_radii(index) if model.max_radius > 0 else None
        items.append(
            Points(
                "" if mesh is None else "particles",
                snap.x[keep],
                snap.color[keep],
                index,
                radii,
                attributes={"velocity": snap.v[keep], "age": snap.age[keep]},
            )
        )
    if snap.trails is not None:
        points, lines = trails_to_line_set(snap.trails)
        items.append(Lines("trails", points, lines, color=TRAIL_COLOR, role="trails", export=True))
    return items
