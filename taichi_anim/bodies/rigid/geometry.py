"""What rigid contacts read of each body's shape, in its principal frame (centre of mass at the origin),
per convex part (a geom: the shape itself, or each part of a compound, placed in that frame): its
contact points (a polytope's vertices; a round shape's core segment ends, with its radius), its
signed distance (a round shape's: distance to the core segment minus the radius; a polytope's: the
largest of its face planes' distances, exact inside and up to the face's edge outside, a lower bound
beyond), its bounding sphere and its oriented bounding box. A triangle mesh body collides as its convex
hull, as convex parts, or as its triangles, each a prism reaching inwards from the surface (a convex
polytope like any other: the separating-axis test, face clipping and GJK take it as they are). Every
body's parts sit in a tree of oriented bounding boxes (obb_tree.py)."""

from __future__ import annotations

import numpy as np

from ...shapes import Box, Capsule, ConvexHull, Sphere
from .obb_tree import obb_tree


def to_principal(points, com, axes) -> np.ndarray:
    """Shape-frame points (N,3) in the principal frame: axes^T (p - com)."""
    return (np.asarray(points, dtype=np.float64) - com) @ axes


def hull_features(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces and edges of the convex hull of `vertices`, coplanar triangles merged into one face:
    (K,4) unit outward normals and offsets (n . x <= d inside), and (E,4,3) edges, each its two end
    points and the normals of the two faces it joins (what the Gauss-map pruning of sat.py reads)."""
    hull = ConvexHull(vertices)
    v, f = hull.vertices, hull.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = np.einsum("fi,fi->f", n, v[f[:, 0]])
    planes = np.column_stack([n, d])
    scale = max(float(np.abs(v).max()), 1e-12)
    key = np.round(planes / [1.0, 1.0, 1.0, scale], 9)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    face_of = np.argsort(order)[inverse.reshape(-1)]  # each triangle's merged face, in first-seen order
    faces = planes[first[order]]
    # an edge joins two triangles; it is a hull edge where they lie on different faces
    ends = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    owner = np.concatenate([np.arange(len(f))] * 3)
    sort = np.lexsort((ends[:, 1], ends[:, 0]))
    ends, owner = ends[sort].reshape(-1, 2, 2), owner[sort].reshape(-1, 2)  # closed: two triangles each
    f0, f1 = face_of[owner[:, 0]], face_of[owner[:, 1]]
    keep = f0 != f1
    edges = np.stack(
        [v[ends[keep, 0, 0]], v[ends[keep, 0, 1]], faces[f0[keep], :3], faces[f1[keep], :3]], axis=1
    )
    return faces, edges


def _convex_geometry(shape, com: np.ndarray, axes: np.ndarray) -> dict:
    """One convex part's arrays, in the frame axes^T (p - com) of its shape's points."""
    if isinstance(shape, (Sphere, Capsule)):
        half = shape.half_length if isinstance(shape, Capsule) else 0.0
        ends = to_principal([[0.0, -half, 0.0], [0.0, half, 0.0]], com, axes)
        r = shape.radius
        points = ends[:1] if half == 0.0 else ends
        return dict(
            points=points,
            point_radius=np.full(len(points), r),
            round=True,
            box=False,
            segment=ends,
            radius=r,
            planes=np.zeros((0, 4)),
            edges=np.zeros((0, 4, 3)),
            half_extents=np.abs(ends).max(axis=0) + r,
        )
    vertices, _ = shape.triangles()
    local = to_principal(np.unique(np.asarray(vertices, dtype=np.float64), axis=0), com, axes)
    planes, edges = hull_features(local)
    return dict(
        points=local,
        point_radius=np.zeros(len(local)),
        round=False,
        box=isinstance(shape, Box),  # its OBB along the principal axes is the box itself
        segment=np.zeros((2, 3)),
        radius=0.0,
        planes=planes,
        edges=edges,
        half_extents=np.abs(local).max(axis=0),
    )


def _prism_geometry(prism: np.ndarray) -> dict:
    """One triangle prism's arrays, (6,3) points in the principal frame: the surface triangle (counter-
    clockwise seen from outside) then its corners moved inwards. Its frame: the origin at its centroid
    (inside it, as sat.py's edge axes need), z along the triangle's outward normal and x along its
    longest edge, so that its box (geom_half) is tight about it; faces and edges in closed form."""
    top = prism[:3]
    n = np.cross(top[1] - top[0], top[2] - top[0])
    n /= np.linalg.norm(n)
    k = int(np.argmax(np.linalg.norm(top - np.roll(top, 1, axis=0), axis=1)))
    x = top[k] - top[k - 1]
    x -= n * (n @ x)
    x /= np.linalg.norm(x)
    rotation = np.column_stack([x, np.cross(n, x), n])
    centre = prism.mean(axis=0)
    local = (prism - centre) @ rotation
    z_top, z_bottom = local[0, 2], local[3, 2]
    sides = []
    for i in range(3):
        d = local[(i + 1) % 3, :2] - local[i, :2]
        m = np.array([d[1], -d[0], 0.0]) / np.hypot(d[0], d[1])  # outwards: the triangle winds about +z
        sides.append(np.append(m, m @ local[i]))
    up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    planes = np.array([[0.0, 0.0, 1.0, z_top], [0.0, 0.0, -1.0, -z_bottom], *sides])
    edges = []
    for i in range(3):
        j, side, before = (i + 1) % 3, sides[i][:3], sides[i - 1][:3]
        edges.append([local[i], local[j], up, side])
        edges.append([local[3 + i], local[3 + j], down, side])
        edges.append([local[i], local[3 + i], before, side])
    return dict(
        points=local,
        point_radius=np.zeros(6),
        round=False,
        box=False,
        segment=np.zeros((2, 3)),
        radius=0.0,
        planes=planes,
        edges=np.array(edges),
        half_extents=np.abs(local).max(axis=0),
        offset=centre,
        rotation=rotation,
        prism=True,
    )


def contact_geometry(shape, com: np.ndarray, axes: np.ndarray) -> dict:
    """The arrays rigid contacts read for one body (see the module's docstring): its convex parts
    ("geoms", one for a simple shape, in the principal frame; a compound's, each in its own frame at an
    offset and rotation in the principal frame) and the body's bounding sphere and OBB about its centre of
    mass, along its principal axes."""
    parts = shape.contact_parts()  # a compound's parts, a mesh's convex decomposition; None: itself
    prisms = shape.contact_prisms()  # a mesh's triangles as prisms; None: not so
    if prisms is not None:
        geoms = [_prism_geometry(to_principal(p, com, axes)) for p in prisms]
        for g, active in zip(geoms, shape.contact_active_edges(), strict=True):
            g["active_edges"] = int(sum(1 << k for k in range(3) if active[k]))
        # As contact points (against other bodies and the colliders), each vertex of the surface once,
        # in the first prism that has it, and no inner corner: a vertex shared by six triangles would
        # otherwise be six contacts against each part it meets.
        _, first = np.unique(prisms[:, :3].reshape(-1, 3), axis=0, return_index=True)
        owned = np.zeros(3 * len(prisms), dtype=bool)
        owned[first] = True
        for k, g in enumerate(geoms):
            g["contact_points"] = np.concatenate([owned[3 * k : 3 * k + 3], np.zeros(3, dtype=bool)])
    elif parts is not None:
        geoms = []
        for part, t, r in parts:
            # each part's frame at its own centre of mass: inside it, as the separating-axis test's
            # orientation of edge axes needs (sat.py)
            centre = part.mass_properties(1.0).com
            geom = _convex_geometry(part, centre, np.eye(3))
            geom.update(offset=axes.T @ (t + r @ centre - com), rotation=axes.T @ r)
            geoms.append(geom)
    else:
        geoms = [dict(_convex_geometry(shape, com, axes), offset=np.zeros(3), rotation=np.eye(3))]
    reach, extent = 0.0, np.zeros(3)
    for g in geoms:
        g.setdefault("contact_points", np.ones(len(g["points"]), dtype=bool))
        g.setdefault("prism", False)
        g.setdefault("active_edges", 0)
        g["bound"] = float(np.linalg.norm(g["points"], axis=1).max() + g["radius"])
        placed = g["points"] @ g["rotation"].T + g["offset"]
        reach = max(reach, float(np.linalg.norm(placed, axis=1).max() + g["radius"]))
        extent = np.maximum(extent, np.abs(placed).max(axis=0) + g["radius"])
    return dict(geoms=geoms, bound=reach, half_extents=extent, tree=obb_tree(geoms))
