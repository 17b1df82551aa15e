"""Geometry for collision detection: bounding volumes, exact primitives (distances, intersections,
continuous tests) and hierarchies (a linear BVH, an octree) with their queries."""

# Bounding volumes and exact primitives (`@ti.func`s), re-exported explicitly (`name as name`).
from .bounds import (
    aabb_contains as aabb_contains,
)
from .bounds import (
    aabb_edge as aabb_edge,
)
from .bounds import (
    aabb_merge as aabb_merge,
)
from .bounds import (
    aabb_overlap as aabb_overlap,
)
from .bounds import (
    aabb_point as aabb_point,
)
from .bounds import (
    aabb_point_distance_sq as aabb_point_distance_sq,
)
from .bounds import (
    aabb_ray as aabb_ray,
)
from .bounds import (
    aabb_sphere_overlap as aabb_sphere_overlap,
)
from .bounds import (
    aabb_surface_area as aabb_surface_area,
)
from .bounds import (
    aabb_swept_edge as aabb_swept_edge,
)
from .bounds import (
    aabb_swept_point as aabb_swept_point,
)
from .bounds import (
    aabb_swept_triangle as aabb_swept_triangle,
)
from .bounds import (
    aabb_triangle as aabb_triangle,
)
from .bounds import (
    sphere_edge as sphere_edge,
)
from .bounds import (
    sphere_overlap as sphere_overlap,
)
from .bounds import (
    sphere_triangle as sphere_triangle,
)
