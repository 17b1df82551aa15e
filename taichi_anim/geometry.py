"""Cloth meshes in plain NumPy: regular grids, spring layouts, lumped masses, validation and loading.

Springs follow Provot 1995, "Deformation constraints in a mass-spring model to describe rigid cloth
behavior" (Graphics Interface '95): stretch springs join direct neighbours, shear springs the two
diagonals of every quad, bend springs vertices two apart. `mesh_springs` recovers the same roles on a
general triangle mesh. Masses are lumped as in Baraff & Witkin 1998, "Large steps in cloth simulation"
(SIGGRAPH '98): each triangle's mass is shared equally by its three vertices.
"""

from __future__ import annotations

import enum
import itertools
import os
from dataclasses import dataclass

import numpy as np

from . import validate
from .errors import ParameterError
from .io.export import read_triangle_mesh

# Relative to the bounding-box diagonal, so that the checks do not depend on the mesh's units.
AREA_TOLERANCE = 1e-12  # a triangle of area <= AREA_TOLERANCE * diagonal^2 is degenerate
DUPLICATE_TOLERANCE = 1e-9  # vertices closer than DUPLICATE_TOLERANCE * diagonal are duplicates
# An edge is "longest" only if clearly so: the equal edges of an equilateral mesh are no quad diagonals.
_LONGEST_MARGIN = 1e-9
# Peak NumPy memory per grid vertex [bytes] (tracemalloc, 1000^2 grid): cloth_grid ~176, grid_springs
# ~500 beyond the grid. Resolutions are checked against them before the arrays are built.
_GRID_BYTES_PER_VERTEX = 170
_GRID_SPRING_BYTES_PER_VERTEX = 490


class SpringFamily(enum.Enum):
    """Provot's spring roles; the position in this enum is the int8 code in `ClothSprings.family`."""

    STRETCH = "stretch"
    SHEAR = "shear"
    BEND = "bend"


_FAMILY_CODE = {family: code for code, family in enumerate(SpringFamily)}


@dataclass(frozen=True)
class ClothSprings:
    """The springs of one cloth.

    pairs: (S,2) int64 vertex indices, i < j in each row, each pair once in the whole array.
    family: (S,) int8 SpringFamily code: 0 stretch, 1 shear, 2 bend.
    """

    pairs: np.ndarray
    family: np.ndarray

    def pairs_of(self, family: SpringFamily) -> np.ndarray:
        """(K,2) int64 pairs of one family."""
        return self.pairs[self.family == _FAMILY_CODE[family]]


def cloth_grid(
    *, origin=(0.0, 0.0, 0.0), size=(1.0, 1.0), resolution=(32, 32), plane="xz"
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (nx*ny,3) float64 [m] and triangles (2(nx-1)(ny-1),3) int64 of a regular grid.

    origin [m]: position of vertex 0. size [m]: (width, depth) of the whole grid. resolution: (nx, ny)
    vertices per side, each >= 2. plane "xz" puts vertex (i, j) at origin + (i*dx, 0, j*dz) (horizontal in
    the Y-up engine), "xy" at origin + (i*dx, j*dy, 0). Vertex index = j*nx + i. Quad (i, j) becomes
    triangles 2q and 2q+1 (q = j*(nx-1) + i), split along its diagonal (i,j)-(i+1,j+1) and wound
    counter-clockwise seen from +y ("xz") or +z ("xy").
    """
    nx, ny = _resolution(resolution, _GRID_BYTES_PER_VERTEX)
    width, depth = (validate.positive(f"size[{k}]", s) for k, s in enumerate(_pair("size", size)))
    start = np.asarray(validate.vec3("origin", origin))
    if plane not in ("xz", "xy"):
        raise ParameterError(f"plane must be 'xz' or 'xy', got {plane!r}")
    u, v = np.meshgrid(np.linspace(0.0, width, nx), np.linspace(0.0, depth, ny))  # both (ny, nx)
    vertices = np.zeros((nx * ny, 3))
    vertices[:, 0] = u.ravel()
    vertices[:, 2 if plane == "xz" else 1] = v.ravel()
    vertices += start

    index = np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)
    v00, v10 = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    v01, v11 = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    # x cross z = -y, so the xz grid needs the opposite winding of the xy grid to face +y.
    if plane == "xz":
        pair = (np.stack([v00, v11, v10], axis=1), np.stack([v00, v01, v11], axis=1))
    else:
        pair = (np.stack([v00, v10, v11], axis=1), np.stack([v00, v11, v01], axis=1))
    return vertices, np.stack(pair, axis=1).reshape(-1, 3)


def grid_springs(resolution) -> ClothSprings:
    """Provot's springs on the grid of `cloth_grid(resolution=...)`.

    Stretch: horizontal and vertical neighbours, (nx-1)ny + nx(ny-1). Shear: both diagonals of every quad,
    2(nx-1)(ny-1). Bend: vertices two apart horizontally and vertically, (nx-2)ny + nx(ny-2).
    """
    nx, ny = _resolution(resolution, _GRID_SPRING_BYTES_PER_VERTEX)
    index = np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)  # index[j, i] = j*nx + i
    blocks = {
        SpringFamily.STRETCH: [(index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])],
        SpringFamily.SHEAR: [(index[:-1, :-1], index[1:, 1:]), (index[:-1, 1:], index[1:, :-1])],
        SpringFamily.BEND: [(index[:, :-2], index[:, 2:]), (index[:-2, :], index[2:, :])],
    }
    groups = [
        (family, np.concatenate([np.stack([a.ravel(), b.ravel()], axis=1) for a, b in pairs]))
        for family, pairs in blocks.items()
    ]
    return _unique_springs(groups, nx * ny)


def mesh_springs(vertices, triangles) -> ClothSprings:
    """Provot's springs on a general triangle mesh (validated first, see `validate_mesh`).

    Stretch: every mesh edge. For each interior edge with opposite vertices a and b: if the edge is the
    longest of both its triangles, it is the diagonal of a split quad and (a, b) is the quad's other
    diagonal, a shear spring; otherwise (a, b) is a bend spring. A pair already present keeps its first
    family in the order stretch, shear, bend.
    """
    vertices, triangles = validate_mesh(vertices, triangles)
    count = len(vertices)
    # Half-edge k of a triangle joins its other two vertices; the triangle's vertex k is its opposite.
    ends_a, ends_b = triangles[:, [1, 2, 0]], triangles[:, [2, 0, 1]]
    length2 = np.sum((vertices[ends_a] - vertices[ends_b]) ** 2, axis=-1)
    others = np.maximum(length2[:, [1, 2, 0]], length2[:, [2, 0, 1]])
    longest = (length2 > others * (1.0 + _LONGEST_MARGIN)).ravel()
    opposite = triangles.ravel()
    keys = (np.minimum(ends_a, ends_b) * count + np.maximum(ends_a, ends_b)).ravel()

    order = np.argsort(keys, kind="stable")
    edges, first, uses = np.unique(keys[order], return_index=True, return_counts=True)
    interior = first[uses == 2]
    side0, side1 = order[interior], order[interior + 1]
    across = np.stack([opposite[side0], opposite[side1]], axis=1)
    is_shear = longest[side0] & longest[side1]
    groups = [
        (SpringFamily.STRETCH, np.stack([edges // count, edges % count], axis=1)),
        (SpringFamily.SHEAR, across[is_shear]),
        (SpringFamily.BEND, across[~is_shear]),
    ]
    return _unique_springs(groups, count)


def lumped_masses(vertices, triangles, density) -> np.ndarray:
    """(V,) vertex masses [kg]: each triangle's area [m^2] * density [kg/m^2], a third to each vertex.

    Vertices used by no triangle get mass 0.
    """
    density = validate.positive("density", density)
    vertices, triangles = validate_mesh(vertices, triangles)
    share = _triangle_areas(vertices, triangles) * (density / 3.0)
    return np.bincount(triangles.ravel(), weights=np.repeat(share, 3), minlength=len(vertices))


def validate_mesh(vertices, triangles, *, name="mesh") -> tuple[np.ndarray, np.ndarray]:
    """Checked copies of a triangle mesh: vertices (V,3) float64 [m], triangles (F,3) int64.

    Raises ParameterError, naming the offending vertex, triangle or edge, for an empty mesh, wrong shapes,
    non-finite coordinates, indices out of range or repeated within a triangle, duplicate vertices,
    zero-area triangles, duplicate triangles and edges shared by more than two triangles. Unused vertices
    are allowed.
    """
    try:
        verts = np.array(vertices, dtype=np.float64)
        tris = np.array(triangles)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name}: vertices and triangles must be numeric arrays ({exc})") from None
    if verts.size == 0 or tris.size == 0:
        raise ParameterError(f"{name}: empty mesh ({verts.size // 3} vertices, {tris.size // 3} triangles)")
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise ParameterError(f"{name}: vertices must have shape (V, 3), got {verts.shape}")
    if tris.ndim != 2 or tris.shape[1] != 3 or not np.issubdtype(tris.dtype, np.integer):
        raise ParameterError(
            f"{name}: triangles must be integers of shape (F, 3), got {tris.dtype} {tris.shape}"
        )
    tris = tris.astype(np.int64)
    _check_indices(verts, tris, name)
    _check_vertices(verts, name)
    _check_triangles(verts, tris, name)
    _check_manifold(tris, name)
    return verts, tris


def load_mesh(mesh, *, name="mesh", check=None) -> tuple[np.ndarray, np.ndarray]:
    """`check(vertices, triangles, name=)` (default `validate_mesh`, the cloth's strict checks) of an
    Open3D TriangleMesh (legacy or tensor), a mesh file, or (vertices, triangles).

    A file is any path Open3D reads (PLY, OBJ, ...); a missing or unreadable one raises ParameterError.
    """
    check = validate_mesh if check is None else check
    if isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        return check(mesh[0], mesh[1], name=name)
    if isinstance(mesh, (str, os.PathLike)):
        # The reader in io.export guards against Open3D's silent failures (truncated PLY, OBJ crashes).
        try:
            data = read_triangle_mesh(mesh)
        except FileNotFoundError:
            raise ParameterError(f"{name}: file not found: {os.fspath(mesh)}") from None
        except ParameterError as exc:
            raise ParameterError(f"{name}: {exc}") from None
        return check(data["vertices"], data["triangles"], name=f"{name} ({os.fspath(mesh)})")
    import open3d as o3d

    if isinstance(mesh, o3d.geometry.TriangleMesh):
        return check(np.asarray(mesh.vertices), np.asarray(mesh.triangles), name=name)
    if isinstance(mesh, o3d.t.geometry.TriangleMesh):
        mesh = mesh.cpu()
        verts = mesh.vertex.positions.numpy() if "positions" in mesh.vertex else np.zeros((0, 3))
        tris = mesh.triangle.indices.numpy() if "indices" in mesh.triangle else np.zeros((0, 3), np.int64)
        return check(verts, tris, name=name)
    raise ParameterError(
        f"{name}: expected an Open3D TriangleMesh, a file path or (vertices, triangles), got {type(mesh)}"
    )


# ------------------------------------------------------------------------------------------- helpers


def _pair(name: str, value) -> tuple:
    if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or len(value) != 2:
        raise ParameterError(f"{name} must be a pair of numbers, got {value!r}")
    return tuple(value)


def _resolution(resolution, bytes_each: float) -> tuple[int, int]:
    nx, ny = _pair("resolution", resolution)
    nx, ny = validate.count("resolution[0]", nx, 2), validate.count("resolution[1]", ny, 2)
    name = f"resolution {(nx, ny)}"
    # Triangles hold 6 vertex indices per vertex (springs up to 12 ends): the kernels index them with int32.
    validate.capacity(name, 6 * (nx - 1) * (ny - 1), bytes_each=0, unit="triangle corners")
    validate.capacity(name, nx * ny, bytes_each=bytes_each, unit="grid vertices")
    return nx, ny


def _unique_springs(groups: list[tuple[SpringFamily, np.ndarray]], vertex_count: int) -> ClothSprings:
    """Concatenate (family, (K,2) pairs) groups, order each pair i < j and keep each pair's first entry."""
    pairs = np.sort(np.concatenate([p.reshape(-1, 2) for _, p in groups]).astype(np.int64), axis=1)
    family = np.concatenate([np.full(len(p), _FAMILY_CODE[f], dtype=np.int8) for f, p in groups])
    _, first = np.unique(pairs[:, 0] * vertex_count + pairs[:, 1], return_index=True)
    keep = np.sort(first)  # np.unique reports first occurrences; sorting restores family order
    return ClothSprings(pairs=pairs[keep], family=family[keep])


def _triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _corners(tris: np.ndarray, t: int) -> str:
    return "vertices " + ", ".join(str(v) for v in tris[t].tolist())


def _diagonal(vertices: np.ndarray) -> float:
    return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


def _check_indices(verts: np.ndarray, tris: np.ndarray, name: str) -> None:
    bad = np.flatnonzero(((tris < 0) | (tris >= len(verts))).any(axis=1))
    if bad.size:
        t = int(bad[0])
        raise ParameterError(
            f"{name}: triangle {t} has a vertex index outside [0, {len(verts)}) ({_corners(tris, t)})"
        )
    bad = np.flatnonzero((tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2]))
    if bad.size:
        t = int(bad[0])
        raise ParameterError(f"{name}: triangle {t} repeats a vertex ({_corners(tris, t)})")


def _check_vertices(verts: np.ndarray, name: str) -> None:
    bad = np.flatnonzero(~np.isfinite(verts).all(axis=1))
    if bad.size:
        raise ParameterError(f"{name}: vertex {bad[0]} is not finite ({verts[bad[0]].tolist()})")
    tolerance = DUPLICATE_TOLERANCE * _diagonal(verts)
    close = (0, 1) if tolerance == 0.0 else _close_vertex_pair(verts, tolerance)
    if close is not None:
        i, j = close
        distance = float(np.linalg.norm(verts[i] - verts[j]))
        raise ParameterError(
            f"{name}: vertices {i} and {j} are duplicates (distance {distance:.3g} < {tolerance:.3g})"
        )


def _close_vertex_pair(verts: np.ndarray, tolerance: float) -> tuple[int, int] | None:
    """A pair (i, j), i < j, of vertices closer than `tolerance`, or None, in O(V log V).

    Vertices are binned into cubes of side 4*tolerance, once for each of the 8 grids shifted by half a
    cube along a subset of the axes. A pair closer than `tolerance` is closer than half a cube on every
    axis, so on each axis one of the two offsets leaves no cube boundary between them: some shifted grid
    puts them in one cube. Vertices sharing a cube (none in a clean mesh) are then compared exactly.
    """
    scaled = (verts - verts.min(axis=0)) / (4.0 * tolerance)
    for shift in itertools.product((0.0, 0.5), repeat=3):
        cells = np.floor(scaled + np.asarray(shift)).astype(np.int64)
        order = np.lexsort(cells.T[::-1])
        starts = np.flatnonzero(np.r_[True, (cells[order[1:]] != cells[order[:-1]]).any(axis=1), True])
        crowded = np.flatnonzero(np.diff(starts) > 1)
        for start, stop in zip(starts[crowded], starts[crowded + 1], strict=True):
            # Sphere packing fits at most 239 vertices `tolerance` apart in one cube, so among any 256
            # of a crowded cube two are closer.
            ids = np.sort(order[start : min(stop, start + 256)])
            close = np.linalg.norm(verts[ids, None] - verts[None, ids], axis=-1) < tolerance
            a, b = np.nonzero(np.triu(close, k=1))
            if a.size:
                return int(ids[a[0]]), int(ids[b[0]])
    return None


def _check_triangles(verts: np.ndarray, tris: np.ndarray, name: str) -> None:
    areas = _triangle_areas(verts, tris)
    limit = AREA_TOLERANCE * _diagonal(verts) ** 2
    bad = np.flatnonzero(areas <= limit)
    if bad.size:
        t = int(bad[0])
        raise ParameterError(
            f"{name}: triangle {t} has zero area ({_corners(tris, t)}; area {areas[t]:.3g} <= {limit:.3g})"
        )
    _, first, inverse = np.unique(np.sort(tris, axis=1), axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()  # NumPy 2.0.0 returned it with an extra axis
    repeats = np.flatnonzero(first[inverse] != np.arange(len(tris)))
    if repeats.size:
        t = int(repeats[0])
        raise ParameterError(
            f"{name}: triangle {t} repeats triangle {first[inverse[t]]} ({_corners(tris, t)})"
        )


def _check_manifold(tris: np.ndarray, name: str) -> None:
    count = int(tris.max()) + 1
    keys = (np.minimum(tris, tris[:, [1, 2, 0]]) * count + np.maximum(tris, tris[:, [1, 2, 0]])).ravel()
    edges, uses = np.unique(keys, return_counts=True)
    crowded = np.flatnonzero(uses > 2)
    if crowded.size:
        owners = np.flatnonzero(keys == edges[crowded[0]]) // 3
        a, b = divmod(int(edges[crowded[0]]), count)
        raise ParameterError(
            f"{name}: edge ({a}, {b}) is shared by {len(owners)} triangles {owners.tolist()} "
            "(non-manifold: at most 2)"
        )


def box_mesh(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """A closed axis-aligned box from lo to hi [m] as (vertices (8,3), triangles (12,3)), counter-clockwise
    seen from outside (outward normals)."""
    lo, hi = validate.box("box", lo, hi)
    corner = np.array(list(itertools.product((0, 1), repeat=3)))  # index 4x + 2y + z
    vertices = np.where(corner == 1, hi, lo)
    faces = [
        (0, 1, 3, 2),  # x = lo
        (4, 6, 7, 5),  # x = hi
        (0, 4, 5, 1),  # y = lo
        (2, 3, 7, 6),  # y = hi
        (0, 2, 6, 4),  # z = lo
        (1, 5, 7, 3),  # z = hi
    ]
    triangles = [t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))]
    return vertices.astype(np.float64), np.array(triangles, dtype=np.int64)


def merge_meshes(meshes) -> tuple[np.ndarray, np.ndarray]:
    """One (vertices, triangles) from several, each mesh's indices shifted past the ones before."""
    vertices, triangles, start = [], [], 0
    for v, t in meshes:
        vertices.append(np.asarray(v, dtype=np.float64))
        triangles.append(np.asarray(t, dtype=np.int64) + start)
        start += len(v)
    return np.concatenate(vertices), np.concatenate(triangles)


def revolve_mesh(profile, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A closed solid of revolution about the y axis (a lathe; Blender's Screw modifier): `profile` is a
    polyline of (r, y) [m] points, r >= 0, from the axis back to the axis, outlining the solid's half
    section counter-clockwise in the (r, y) plane (e.g. a glass: (0, 0), (R, 0), (R, H), (R - t, H),
    (R - t, b), (0, b)); `segments` around. Points on the axis become single vertices. Returns
    (vertices, triangles) with outward normals."""
    p = np.asarray(profile, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3 or not np.all(np.isfinite(p)):
        raise ParameterError(f"profile must be at least 3 finite (r, y) points, got shape {p.shape}")
    if np.any(p[:, 0] < 0) or p[0, 0] != 0 or p[-1, 0] != 0 or np.any(p[1:-1, 0] == 0):
        raise ParameterError("profile must start and end on the axis (r = 0) and leave it in between (r > 0)")
    segments = validate.count("segments", segments, 3)
    ring = p[1:-1]  # off-axis points, one ring of `segments` vertices each
    a = 2.0 * np.pi * np.arange(segments) / segments
    rings = np.stack(
        [
            np.outer(ring[:, 0], np.cos(a)),
            np.repeat(ring[:, 1:2], segments, 1),
            -np.outer(ring[:, 0], np.sin(a)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    first, last = len(rings), len(rings) + 1  # the two axis points
    vertices = np.concatenate([rings, [[0.0, p[0, 1], 0.0], [0.0, p[-1, 1], 0.0]]])
    k = np.arange(segments)
    nxt = (k + 1) % segments
    tris = [np.stack([np.full(segments, first), nxt, k], 1)]  # the fan from the first axis point
    for i in range(len(ring) - 1):  # a band of quads between rings i and i + 1
        a0, a1, b0, b1 = (
            i * segments + k,
            i * segments + nxt,
            (i + 1) * segments + k,
            (i + 1) * segments + nxt,
        )
        tris += [np.stack([a0, a1, b1], 1), np.stack([a0, b1, b0], 1)]
    base = (len(ring) - 1) * segments
    tris.append(np.stack([np.full(segments, last), base + k, base + nxt], 1))  # the fan to the last one
    return vertices, np.concatenate(tris).astype(np.int64)
