"""Open3D export: round trips per format, custom attributes, empty files, atomic writes, errors, manifest."""

from __future__ import annotations

import dataclasses
import datetime as dt
import enum
import json
import platform
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from taichi_anim.errors import OutputError, ParameterError
from taichi_anim.io.atomic import atomic_path, incomplete_reason, text_rows_problem
from taichi_anim.io.export import (
    area_weighted_normals,
    frame_numbering,
    frame_path,
    read_line_set,
    read_point_cloud,
    read_triangle_mesh,
    trails_to_line_set,
    write_line_set,
    write_point_cloud,
    write_triangle_mesh,
)
from taichi_anim.io.manifest import (
    environment,
    jsonable,
    prepare_run_folder,
    read_manifest,
    write_manifest,
)

o3d = pytest.importorskip("open3d")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def grid_mesh(n: int = 4):
    """An n x n vertex grid in the XZ plane (Y up), triangles counter-clockwise seen from +Y."""
    x, z = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n))
    v = np.stack([x, 0.1 * x * z, z], axis=-1).reshape(-1, 3)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            f += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return v, np.array(f)


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ---------------------------------------------------------------------------------------------- paths


def test_frame_path_pads_to_four_digits_and_grows(tmp_path):
    assert frame_path(tmp_path, "cloth", 0) == tmp_path / "cloth_0000.ply"
    assert frame_path(tmp_path, "cloth", 42).name == "cloth_0042.ply"
    assert frame_path(tmp_path, "cloth", 9999).name == "cloth_9999.ply"
    assert frame_path(tmp_path, "cloth", 12345).name == "cloth_12345.ply"
    assert frame_path(tmp_path, "p", np.int64(7), ext=".obj").name == "p_0007.obj"
    # Zero padding keeps lexical order equal to frame order below 10000.
    names = [frame_path(tmp_path, "x", i).name for i in (3, 20, 100, 1000)]
    assert names == sorted(names)


def test_frame_path_pads_to_the_run_length(tmp_path):
    # 10000 frames are numbered 0..9999 (4 digits); 10001 need 5 digits for every name to sort right.
    assert frame_path(tmp_path, "c", 7, frames=10000).name == "c_0007.ply"
    names = [frame_path(tmp_path, "c", i, frames=10001).name for i in range(10001)]
    assert names[7] == "c_00007.ply" and names[-1] == "c_10000.ply" and names == sorted(names)
    with frame_numbering(123456) as digits:  # what a run sets around its scene's export
        assert digits == 6 and frame_path(tmp_path, "c", 42).name == "c_000042.ply"
    assert frame_path(tmp_path, "c", 42).name == "c_0042.ply"
    with pytest.raises(ParameterError, match="frame must be < frames"):
        frame_path(tmp_path, "c", 12, frames=12)
    with pytest.raises(ParameterError, match="frames"):
        frame_path(tmp_path, "c", 0, frames=0)


@pytest.mark.parametrize("frame", [-1, 1.5, True])
def test_frame_path_rejects_bad_frames(tmp_path, frame):
    with pytest.raises(ParameterError, match="frame"):
        frame_path(tmp_path, "cloth", frame)


def test_frame_path_rejects_separator_in_name(tmp_path):
    with pytest.raises(ParameterError, match="name"):
        frame_path(tmp_path, "a/b", 1)


# ---------------------------------------------------------------------------------------- point clouds


def test_point_cloud_ply_round_trip_keeps_order_colors_and_attributes(tmp_path, rng):
    n = 50
    pts = rng.normal(size=(n, 3))
    col = rng.random((n, 3))
    radius = rng.uniform(0.01, 0.05, n)
    velocity = rng.normal(size=(n, 3)).astype(np.float32)
    age = np.arange(n, dtype=np.int64)  # int64 is stored as int32: PLY has no 64-bit integers
    path = write_point_cloud(
        tmp_path / "p.ply", pts, col, attributes={"radius": radius, "velocity": velocity, "age": age}
    )
    assert path == tmp_path / "p.ply" and listing(tmp_path) == ["p.ply"]

    back = read_point_cloud(path)
    np.testing.assert_array_equal(back["points"], pts)  # double precision, same order
    np.testing.assert_allclose(back["colors"], col, atol=0.5 / 255 + 1e-12)  # 8-bit colour
    np.testing.assert_array_equal(back["radius"], radius)
    np.testing.assert_array_equal(back["velocity"], velocity)
    assert back["velocity"].shape == (n, 3)
    np.testing.assert_array_equal(back["age"], age)

    # Straight through Open3D: the custom attributes really are PLY properties.
    raw = o3d.t.io.read_point_cloud(str(path))
    assert {"radius", "age", "velocity_0", "velocity_1", "velocity_2"} <= set(raw.point)
    np.testing.assert_array_equal(raw.point["velocity_1"].numpy()[:, 0], velocity[:, 1])


def test_point_cloud_float32_positions_stay_single_precision(tmp_path, rng):
    pts = rng.random((10, 3)).astype(np.float32)
    write_point_cloud(tmp_path / "f.ply", pts)
    header = (tmp_path / "f.ply").read_bytes().split(b"end_header")[0].decode()
    assert "property float x" in header and "double" not in header
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "f.ply")["points"], pts)


def test_point_cloud_pcd_and_xyz_round_trip(tmp_path, rng):
    pts = rng.random((20, 3))
    radius = rng.random(20)
    velocity = rng.random((20, 3))
    write_point_cloud(tmp_path / "p.pcd", pts, rng.random((20, 3)), {"radius": radius, "velocity": velocity})
    back = read_point_cloud(tmp_path / "p.pcd")
    np.testing.assert_array_equal(back["points"], pts)
    np.testing.assert_allclose(back["radius"], radius, rtol=1e-6)
    np.testing.assert_allclose(back["velocity"], velocity)

    write_point_cloud(tmp_path / "p.xyz", pts)
    np.testing.assert_allclose(read_point_cloud(tmp_path / "p.xyz")["points"], pts, atol=1e-7)
    with pytest.raises(ParameterError, match="xyz"):
        write_point_cloud(tmp_path / "c.xyz", pts, colors=rng.random((20, 3)))


@pytest.mark.parametrize("ext", ["ply", "pcd", "xyz"])
def test_empty_point_cloud_writes_a_valid_file(tmp_path, ext):
    # Open3D refuses to write 0 points (returns False); an empty frame must still exist on disk.
    kw = {} if ext == "xyz" else {"colors": np.zeros((0, 3)), "attributes": {"radius": np.zeros(0)}}
    path = write_point_cloud(tmp_path / f"e.{ext}", np.zeros((0, 3)), **kw)
    assert path.is_file() and listing(tmp_path) == [f"e.{ext}"]
    back = read_point_cloud(path)
    assert back["points"].shape == (0, 3)
    if ext == "ply":  # the schema of a non-empty frame is kept
        assert back["colors"].shape == (0, 3) and back["radius"].shape == (0,)
        assert path.read_text().startswith("ply\nformat ascii 1.0\n")


def test_point_cloud_bad_inputs_name_the_parameter(tmp_path, rng):
    pts = rng.random((5, 3))
    cases = [
        ({"points": np.array([[0.0, np.nan, 0.0]])}, "points"),
        ({"points": pts[:, :2]}, "points"),
        ({"points": pts, "colors": rng.random((4, 3))}, "colors"),
        ({"points": pts, "colors": 2 * np.ones((5, 3))}, "colors"),
        ({"points": pts, "attributes": {"radius": np.ones(4)}}, "radius"),
        ({"points": pts, "attributes": {"colors": np.ones(5)}}, "colors"),
        ({"points": pts, "attributes": {"bad name": np.ones(5)}}, "bad name"),
    ]
    for kwargs, word in cases:
        with pytest.raises(ParameterError, match=word):
            write_point_cloud(tmp_path / "x.ply", **kwargs)
    with pytest.raises(ParameterError, match=r"\.stl"):
        write_point_cloud(tmp_path / "x.stl", pts)
    assert listing(tmp_path) == []


# ---------------------------------------------------------------------------------------------- meshes


def test_area_weighted_normals_point_up_for_a_ccw_floor():
    v, f = grid_mesh(3)
    v[:, 1] = 0.0
    n = area_weighted_normals(np.vstack([v, [[5.0, 5.0, 5.0]]]), f)
    np.testing.assert_allclose(n[:-1], np.tile([0.0, 1.0, 0.0], (len(v), 1)), atol=1e-12)
    np.testing.assert_array_equal(n[-1], 0.0)  # an isolated vertex gets no NaN
    degenerate = area_weighted_normals(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    assert np.all(np.isfinite(degenerate))


def test_triangle_mesh_ply_round_trip_is_exact(tmp_path, rng):
    v, f = grid_mesh(5)
    col = rng.random((len(v), 3))
    write_triangle_mesh(tmp_path / "m.ply", v, f, vertex_colors=col)
    back = read_triangle_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(back["vertices"], v)  # PLY keeps vertex order and doubles
    np.testing.assert_array_equal(back["triangles"], f)
    np.testing.assert_allclose(back["vertex_normals"], area_weighted_normals(v, f), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(back["vertex_normals"], axis=1), 1.0)
    assert np.all(back["vertex_normals"][:, 1] > 0.9)  # counter-clockwise from +Y faces up
    np.testing.assert_allclose(back["vertex_colors"], col, atol=0.5 / 255 + 1e-12)

    given = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    write_triangle_mesh(tmp_path / "n.ply", v, f, vertex_normals=given)
    np.testing.assert_array_equal(read_triangle_mesh(tmp_path / "n.ply")["vertex_normals"], given)
    write_triangle_mesh(tmp_path / "none.ply", v, f, compute_normals=False)
    assert "vertex_normals" not in read_triangle_mesh(tmp_path / "none.ply")


def test_triangle_mesh_obj_round_trip_compares_faces_by_coordinates(tmp_path, rng):
    v, f = grid_mesh(4)
    v = np.vstack([v, [[9.0, 9.0, 9.0]]])  # unused vertex: OBJ readers drop it
    col = rng.random((len(v), 3))
    write_triangle_mesh(tmp_path / "m.obj", v, f, vertex_colors=col)
    assert listing(tmp_path) == ["m.obj"]  # no .mtl next to it
    back = read_triangle_mesh(tmp_path / "m.obj")
    assert len(back["triangles"]) == len(f)
    assert len(back["vertices"]) == len(v) - 1
    # OBJ renumbers vertices: compare each face's corner coordinates (OBJ keeps ~6 significant digits).
    got = back["vertices"][back["triangles"]].reshape(len(f), 9)
    want = v[f].reshape(len(f), 9)
    np.testing.assert_allclose(got[np.lexsort(got.T[::-1])], want[np.lexsort(want.T[::-1])], atol=1e-5)
    # Colours travel with their vertices.
    back_col = {
        tuple(np.round(p, 4)): c for p, c in zip(back["vertices"], back["vertex_colors"], strict=True)
    }
    for i in np.unique(f):
        np.testing.assert_allclose(back_col[tuple(np.round(v[i], 4))], col[i], atol=1e-5)


@pytest.mark.parametrize("ext", ["ply", "obj"])
def test_empty_and_faceless_meshes(tmp_path, ext):
    write_triangle_mesh(tmp_path / f"e.{ext}", np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    back = read_triangle_mesh(tmp_path / f"e.{ext}")
    assert back["vertices"].shape == (0, 3) and back["triangles"].shape == (0, 3)
    v = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    write_triangle_mesh(tmp_path / f"v.{ext}", v, np.zeros((0, 3), dtype=int))
    back = read_triangle_mesh(tmp_path / f"v.{ext}")
    np.testing.assert_allclose(back["vertices"], v)
    assert back["triangles"].shape == (0, 3)


def test_triangle_mesh_bad_inputs_name_the_parameter(tmp_path):
    v, f = grid_mesh(3)
    cases = [
        ({"vertices": np.where(np.arange(27).reshape(9, 3) == 4, np.nan, v), "triangles": f}, "vertices"),
        ({"vertices": v[:, :2], "triangles": f}, "vertices"),
        ({"vertices": v, "triangles": f[:, :2]}, "triangles"),
        ({"vertices": v, "triangles": np.vstack([f, [[0, 1, 9]]])}, r"triangles.*outside \[0, 9\)"),
        ({"vertices": v, "triangles": np.vstack([f, [[0, -1, 2]]])}, "triangles"),
        ({"vertices": v, "triangles": f + 0.5}, "triangles"),
        ({"vertices": v, "triangles": f, "vertex_normals": np.ones((3, 3))}, "vertex_normals"),
        ({"vertices": v, "triangles": f, "vertex_colors": -np.ones((9, 3))}, "vertex_colors"),
    ]
    for kwargs, pattern in cases:
        with pytest.raises(ParameterError, match=pattern):
            write_triangle_mesh(tmp_path / "bad.ply", **kwargs)
    assert listing(tmp_path) == []


# ------------------------------------------------------------------------------------------- line sets


def test_line_set_round_trip_and_empty(tmp_path, rng):
    pts = rng.random((6, 3))
    lines = np.array([[0, 1], [1, 2], [4, 5]])
    col = rng.random((3, 3))
    write_line_set(tmp_path / "l.ply", pts, lines, col)
    back = read_line_set(tmp_path / "l.ply")
    np.testing.assert_array_equal(back["points"], pts)
    np.testing.assert_array_equal(back["lines"], lines)
    np.testing.assert_allclose(back["colors"], col, atol=0.5 / 255 + 1e-12)

    write_line_set(tmp_path / "e.ply", pts, np.zeros((0, 2), dtype=int))
    back = read_line_set(tmp_path / "e.ply")
    assert back["points"].shape == (0, 3) and back["lines"].shape == (0, 2)
    with pytest.raises(ParameterError, match="lines"):
        write_line_set(tmp_path / "b.ply", pts, np.array([[0, 6]]))
    with pytest.raises(ParameterError, match="colors"):
        write_line_set(tmp_path / "b.ply", pts, lines, rng.random((2, 3)))


def test_trails_drop_zero_length_segments_and_unused_points():
    trails = np.zeros((3, 4, 3))
    # Particle 0 was just emitted: its first two samples are its birth position.
    trails[0] = [[0, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]]
    trails[1] = 5.0  # at rest the whole time: no segment at all
    trails[2] = [[0, 1, 0], [0, 2, 0], [0, 3, 0], [0, 3, 0]]
    points, lines, particle, sample = trails_to_line_set(trails, return_source=True)
    segments = points[lines]
    np.testing.assert_array_equal(
        segments,
        [[[0, 0, 0], [1, 0, 0]], [[1, 0, 0], [2, 0, 0]], [[0, 1, 0], [0, 2, 0]], [[0, 2, 0], [0, 3, 0]]],
    )
    assert len(points) == 6  # only referenced points are kept
    assert lines.dtype == np.int32 and np.all(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1) > 0)
    np.testing.assert_array_equal(particle, [0, 0, 2, 2])
    np.testing.assert_array_equal(sample, [1, 2, 0, 1])
    # A threshold drops short segments too, and the result writes as a line set.
    p2, l2 = trails_to_line_set(trails, min_length=1.5)
    assert len(l2) == 0 and len(p2) == 0
    with pytest.raises(ParameterError, match="trails"):
        trails_to_line_set(np.zeros((3, 3)))


def test_trails_write_and_read_back(tmp_path, rng):
    trails = np.cumsum(rng.normal(size=(5, 8, 3)), axis=1)
    points, lines = trails_to_line_set(trails)
    assert len(lines) == 5 * 7 and len(points) == 5 * 8
    write_line_set(tmp_path / "t.ply", points, lines)
    back = read_line_set(tmp_path / "t.ply")
    expected = np.stack([trails[:, :-1], trails[:, 1:]], axis=2).reshape(-1, 2, 3)
    np.testing.assert_array_equal(back["points"][back["lines"]], expected)


# -------------------------------------------------------------------------------------- reading errors


def test_readers_raise_instead_of_returning_empty(tmp_path):
    for reader in (read_point_cloud, read_triangle_mesh, read_line_set):
        with pytest.raises(FileNotFoundError):
            reader(tmp_path / "missing.ply")
    (tmp_path / "g.ply").write_text("this is not a ply file")
    (tmp_path / "g.obj").write_text("garbage line\n")
    (tmp_path / "g.pcd").write_text("garbage\n")
    for reader, name in [
        (read_point_cloud, "g.ply"),
        (read_point_cloud, "g.pcd"),
        (read_triangle_mesh, "g.ply"),
        (read_triangle_mesh, "g.obj"),
        (read_line_set, "g.ply"),
    ]:
        with pytest.raises(ParameterError):
            reader(tmp_path / name)
    # A valid header announcing 10 points with the data missing (a truncated write).
    (tmp_path / "t.ply").write_text(
        "ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n"
    )
    with pytest.raises(ParameterError, match="truncated"):
        read_point_cloud(tmp_path / "t.ply")


def test_truncated_files_raise_instead_of_returning_partial_data(tmp_path, rng):
    # Open3D reads a cut PLY with only a printed warning: the legacy readers return the rows they got,
    # the tensor reader uninitialised memory.
    v, f = grid_mesh(6)
    pts = rng.random((40, 3))
    files = [
        (write_point_cloud(tmp_path / "p.ply", pts, rng.random((40, 3)), {"v": pts}), read_point_cloud),
        (write_triangle_mesh(tmp_path / "m.ply", v, f), read_triangle_mesh),
        (write_line_set(tmp_path / "l.ply", pts, np.array([[0, 1], [2, 3]])), read_line_set),
        (write_point_cloud(tmp_path / "p.pcd", pts, attributes={"r": pts[:, 0]}), read_point_cloud),
    ]
    for path, reader in files:
        data = path.read_bytes()
        reader(path)  # complete: fine
        for cut in (len(data) - 1, len(data) // 2):
            bad = path.with_name("cut" + path.suffix)
            bad.write_bytes(data[:cut])
            with pytest.raises(ParameterError):
                reader(bad)


# ------------------------------------------------------------------------------------------- atomicity


def test_crash_mid_write_leaves_no_file_and_no_temp(tmp_path, monkeypatch, rng):
    pts = rng.random((10, 3))
    seen = []

    def crash(path, *args, **kwargs):
        seen.append(Path(path))
        Path(path).write_bytes(b"ply\nhalf a file")  # some bytes are out when the crash comes
        raise RuntimeError("simulated crash inside Open3D")

    monkeypatch.setattr(o3d.t.io, "write_point_cloud", crash)
    with pytest.raises(RuntimeError, match="simulated"):
        write_point_cloud(tmp_path / "p.ply", pts, attributes={"radius": np.ones(10)})
    assert listing(tmp_path) == []
    # The temporary file sat beside the target, hidden, with the target's extension.
    assert seen[0].parent == tmp_path and seen[0].name.startswith(".p.tmp-") and seen[0].suffix == ".ply"

    monkeypatch.setattr(o3d.io, "write_triangle_mesh", crash)
    v, f = grid_mesh(3)
    with pytest.raises(RuntimeError, match="simulated"):
        write_triangle_mesh(tmp_path / "m.obj", v, f)
    monkeypatch.setattr(o3d.io, "write_line_set", crash)
    with pytest.raises(RuntimeError, match="simulated"):
        write_line_set(tmp_path / "l.ply", pts, np.array([[0, 1]]))
    assert listing(tmp_path) == []


def test_failed_write_keeps_the_previous_version(tmp_path, monkeypatch, rng):
    old = rng.random((4, 3))
    write_point_cloud(tmp_path / "p.ply", old)
    before = (tmp_path / "p.ply").read_bytes()
    monkeypatch.setattr(o3d.t.io, "write_point_cloud", lambda *a, **k: False)  # Open3D's way to fail
    with pytest.raises(OutputError, match="could not write"):
        write_point_cloud(tmp_path / "p.ply", rng.random((4, 3)))
    assert (tmp_path / "p.ply").read_bytes() == before and listing(tmp_path) == ["p.ply"]
    # "Success" with nothing written is a failure too.
    monkeypatch.setattr(o3d.t.io, "write_point_cloud", lambda path, *a, **k: Path(path).touch() or True)
    with pytest.raises(OutputError, match="no data"):
        write_point_cloud(tmp_path / "p.ply", rng.random((4, 3)))
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "p.ply")["points"], old)
    assert listing(tmp_path) == ["p.ply"]


def test_publishing_flushes_the_file_renames_it_then_flushes_the_folder(tmp_path, monkeypatch, rng):
    import os

    events = []
    fsync, replace = os.fsync, os.replace

    def record_fsync(fd):
        events.append(("fsync", os.path.realpath(f"/proc/self/fd/{fd}")))
        return fsync(fd)

    def record_replace(a, b):
        events.append(("replace", str(a), str(b)))
        return replace(a, b)

    monkeypatch.setattr(os, "fsync", record_fsync)
    monkeypatch.setattr(os, "replace", record_replace)
    path = write_point_cloud(tmp_path / "p.ply", rng.random((5, 3)))
    kinds = [e[0] for e in events]
    assert kinds == ["fsync", "replace", "fsync"]
    tmp = events[1][1]
    assert events[0][1] == tmp and events[1][2] == str(path) and events[2][1] == str(tmp_path)


def test_a_file_in_the_way_is_an_output_error(tmp_path, rng):
    (tmp_path / "seq").write_text("a file, not a folder")
    with pytest.raises(OutputError, match="is not a folder"):
        write_point_cloud(tmp_path / "seq" / "p_0000.ply", rng.random((3, 3)))
    (tmp_path / "d.ply").mkdir()  # a folder where the file should go
    with pytest.raises(OutputError, match="folder"):
        write_point_cloud(tmp_path / "d.ply", rng.random((3, 3)))
    assert listing(tmp_path) == ["d.ply", "seq"]


def test_incomplete_files_are_recognised_in_every_format_we_write(tmp_path, rng):
    # Each format is cut at half its length: the check must notice, and pass the complete file.
    v, f = grid_mesh(5)
    pts = rng.random((50, 3))
    files = [
        write_point_cloud(tmp_path / "p.ply", pts, attributes={"v": pts}),
        write_point_cloud(tmp_path / "p.pcd", pts, attributes={"a": pts[:, 0]}),
        write_triangle_mesh(tmp_path / "m.ply", v, f),
        write_line_set(tmp_path / "l.ply", pts, np.array([[0, 1], [2, 3]])),
        write_manifest(tmp_path, {"x": pts}, {}),
    ]
    png = tmp_path / "i.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100) + b"\0\0\0\0IEND\xaeB`\x82")
    for path in [*files, png]:
        assert incomplete_reason(path) is None, path
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        assert incomplete_reason(path) is not None, path
    # Header-less text (OBJ, XYZ): counted lines, and a cut last line.
    obj = write_triangle_mesh(tmp_path / "m.obj", v, f)
    assert text_rows_problem(obj, {b"v": len(v), b"f": len(f)}) is None
    assert "expected" in text_rows_problem(obj, {b"v": len(v), b"f": len(f) + 1})
    obj.write_bytes(obj.read_bytes()[:-3])
    assert text_rows_problem(obj, {b"v": len(v)}) == "the last line is cut off"


def test_publishing_a_truncated_file_raises_and_publishes_nothing(tmp_path):
    with pytest.raises(OutputError, match="incomplete"):
        with atomic_path(tmp_path / "x.ply") as tmp:
            header = "ply\nformat binary_little_endian 1.0\nelement vertex 9\nproperty float x\nend_header\n"
            tmp.write_text(header)
    assert listing(tmp_path) == []


def test_run_folder_removes_only_the_previous_runs_files(tmp_path):
    outside = tmp_path / "outside.ply"
    outside.write_text("not in the run folder")
    out = tmp_path / "run"
    out.mkdir()
    for n in ("a_0000.ply", "listed.obj", "user.txt", "b_0000.ply", "b_last.png", "b_extra_0001.ply"):
        (out / n).write_text("x")
    (out / "sub").mkdir()
    files = ["listed.obj", "../outside.ply", str(outside), "sub", {"bogus": 1}]
    (out / "run.json").write_text(
        json.dumps(
            {"settings": {"scene": "a"}, "files": [{"path": p} if isinstance(p, str) else p for p in files]}
        )
    )
    removed = prepare_run_folder(out, names=["b"])
    # Listed plain names, the old scene's frames and the new scene's frames; never outside the folder.
    expected = ["a_0000.ply", "b_0000.ply", "b_extra_0001.ply", "b_last.png", "listed.obj"]
    assert sorted(p.name for p in removed) == expected
    assert listing(out) == ["run.json", "sub", "user.txt"] and outside.exists()
    with pytest.raises(OutputError, match="is a file"):
        prepare_run_folder(out / "user.txt")


def test_write_creates_missing_folders(tmp_path, rng):
    path = frame_path(tmp_path / "out" / "seq", "p", 3)
    write_point_cloud(path, rng.random((3, 3)))
    assert path.is_file() and listing(path.parent) == ["p_0003.ply"]


# --------------------------------------------------------------------------------------------- manifest


class Method(enum.Enum):
    IMPLICIT = 1


@dataclasses.dataclass(frozen=True)
class Options:
    method: Method
    dt: float
    out: Path
    gravity: tuple


def test_manifest_round_trips_numpy_enums_dataclasses_and_paths(tmp_path):
    from taichi_anim import runtime

    runtime.ensure_initialized()
    settings = {
        "resolution": (np.int64(64), np.int32(64)),
        "dt": np.float32(0.25),
        "pinned": np.array([0, 63]),
        "options": Options(Method.IMPLICIT, 1 / 60, tmp_path / "x", (0.0, -9.81, 0.0)),
        "method": Method.IMPLICIT,
        Method.IMPLICIT: "enum key",
        "out": tmp_path,
        "flags": {"b": np.bool_(True)},
        "residual": float("nan"),
    }
    timings = {"step_s": np.float64(0.0125), "compile_s": 1.5, "steps_per_s": np.array([79.9, 80.1])}
    path = write_manifest(tmp_path, settings, timings)
    assert path == tmp_path / "run.json" and listing(tmp_path) == ["run.json"]
    with pytest.raises(ValueError, match="status"):
        write_manifest(tmp_path, settings, timings, status="done")
    doc = json.loads(path.read_text())  # strict JSON parse of the text on disk
    assert doc == read_manifest(tmp_path)
    s = doc["settings"]
    assert s["resolution"] == [64, 64] and s["dt"] == 0.25 and s["pinned"] == [0, 63]
    assert s["options"] == {
        "method": "IMPLICIT",
        "dt": 1 / 60,
        "out": str(tmp_path / "x"),
        "gravity": [0.0, -9.81, 0.0],
    }
    assert s["method"] == "IMPLICIT" and s["IMPLICIT"] == "enum key" and s["out"] == str(tmp_path)
    assert s["flags"] == {"b": True} and s["residual"] == "NaN"
    assert doc["timings"] == {"step_s": 0.0125, "compile_s": 1.5, "steps_per_s": [79.9, 80.1]}
    assert doc["schema"] == 2 and doc["status"] == "complete" and doc["files"] == [] and doc["error"] is None

    env = doc["environment"]
    assert env["python"] == platform.python_version() and env["machine"] == platform.machine()
    assert env["cpu_count"] >= 1
    assert env["packages"]["numpy"] == np.__version__
    assert env["packages"]["taichi"] == metadata.version("taichi")
    assert env["packages"]["open3d"] == o3d.__version__
    assert "taichi_anim" in env["packages"]  # None when not pip-installed
    assert env["taichi"]["initialized"] is True and env["taichi"]["arch"] == runtime.backend_name()
    assert dt.datetime.fromisoformat(env["date"]).tzinfo is not None


def test_jsonable_and_environment_without_taichi_state():
    assert jsonable({"a": (1, np.float32(2.5)), "b": {3, 1}, "c": float("-inf")}) == {
        "a": [1, 2.5],
        "b": [1, 3],
        "c": "-Infinity",
    }
    env = environment()
    assert set(env) >= {"date", "python", "platform", "machine", "cpu_count", "packages", "taichi"}
