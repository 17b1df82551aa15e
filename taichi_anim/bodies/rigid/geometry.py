"""What rigid contacts read of each body's shape, in its principal frame (centre of mass at the origin):
its contact points (a polytope's vertices; a round shape's core segment ends, with its radius), its
signed distance (a round shape's: distance to the core segment minus the radius; a polytope's: the
largest of its face planes' distances, exact inside and up to the face's edge outside, a lower bound
beyond), its bounding sphere and its oriented bounding box. A triangle mesh body's signed distance is its
convex hull's (its own vertices are its contact points)."""

from __future__ import annotations

import numpy as np

from ...shapes import Box, Capsule, ConvexHull, Sphere


def to_principal(points, com, axes) -> np.ndarray:
    """Shape-frame points (N,3) in the principal frame: axes^T (p - com)."""
    return (np.asarray(points, dtype=np.float64) - com) @ axes


def hull_planes(vertices: np.ndarray) -> np.ndarray:
    """(K,4) unit outward normals and offsets (n . x <= d inside) of the convex hull of `vertices`,
    coplanar faces merged."""
    hull = ConvexHull(vertices)
    v, f = hull.vertices, hull.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = np.einsum("fi,fi->f", n, v[f[:, 0]])
    planes = np.column_stack([n, d])
    scale = max(float(np.abs(v).max()), 1e-12)
    key = np.round(planes / [1.0, 1.0, 1.0, scale], 9)
    _, first = np.unique(key, axis=0, return_index=True)
    return planes[np.sort(first)]


def contact_geometry(shape, com: np.ndarray, axes: np.ndarray) -> dict:
    """The arrays rigid contacts read for one body (see the module's docstring)."""
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
            bound=float(np.linalg.norm(ends, axis=1).max() + r),
            half_extents=np.abs(ends).max(axis=0) + r,
        )
    vertices, _ = shape.triangles()
    local = to_principal(np.unique(np.asarray(vertices, dtype=np.float64), axis=0), com, axes)
    return dict(
        points=local,
        point_radius=np.zeros(len(local)),
        round=False,
        box=isinstance(shape, Box),  # its OBB along the principal axes is the box itself
        segment=np.zeros((2, 3)),
        radius=0.0,
        planes=hull_planes(local),
        bound=float(np.linalg.norm(local, axis=1).max()),
        half_extents=np.abs(local).max(axis=0),
    )
