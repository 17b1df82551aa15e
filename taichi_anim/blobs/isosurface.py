"""Isosurface psi = iso of a BlobField as a triangle mesh with normals from the field's analytic gradient.

Extractors (Lorensen & Cline 1987, "Marching Cubes: A High Resolution 3D Surface Construction
Algorithm", and its variants), all on the same grid values with linear interpolation along grid edges:
- OPEN3D: `open3d.t.geometry.TriangleMesh.create_isosurfaces` (VTK's Flying Edges), on the smallest box
  of nodes around the flagged blocks.
- SKIMAGE: `skimage.measure.marching_cubes` (Lewiner et al. 2003), same box; needs scikit-image.
- TAICHI: marching tetrahedra in a Taichi kernel over the flagged blocks only (tetrahedra.py).
The default is OPEN3D, chosen by measurement (benchmarks/blobs.py: a 1000-particle jet, two runs on a
loaded 2-core CPU, so read ratios). All three pass the closed / manifold / orientation checks from 64^3
to 256^3. Extraction alone, Open3D and the tetrahedra are within the noise of each other (128^3: 4.5 /
5.0 ms and 7.3 / 7.6 ms; 256^3: 17 / 26 and 23 / 21 ms) and scikit-image is 2-3x slower. But the
tetrahedra's diagonals make 3.1x the triangles (52.8k against 16.9k at 128^3), so 3x the vertices whose
normals are evaluated, exported and drawn: whole meshing (field, extraction, normals) took 22-31 ms with
Open3D against 42-49 ms with the tetrahedra at 128^3, 72-95 against 151-155 ms at 256^3. Open3D is
already a dependency; scikit-image is not. TAICHI stays as the dependency-free extractor that visits only
flagged blocks (and would run on a GPU, not measured here).

Orientation: triangles are wound counter-clockwise seen from outside, agreeing with the outward normals
-grad psi / |grad psi|. The libraries wind one consistent way that depends on their conventions (and the
axis swap Open3D makes), so the whole mesh is flipped when it disagrees with the field normals.
"""

from dataclasses import dataclass
from enum import Enum

import numpy as np

from .. import validate
from ..errors import ParameterError
from ..io.export import write_triangle_mesh
from .tetrahedra import MarchingTetrahedra


class IsosurfaceMethod(Enum):
    """Who extracts the isosurface: Open3D's Flying Edges, scikit-image's marching cubes, or the Taichi
    marching tetrahedra kernel."""

    OPEN3D = "open3d"
    SKIMAGE = "skimage"
    TAICHI = "taichi"


DEFAULT_METHOD = IsosurfaceMethod.OPEN3D
ORIENT_SAMPLE = 4096  # triangles that decide the whole mesh's winding (_orient)
# Without the surface's normals, the sample's are computed for it: fewer triangles, since every one is
# wound the same way by the extractor (4096 triangles' vertices were 40 % of a 16,000-particle surge's).
ORIENT_SAMPLE_BARE = 256


@dataclass
class BlobMesh:
    """A closed triangle mesh: vertices (V,3) [m], triangles (F,3) int32 counter-clockwise seen from
    outside, normals (V,3) unit outward normals from the field gradient (None for a surface extracted
    without them)."""

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray

    @property
    def triangle_count(self) -> int:
        """Number of triangles F."""
        return len(self.triangles)

    def write(self, path, vertex_colors=None):
        """Write it atomically as .ply (or .obj) with its normals, if it has them; returns the path."""
        return write_triangle_mesh(
            path, self.vertices, self.triangles, vertex_normals=self.normals, vertex_colors=vertex_colors,
            compute_normals=self.normals is not None,
        )  # fmt: skip


def method_of(method) -> IsosurfaceMethod:
    """An IsosurfaceMethod from itself or its name, else ParameterError."""
    if isinstance(method, IsosurfaceMethod):
        return method
    validate.choice("isosurface method", method, [m.value for m in IsosurfaceMethod])
    return IsosurfaceMethod(method)


def extract(field, iso: float, method=DEFAULT_METHOD, normals: bool = True) -> BlobMesh:
    """The isosurface psi = iso (iso > 0 [1]) of `field` (a BlobField after `evaluate`) as a BlobMesh,
    with its vertex normals, or without them (normals=False: only the vertices that decide the winding
    get theirs; the normals took 15-36 % of a liquid's surfacing in benchmarks/fluid_surfacing.py)."""
    verts, tris = extract_triangles(field, iso, method)
    if normals:
        n = field.outward_normals(verts)
        return BlobMesh(verts, _orient(verts, tris, lambda v: n[v]), n)
    return BlobMesh(
        verts, _orient(verts, tris, lambda v: field.outward_normals(verts[v]), ORIENT_SAMPLE_BARE), None
    )


def extract_triangles(field, iso: float, method=DEFAULT_METHOD) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V,3) [m], triangles (F,3) int32) of psi = iso, wound as the extractor makes them."""
    iso = validate.positive("iso", iso)
    method = method_of(method)
    if method == IsosurfaceMethod.TAICHI:
        if getattr(field, "_tetrahedra", None) is None:
            field._tetrahedra = MarchingTetrahedra(field)
        return field._tetrahedra.extract(iso)
    origin, volume = field.active_volume()
    if volume.size == 0 or volume.max() <= iso:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
    if method == IsosurfaceMethod.OPEN3D:
        verts, tris = _open3d(volume, iso)
    else:
        verts, tris = _skimage(volume, iso)
    return np.asarray(field.lo) + field.spacing * (origin + verts), tris


def _open3d(volume: np.ndarray, iso: float) -> tuple[np.ndarray, np.ndarray]:
    import open3d as o3d

    mesh = o3d.t.geometry.TriangleMesh.create_isosurfaces(o3d.core.Tensor(volume), [float(iso)])
    # Flying Edges reads the array as [z, y, x]: its vertex (x, y, z) is our node index (k, j, i).
    verts = mesh.vertex.positions.numpy().astype(np.float64)[:, ::-1]
    return verts, mesh.triangle.indices.numpy().astype(np.int32)


def _skimage(volume: np.ndarray, iso: float) -> tuple[np.ndarray, np.ndarray]:
    try:
        from skimage import measure
    except ImportError as e:  # an optional peer (the `bench` extra), not an engine dependency
        raise ParameterError(
            "isosurface method 'skimage' needs scikit-image (pip install scikit-image); use 'open3d'"
        ) from e
    # allow_degenerate keeps zero-area triangles: dropping them would open holes in the closed mesh.
    verts, faces, _, _ = measure.marching_cubes(volume, float(iso), allow_degenerate=True)
    return verts.astype(np.float64), faces.astype(np.int32)


def _orient(verts: np.ndarray, tris: np.ndarray, normals_of, sample: int = ORIENT_SAMPLE) -> np.ndarray:
    """`tris`, reversed as a whole if their normals mostly disagree with the outward field normals
    (normals_of(indices): those of the vertices `indices`). The extractors wind every triangle one way,
    so a spread of about `sample` of them decides (all of a 58,000-triangle surface took 20 ms)."""
    if not len(tris):
        return tris
    some = tris[:: max(1, len(tris) // sample)]
    face = np.cross(verts[some[:, 1]] - verts[some[:, 0]], verts[some[:, 2]] - verts[some[:, 0]])
    agree = np.einsum("ij,ij->i", face, normals_of(some.ravel()).reshape(-1, 3, 3).sum(axis=1)).sum()
    return tris if agree >= 0 else np.ascontiguousarray(tris[:, ::-1])
