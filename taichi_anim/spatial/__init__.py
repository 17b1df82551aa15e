"""Geometry for collision detection: bounding volumes, exact primitives (distances, intersections,
continuous tests) and hierarchies (a linear BVH, an octree) with their queries."""

# hierarchies and mesh queries
from .lbvh import BVH, box_area, box_overlap, box_point_dist2, box_segment_entry, morton3  # noqa: F401
from .octree import Octree  # noqa: F401
from .tri_grid import TriGrid  # noqa: F401
