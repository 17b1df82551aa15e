"""Geometry for collision detection: bounding volumes, exact primitives (distances, intersections,
continuous tests) and hierarchies (a linear BVH, an octree) with their queries."""

# Bounding volumes and exact primitives (`@ti.func`s).
from .bounds import (
    aabb_contains,
    aabb_edge,
    aabb_merge,
    aabb_overlap,
    aabb_point,
    aabb_point_distance_sq,
    aabb_ray,
    aabb_sphere_overlap,
    aabb_surface_area,
    aabb_swept_edge,
    aabb_swept_point,
    aabb_swept_triangle,
    aabb_triangle,
    sphere_edge,
    sphere_overlap,
    sphere_triangle,
)
from .ccd import (
    ccd_edge_edge,
    ccd_point_triangle,
)
from .crossings import Separation, intersecting_triangle_pairs, min_separation
from .distance import (
    point_segment_closest,
    point_triangle_closest,
    point_triangle_distance_sq,
    point_triangle_feature,
    segment_segment_closest,
)
from .intersect import (
    NO_HIT,
    ray_triangle,
    segment_triangle,
    triangle_triangle_intersect,
)
from .lbvh import BVH, morton3
from .mesh_check import MeshReport, mesh_report, triangle_pairs_intersect
from .mesh_query import (
    TriangleMesh,
    check_mesh,
    inside_closed_mesh,
    triangle_box_overlap,
    triangle_solid_angle,
    winding_number_np,
)
from .octree import Octree
from .select import BoxQueryMethod, BruteBoxes, choose_box_query, make_box_query
from .tri_grid import TriGrid

__all__ = [
    "BVH",
    "BoxQueryMethod",
    "BruteBoxes",
    "choose_box_query",
    "make_box_query",
    "Separation",
    "intersecting_triangle_pairs",
    "min_separation",
    "MeshReport",
    "mesh_report",
    "triangle_pairs_intersect",
    "TriangleMesh",
    "check_mesh",
    "triangle_box_overlap",
    "triangle_solid_angle",
    "winding_number_np",
    "inside_closed_mesh",
    "Octree",
    "TriGrid",
    "morton3",
    "aabb_contains",
    "aabb_edge",
    "aabb_merge",
    "aabb_overlap",
    "aabb_point",
    "aabb_point_distance_sq",
    "aabb_ray",
    "aabb_sphere_overlap",
    "aabb_surface_area",
    "aabb_swept_edge",
    "aabb_swept_point",
    "aabb_swept_triangle",
    "aabb_triangle",
    "sphere_edge",
    "sphere_overlap",
    "sphere_triangle",
    "point_segment_closest",
    "point_triangle_closest",
    "point_triangle_distance_sq",
    "point_triangle_feature",
    "segment_segment_closest",
    "NO_HIT",
    "ray_triangle",
    "segment_triangle",
    "triangle_triangle_intersect",
    "ccd_edge_edge",
    "ccd_point_triangle",
]
