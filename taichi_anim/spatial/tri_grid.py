"""Uniform loose grid over axis-aligned boxes: the single-level case of the loose octree (`octree.py`,
Ulrich 2000). Every box goes into the cell of its centre at one level, the deepest whose cell side is
>= the largest box extent, so a cell's loose box (twice the cell) holds each of its boxes; cells are
hashed and counting-sorted as the octree's. The classic grid's weakness is kept on purpose: one large
box makes every cell large (the comparison in benchmarks/results/bvh_study.md shows it)."""

from ..runtime import data_oriented
from .octree import Octree


@data_oriented
class TriGrid(Octree):
    """Uniform loose grid over up to `capacity` boxes; the same fields, build and queries as `Octree`."""

    single_level = True

    def describe(self) -> str:
        """One line for summaries: the method and the boxes held."""
        return f"grid ({self.n} of {self.capacity} boxes)"
