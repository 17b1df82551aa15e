"""Geometry for collision detection: bounding volumes, exact primitives (distances, intersections,
continuous tests) and hierarchies (a linear BVH, an octree) with their queries."""
