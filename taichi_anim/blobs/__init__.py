"""Blobs: the Gaussian blobby field of a particle cloud on a grid (Blinn 1982) and its isosurface as a
closed triangle mesh with normals from the field's gradient (marching cubes, Lorensen & Cline 1987)."""

from .field import BlobField
from .isosurface import BlobMesh, IsosurfaceMethod

__all__ = ["BlobField", "BlobMesh", "IsosurfaceMethod"]
