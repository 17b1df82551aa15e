"""Cloth geometry: grid layout and winding, Provot spring families, lumped masses, mesh checks, loading."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from taichi_anim.errors import ParameterError
from taichi_anim.geometry import (
    ClothSprings,
    SpringFamily,
    cloth_grid,
    grid_springs,
    load_mesh,
    lumped_masses,
    mesh_springs,
    validate_mesh,
)

RESOLUTIONS = [(2, 2), (2, 5), (3, 3), (5, 4), (7, 9)]


def _pair_set(pairs: np.ndarray) -> set[tuple[int, int]]:
    return {(int(a), int(b)) for a, b in pairs}


def _check_well_formed(springs: ClothSprings, vertex_count: int) -> None:
    assert springs.pairs.dtype == np.int64 and springs.pairs.shape == (len(springs.family), 2)
    assert springs.family.dtype == np.int8
    assert np.all(springs.pairs[:, 0] < springs.pairs[:, 1])
    assert springs.pairs.min() >= 0 and springs.pairs.max() < vertex_count
    assert len(_pair_set(springs.pairs)) == len(springs.pairs), "duplicate spring pairs"


def _square() -> tuple[np.ndarray, np.ndarray]:
    """Unit square in the xz plane, two triangles."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], dtype=np.float64)
    return vertices, np.array([[0, 2, 1], [0, 3, 2]])


# ------------------------------------------------------------------------------------------- cloth_grid


@pytest.mark.parametrize("plane, along, up", [("xz", 2, 1), ("xy", 1, 2)])
def test_grid_positions_indices_and_winding(plane, along, up):
    nx, ny = 5, 4
    origin, size = np.array([0.5, -1.0, 2.0]), (2.0, 1.5)
    vertices, triangles = cloth_grid(origin=origin, size=size, resolution=(nx, ny), plane=plane)
    assert vertices.shape == (nx * ny, 3) and vertices.dtype == np.float64
    assert triangles.shape == (2 * (nx - 1) * (ny - 1), 3) and triangles.dtype == np.int64
    dx, dy = size[0] / (nx - 1), size[1] / (ny - 1)
    for j, i in itertools.product(range(ny), range(nx)):
        expected = origin.copy()
        expected[0] += i * dx
        expected[along] += j * dy
        np.testing.assert_allclose(vertices[j * nx + i], expected, atol=1e-12)
    # Every triangle's normal (b - a) x (c - a) points to +y ("xz") or +z ("xy") with magnitude 2 * area.
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    np.testing.assert_allclose(normals[:, up], dx * dy, rtol=1e-12)
    np.testing.assert_allclose(np.delete(normals, up, axis=1), 0.0, atol=1e-12)


def test_grid_uses_the_diagonal_i_j_to_i1_j1():
    nx, ny = 4, 3
    _, triangles = cloth_grid(resolution=(nx, ny))
    edges = _pair_set(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1))
    for j, i in itertools.product(range(ny - 1), range(nx - 1)):
        assert (j * nx + i, (j + 1) * nx + i + 1) in edges
        assert (j * nx + i + 1, (j + 1) * nx + i) not in edges


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"resolution": (1, 4)}, "resolution"),
        ({"resolution": (4, 2.5)}, "resolution"),
        ({"resolution": 8}, "resolution"),
        ({"size": (1.0, 0.0)}, "size"),
        ({"size": (1.0, math.nan)}, "size"),
        ({"origin": (0.0, 1.0)}, "origin"),
        ({"plane": "yz"}, "plane"),
    ],
)
def test_grid_rejects_bad_parameters(kwargs, word):
    with pytest.raises(ParameterError, match=word):
        cloth_grid(**kwargs)


# ----------------------------------------------------------------------------------------- grid_springs


@pytest.mark.parametrize("nx, ny", RESOLUTIONS)
def test_grid_spring_counts_match_closed_form(nx, ny):
    springs = grid_springs((nx, ny))
    _check_well_formed(springs, nx * ny)
    assert len(springs.pairs_of(SpringFamily.STRETCH)) == (nx - 1) * ny + nx * (ny - 1)
    assert len(springs.pairs_of(SpringFamily.SHEAR)) == 2 * (nx - 1) * (ny - 1)
    assert len(springs.pairs_of(SpringFamily.BEND)) == (nx - 2) * ny + nx * (ny - 2)
    # Codes follow the enum order, and each family is one contiguous block in that order.
    assert np.all(np.diff(springs.family) >= 0)


@pytest.mark.parametrize("nx, ny", RESOLUTIONS)
def test_grid_spring_rest_lengths(nx, ny):
    dx = 0.7 / (nx - 1)  # square cells, so shear springs are dx * sqrt(2) long
    vertices, _ = cloth_grid(size=(dx * (nx - 1), dx * (ny - 1)), resolution=(nx, ny))
    springs = grid_springs((nx, ny))
    expected = {SpringFamily.STRETCH: dx, SpringFamily.SHEAR: dx * math.sqrt(2.0), SpringFamily.BEND: 2 * dx}
    for family, length in expected.items():
        pairs = springs.pairs_of(family)
        lengths = np.linalg.norm(vertices[pairs[:, 0]] - vertices[pairs[:, 1]], axis=1)
        np.testing.assert_allclose(lengths, length, rtol=1e-12)


# ----------------------------------------------------------------------------------------- mesh_springs


def _expected_mesh_springs(nx: int, ny: int) -> dict[SpringFamily, set[tuple[int, int]]]:
    """Springs of the triangulated grid, written out from the grid's indices (not from the triangles)."""

    def v(i, j):
        return j * nx + i

    def pair(p, q):
        return (min(p, q), max(p, q))

    stretch, shear, bend = set(), set(), set()
    for j, i in itertools.product(range(ny), range(nx)):
        if i + 1 < nx:
            stretch.add(pair(v(i, j), v(i + 1, j)))
        if j + 1 < ny:
            stretch.add(pair(v(i, j), v(i, j + 1)))
        if i + 1 < nx and j + 1 < ny:
            stretch.add(pair(v(i, j), v(i + 1, j + 1)))  # the diagonal each quad is split along
            shear.add(pair(v(i + 1, j), v(i, j + 1)))  # the quad's other diagonal
        # An interior horizontal edge (i,j)-(i+1,j) lies between triangles whose opposite vertices are
        # (i,j-1) below and (i+1,j+1) above; an interior vertical edge (i,j)-(i,j+1) between (i-1,j) and
        # (i+1,j+1).
        if i + 1 < nx and 0 < j < ny - 1:
            bend.add(pair(v(i, j - 1), v(i + 1, j + 1)))
        if j + 1 < ny and 0 < i < nx - 1:
            bend.add(pair(v(i - 1, j), v(i + 1, j + 1)))
    return {SpringFamily.STRETCH: stretch, SpringFamily.SHEAR: shear, SpringFamily.BEND: bend}


@pytest.mark.parametrize("nx, ny", RESOLUTIONS)
@pytest.mark.parametrize("plane", ["xz", "xy"])
def test_mesh_springs_on_the_triangulated_grid(nx, ny, plane):
    vertices, triangles = cloth_grid(size=(1.0, 2.0), resolution=(nx, ny), plane=plane)
    springs = mesh_springs(vertices, triangles)
    _check_well_formed(springs, nx * ny)
    mesh_edges = _pair_set(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1))
    expected = _expected_mesh_springs(nx, ny)
    assert expected[SpringFamily.STRETCH] == mesh_edges
    for family, pairs in expected.items():
        assert _pair_set(springs.pairs_of(family)) == pairs, family
    # Closed-form counts of the same sets.
    assert len(expected[SpringFamily.SHEAR]) == (nx - 1) * (ny - 1)
    assert len(expected[SpringFamily.BEND]) == (nx - 1) * (ny - 2) + (nx - 2) * (ny - 1)


def test_mesh_springs_equilateral_triangles_are_bend_not_shear():
    # Two equilateral triangles sharing an edge: no edge is strictly the longest, so no quad was split.
    h = math.sqrt(3.0) / 2
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0, h], [0.5, 0, -h]])
    springs = mesh_springs(vertices, np.array([[0, 2, 1], [0, 1, 3]]))
    assert _pair_set(springs.pairs_of(SpringFamily.BEND)) == {(2, 3)}
    assert len(springs.pairs_of(SpringFamily.SHEAR)) == 0
    assert len(springs.pairs_of(SpringFamily.STRETCH)) == 5


def test_mesh_springs_edge_longest_in_only_one_triangle_is_bend():
    # The edge (0, 2) is the hypotenuse of triangle (0, 3, 2) but not the longest edge of (0, 2, 1), whose
    # vertex 1 lies far out: the two triangles are no split quad, so (1, 3) bends.
    vertices = np.array([[0, 0, 0], [3, 0, 0], [1, 0, 1], [0, 0, 1]], dtype=np.float64)
    springs = mesh_springs(vertices, np.array([[0, 2, 1], [0, 3, 2]]))
    assert _pair_set(springs.pairs_of(SpringFamily.BEND)) == {(1, 3)}
    assert len(springs.pairs_of(SpringFamily.SHEAR)) == 0
    # Pull vertex 1 back to (1, 0, 0) and (0, 2) is the diagonal of a unit square: (1, 3) shears.
    vertices[1] = [1, 0, 0]
    springs = mesh_springs(vertices, np.array([[0, 2, 1], [0, 3, 2]]))
    assert _pair_set(springs.pairs_of(SpringFamily.SHEAR)) == {(1, 3)}
    assert len(springs.pairs_of(SpringFamily.BEND)) == 0


def test_mesh_springs_drop_an_opposite_pair_that_is_already_an_edge():
    # A tetrahedron's surface: the vertices opposite each edge are joined by the opposite edge, so every
    # bend candidate is already a stretch spring and must not appear twice.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    triangles = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    springs = mesh_springs(vertices, triangles)
    _check_well_formed(springs, 4)
    assert len(springs.pairs) == 6
    assert np.all(springs.family == 0)


# ---------------------------------------------------------------------------------------- lumped_masses


@pytest.mark.parametrize("nx, ny", RESOLUTIONS)
def test_lumped_masses_sum_and_fractions(nx, ny):
    width, depth, density = 1.3, 0.8, 0.25  # [m], [m], [kg/m^2]
    vertices, triangles = cloth_grid(size=(width, depth), resolution=(nx, ny))
    masses = lumped_masses(vertices, triangles, density).reshape(ny, nx)
    assert masses.dtype == np.float64
    assert abs(masses.sum() - density * width * depth) <= 1e-12 * density * width * depth
    # Each triangle gives a third of its area (cell/2) to each vertex, so a vertex gets cell/6 per incident
    # triangle: 6 inside, 3 on an edge, 2 at the corners on the split diagonal, 1 at the other two corners.
    cell = density * width / (nx - 1) * depth / (ny - 1)
    expected = np.full((ny, nx), cell)
    expected[0, :] = expected[-1, :] = expected[:, 0] = expected[:, -1] = cell / 2
    expected[0, 0] = expected[-1, -1] = cell / 3
    expected[0, -1] = expected[-1, 0] = cell / 6
    np.testing.assert_allclose(masses, expected, rtol=1e-12)


def test_lumped_masses_unused_vertex_gets_zero_and_bad_density_raises():
    vertices, triangles = _square()
    vertices = np.vstack([vertices, [[5.0, 5.0, 5.0]]])
    masses = lumped_masses(vertices, triangles, 2.0)
    np.testing.assert_allclose(masses, [2 / 3, 1 / 3, 2 / 3, 1 / 3, 0.0], rtol=1e-12)
    for density in (0.0, -1.0, math.inf):
        with pytest.raises(ParameterError, match="density"):
            lumped_masses(*_square(), density)


# ---------------------------------------------------------------------------------------- validate_mesh


def test_validate_mesh_returns_float64_and_int64_copies():
    vertices, triangles = _square()
    v, t = validate_mesh(vertices.astype(np.float32), triangles.astype(np.int32))
    assert v.dtype == np.float64 and t.dtype == np.int64
    np.testing.assert_array_equal(v, vertices)
    np.testing.assert_array_equal(t, triangles)
    v2, _ = validate_mesh(vertices, triangles)
    v2[0, 0] = 9.0
    assert vertices[0, 0] == 0.0


def _with(array: np.ndarray, index, value) -> np.ndarray:
    array = array.copy()
    array[index] = value
    return array


# Each case edits the 4x4 grid (16 vertices, 18 triangles, bbox diagonal sqrt(2)) into a bad mesh.
BAD_MESHES = [
    ("empty vertices", lambda v, t: (v[:0], t), r"empty mesh \(0 vertices, 18 triangles\)"),
    ("empty triangles", lambda v, t: (v, t[:0]), r"empty mesh \(16 vertices, 0 triangles\)"),
    ("vertex shape", lambda v, t: (v[:, :2], t), r"shape \(V, 3\)"),
    ("float triangles", lambda v, t: (v, t.astype(np.float64)), r"integers"),
    ("nan vertex", lambda v, t: (_with(v, (7, 1), np.nan), t), r"vertex 7 is not finite"),
    ("inf vertex", lambda v, t: (_with(v, (11, 0), np.inf), t), r"vertex 11 is not finite"),
    ("index out of range", lambda v, t: (v, _with(t, (13, 2), 16)), r"triangle 13 .*vertices 8, 12, 16"),
    ("negative index", lambda v, t: (v, _with(t, (4, 0), -1)), r"triangle 4 .*vertices -1, 7, 3"),
    ("repeated index", lambda v, t: (v, _with(t, 5, [6, 9, 6])), r"triangle 5 repeats a vertex"),
    ("duplicate vertex", lambda v, t: (np.vstack([v, v[9]]), t), r"vertices 9 and 16 are duplicates"),
    (
        "near-duplicate vertex",
        lambda v, t: (np.vstack([v, v[5] + [1e-11, 0, 0]]), t),
        r"vertices 5 and 16 are duplicates",
    ),
    (
        "zero-area triangle",  # an extra triangle on three new collinear points
        lambda v, t: (np.vstack([v, [[2, 0, 0], [3, 0, 0], [4, 0, 0]]]), np.vstack([t, [16, 17, 18]])),
        r"triangle 18 has zero area \(vertices 16, 17, 18",
    ),
    ("duplicate triangle", lambda v, t: (v, np.vstack([t, t[3, ::-1]])), r"triangle 18 repeats triangle 3"),
    (
        "non-manifold edge",  # a third triangle, folded up out of the plane, on the interior edge (5, 6)
        lambda v, t: (np.vstack([v, [0.5, 1.0, 0.5]]), np.vstack([t, [5, 6, 16]])),
        r"edge \(5, 6\) is shared by 3 triangles",
    ),
]


@pytest.mark.parametrize("edit, message", [pytest.param(e, m, id=c) for c, e, m in BAD_MESHES])
def test_validate_mesh_rejects(edit, message):
    vertices, triangles = edit(*cloth_grid(resolution=(4, 4)))
    with pytest.raises(ParameterError, match=f"^drape: .*{message}"):
        validate_mesh(vertices, triangles, name="drape")


def test_validate_mesh_tolerates_vertices_just_beyond_the_duplicate_tolerance_and_unused_vertices():
    vertices, triangles = cloth_grid(resolution=(4, 4))  # bbox diagonal sqrt(2)
    extra = vertices[5] + [3e-9, 0.0, 0.0]  # > 1e-9 * sqrt(2): close, but not a duplicate
    validated, _ = validate_mesh(np.vstack([vertices, extra]), triangles)
    assert len(validated) == 17


@pytest.mark.parametrize("seed", range(20))
def test_validate_mesh_finds_a_planted_duplicate_anywhere(seed):
    # The duplicate search bins vertices into shifted grids; a close pair straddling cell boundaries on
    # any combination of axes must still be found (random points are ~0.1 apart, so it is the only one).
    rng = np.random.default_rng(seed)
    vertices = rng.uniform(-1.0, 1.0, (400, 3))
    tolerance = 1e-9 * np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    direction = rng.normal(size=3)
    i = int(rng.integers(3, 400))
    vertices = np.vstack([vertices, vertices[i] + 0.9 * tolerance * direction / np.linalg.norm(direction)])
    triangles = np.array([[0, 1, 2]])
    with pytest.raises(ParameterError, match=f"vertices {i} and 400 are duplicates"):
        validate_mesh(vertices, triangles)


# -------------------------------------------------------------------------------------------- load_mesh


def test_load_mesh_from_arrays_and_open3d_meshes():
    o3d = pytest.importorskip("open3d")
    vertices, triangles = cloth_grid(size=(0.6, 0.9), resolution=(5, 7), origin=(0.1, 1.0, -0.2))
    for source in (
        (vertices, triangles),
        o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
        ),
    ):
        v, t = load_mesh(source)
        np.testing.assert_array_equal(v, vertices)
        np.testing.assert_array_equal(t, triangles)
    tensor_mesh = o3d.t.geometry.TriangleMesh()
    tensor_mesh.vertex.positions = o3d.core.Tensor(vertices)
    tensor_mesh.triangle.indices = o3d.core.Tensor(triangles.astype(np.int32))
    v, t = load_mesh(tensor_mesh)
    np.testing.assert_array_equal(v, vertices)
    np.testing.assert_array_equal(t, triangles)
    with pytest.raises(ParameterError, match="empty"):
        load_mesh(o3d.geometry.TriangleMesh())


def test_load_mesh_ply_round_trip(tmp_path):
    o3d = pytest.importorskip("open3d")
    vertices, triangles = cloth_grid(size=(0.6, 0.9), resolution=(6, 4), plane="xy")
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
    )
    path = tmp_path / "cloth.ply"
    assert o3d.io.write_triangle_mesh(str(path), mesh)
    for source in (path, str(path)):
        v, t = load_mesh(source, name="drape")
        np.testing.assert_allclose(v, vertices, rtol=0, atol=1e-6)  # PLY may store float32
        np.testing.assert_array_equal(t, triangles)


def test_load_mesh_missing_garbage_and_wrong_type(tmp_path):
    missing = tmp_path / "nowhere.ply"
    with pytest.raises(ParameterError, match=f"drape: file not found: .*{missing.name}"):
        load_mesh(missing, name="drape")
    for suffix, content in ((".ply", b"\x00\x01garbage\xff" * 50), (".obj", b"this is not a mesh\n")):
        garbage = tmp_path / f"garbage{suffix}"
        garbage.write_bytes(content)
        with pytest.raises(ParameterError, match=f"drape.*garbage{suffix}"):
            load_mesh(garbage, name="drape")
    with pytest.raises(ParameterError, match="expected an Open3D TriangleMesh"):
        load_mesh(42)
