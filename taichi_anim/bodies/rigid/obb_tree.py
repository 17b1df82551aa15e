"""A body's tree of oriented bounding boxes over its convex parts (Gottschalk, Lin & Manocha, "OBBTree: A
Hierarchical Structure for Rapid Interference Detection", SIGGRAPH 1996): the cascade's OBB level
inside a body, so that two bodies of many parts (a mesh's triangles, a decomposition's parts) give the
exact test only to the pairs of parts whose boxes meet, after a descent of about log(parts) levels.

Built top-down as the paper's section 3: a node's box is fitted by the covariance of what it holds (here
the corners of its parts' own boxes; the paper takes the convex hull's triangles) and its axes; it is
split across its longest axis, at the median of its parts' centres (the paper splits at the mean; the
median keeps the tree balanced, at most ceil(log2(parts)) + 1 levels deep). A leaf is one part, with the
part's own box. detection.py walks two bodies' trees together."""

from __future__ import annotations

import numpy as np

# The walk's stack holds at most (depth of a) + (depth of b) node pairs: two trees of up to 2^20 leaves
# (shapes.MAX_CONTACT_TRIANGLES) are 21 levels deep each.
STACK = 64

_SIGNS = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=np.float64)


def _corners(g: dict) -> np.ndarray:
    """The 8 corners (8,3) of part g's box, in the body's principal frame."""
    return (_SIGNS * g["half_extents"]) @ g["rotation"].T + g["offset"]


def _fit(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre (3,), rotation (3,3) whose columns are the box's axes, half extents (3,)) of the box about
    `points` along the eigenvectors of their covariance (a proper rotation)."""
    centred = points - points.mean(axis=0)
    _, axes = np.linalg.eigh(centred.T @ centred)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    along = points @ axes
    low, high = along.min(axis=0), along.max(axis=0)
    return axes @ (0.5 * (low + high)), axes, 0.5 * (high - low)


def obb_tree(geoms: list[dict]) -> dict:
    """The tree of one body's parts: per node (root first) its box's centre `offset` (N,3) and axes
    `rotation` (N,3,3) in the principal frame, `half` extents (N,3), `bound` (N,) the radius of a sphere
    about the centre holding the box, `child` (N,2) its two children's indices (-1: a leaf) and `geom`
    (N,) the part of a leaf (-1: not a leaf)."""
    corners = np.stack([_corners(g) for g in geoms])  # (G,8,3)
    centres = np.array([g["offset"] for g in geoms], dtype=np.float64).reshape(-1, 3)
    nodes: list[list] = []

    def build(parts: np.ndarray) -> int:
        index = len(nodes)
        if len(parts) == 1:
            g = geoms[parts[0]]
            nodes.append([g["offset"], g["rotation"], g["half_extents"], g["bound"], (-1, -1), int(parts[0])])
            return index
        centre, axes, half = _fit(corners[parts].reshape(-1, 3))
        nodes.append([centre, axes, half, float(np.linalg.norm(half)), None, -1])
        along = centres[parts] @ axes[:, int(np.argmax(half))]
        order = parts[np.argsort(along, kind="stable")]
        middle = len(order) // 2
        left = build(order[:middle])
        nodes[index][4] = (left, build(order[middle:]))
        return index

    build(np.arange(len(geoms)))
    fields = list(zip(*nodes, strict=True))
    return dict(
        offset=np.array(fields[0], dtype=np.float64).reshape(-1, 3),
        rotation=np.array(fields[1], dtype=np.float64).reshape(-1, 3, 3),
        half=np.array(fields[2], dtype=np.float64).reshape(-1, 3),
        bound=np.array(fields[3], dtype=np.float64),
        child=np.array(fields[4], dtype=np.int32).reshape(-1, 2),
        geom=np.array(fields[5], dtype=np.int32),
    )
