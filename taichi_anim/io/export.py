"""Open3D export of point clouds, triangle meshes and line sets, each published atomically and verified
complete (atomic.py), and reading back; frame file names for sequences."""

from __future__ import annotations

import contextlib
import contextvars
import os
import re
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .. import validate
from ..errors import OutputError, ParameterError
from . import read_guard
from .atomic import atomic_path, ply_layout, text_rows_problem
from .obj_scan import scan_obj

__all__ = ["atomic_path"]  # re-exported: renderers and viewers publish through it too

POINT_CLOUD_FORMATS = ("ply", "pcd", "xyz")
TRIANGLE_MESH_FORMATS = ("ply", "obj")
LINE_SET_FORMATS = ("ply",)

# Open3D's tensor PLY writer accepts only these; other dtypes are converted (see _attribute_array).
_PLY_TYPES = {
    np.dtype(np.uint8): "uchar",
    np.dtype(np.uint16): "ushort",
    np.dtype(np.int32): "int",
    np.dtype(np.float32): "float",
    np.dtype(np.float64): "double",
}
# Names Open3D maps to its own PLY properties, which have their own parameters here.
_RESERVED_ATTRIBUTES = ("positions", "colors", "x", "y", "z", "red", "green", "blue")
_ATTRIBUTE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


# ----------------------------------------------------------------------------------------------- paths


MIN_FRAME_DIGITS = 4
# Digits of frame numbers while a run with a known frame count exports (see frame_numbering).
_FRAME_DIGITS: contextvars.ContextVar[int] = contextvars.ContextVar("frame_digits", default=MIN_FRAME_DIGITS)


def frame_digits(frames: int) -> int:
    """Digits for the frame numbers 0 .. frames-1: at least 4, enough for the last one (10001 frames: 5)."""
    frames = validate.count("frames", frames, 1)
    return max(MIN_FRAME_DIGITS, len(str(frames - 1)))


@contextlib.contextmanager
def frame_numbering(frames: int) -> Iterator[int]:
    """Within the block, frame_path pads frame numbers to frame_digits(frames), so every name of a run
    of `frames` frames has the same width and names sort in frame order; yields the width."""
    token = _FRAME_DIGITS.set(frame_digits(frames))
    try:
        yield _FRAME_DIGITS.get()
    finally:
        _FRAME_DIGITS.reset(token)


def frame_path(
    out_dir: str | os.PathLike, name: str, frame: int, ext: str = "ply", *, frames: int | None = None
) -> Path:
    """Path of frame `frame` of sequence `name`: `<out_dir>/<name>_0042.<ext>`.

    The frame number is zero-padded to frame_digits(frames) digits when `frames` (the run's frame count)
    is given, else to the width set by an enclosing frame_numbering (4 outside one), so the names of a
    run sort in frame order. A number wider than the padding is written in full.
    """
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or frame < 0:
        raise ParameterError(f"frame must be an integer >= 0, got {frame!r}")
    if not name or "/" in name or "\\" in name:
        raise ParameterError(f"name must be a non-empty file name without separators, got {name!r}")
    ext = ext.lstrip(".")
    if not ext:
        raise ParameterError("ext must be a non-empty extension such as 'ply'")
    if frames is None:
        digits = _FRAME_DIGITS.get()
    else:
        digits = frame_digits(frames)
        if frame >= frames:
            raise ParameterError(f"frame must be < frames ({frames}), got {frame}")
    return Path(out_dir) / f"{name}_{int(frame):0{digits}d}.{ext}"


@contextlib.contextmanager
def _c_stderr_to_null() -> Iterator[None]:
    """Silence C-level writes to stderr (RPly prints one line per failed value on a full disk); our own
    completeness check reports the failure in one message instead."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no real stderr (embedded interpreters)
        yield
        return
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, 2)
        finally:
            os.close(null)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _check_written(ok: bool, tmp: Path, path: Path, what: str, rows: dict[bytes, int] | None = None) -> None:
    """Open3D reports failure by returning False and printing a warning, never by raising, and its PLY and
    OBJ writers report success for a file cut short by a full disk. Headers are checked by atomic_path;
    header-less text formats against the `rows` they must hold (first word -> line count)."""
    if not ok:
        raise OutputError(f"cannot write {path}: Open3D could not write the {what} (disk full? read-only?)")
    if not tmp.exists() or tmp.stat().st_size == 0:
        raise OutputError(f"cannot write {path}: Open3D reported success but wrote no data for the {what}")
    reason = None if rows is None else text_rows_problem(tmp, rows)
    if reason is not None:
        raise OutputError(
            f"cannot write {path}: the written {what} is incomplete ({reason}); the disk may be full or a "
            "file size limit reached"
        )


def _format(path: Path, formats: tuple[str, ...], what: str) -> str:
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in formats:
        raise ParameterError(
            f"cannot write a {what} as {path.suffix or 'a file without extension'!r} ({path.name}); "
            f"use one of: {', '.join('.' + f for f in formats)}"
        )
    return fmt


# ------------------------------------------------------------------------------------------ validation


def _points(name: str, value) -> np.ndarray:
    return validate.finite_array(name, value, (3,))


def _attribute_array(name: str, value, n: int) -> np.ndarray:
    """A per-point attribute as (n,) or (n,k), converted to a dtype the PLY writer accepts."""
    if not isinstance(name, str) or not _ATTRIBUTE_NAME.match(name) or name in _RESERVED_ATTRIBUTES:
        raise ParameterError(
            f"attribute name {name!r} must be an identifier and not one of {', '.join(_RESERVED_ATTRIBUTES)} "
            "(pass positions and colours as points= and colors=)"
        )
    a = np.asarray(value)
    if a.ndim not in (1, 2) or a.shape[0] != n:
        raise ParameterError(f"attributes[{name!r}] must have shape ({n},) or ({n}, k), got {a.shape}")
    if a.dtype == np.bool_:
        a = a.astype(np.uint8)
    elif a.dtype.kind == "f":
        if not np.all(np.isfinite(a)):
            raise ParameterError(f"attributes[{name!r}] contains non-finite values")
        if a.dtype != np.float64:
            a = a.astype(np.float32)
    elif a.dtype.kind in "iu" and a.dtype not in _PLY_TYPES:
        # PLY (through Open3D) has no 64-bit or 16-bit signed integers; int32 holds ids and counts.
        info = np.iinfo(np.int32)
        if a.size and (a.min() < info.min or a.max() > info.max):
            raise ParameterError(f"attributes[{name!r}] does not fit in int32, which PLY needs")
        a = a.astype(np.int32)
    elif a.dtype not in _PLY_TYPES:
        raise ParameterError(f"attributes[{name!r}] has unsupported dtype {a.dtype}")
    return a


def _position_dtype(points) -> np.dtype:
    # Keep single precision when the simulation is single precision: half the file size, no false digits.
    return np.dtype(np.float32) if np.asarray(points).dtype == np.float32 else np.dtype(np.float64)


# ------------------------------------------------------------------------------------- hand-written PLY


def _write_empty_ply(path: Path, elements: list[tuple[str, list[str]]]) -> None:
    """Write a header-only ASCII PLY whose elements all have count 0.

    Open3D refuses to write empty geometry ("point cloud has 0 points"), yet an empty frame (all particles
    dead, nothing emitted yet) is a valid frame of a sequence and must exist on disk.
    """
    lines = ["ply", "format ascii 1.0", "comment Created by taichi_anim (empty)"]
    for element, properties in elements:
        lines.append(f"element {element} 0")
        lines.extend(f"property {p}" for p in properties)
    lines.append("end_header")
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def _ply_header(path: Path) -> dict[str, list] | None:
    """{element: [count, [property names]]} from a PLY header, or None if the file is not PLY."""
    layout = ply_layout(path)
    if layout is None:
        return None
    return {name: [count, [p for p, _ in props]] for name, count, props in layout[2]}


def _pcd_point_count(path: Path) -> int | None:
    with open(path, "rb") as f:
        head = f.read(1 << 14).decode("ascii", "replace")
    for line in head.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] == "POINTS" and parts[1].isdigit():
            return int(parts[1])
    return None


def _is_blank_text(path: Path) -> bool:
    with open(path, "rb") as f:
        return not f.read(1 << 16).strip()


# ---------------------------------------------------------------------------------------- point clouds


def write_point_cloud(
    path: str | os.PathLike,
    points,
    colors=None,
    attributes: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write a point cloud atomically; the format follows the extension (.ply, .pcd, .xyz).

    points: (N,3) positions [m]; float32 input is written as float, anything else as double.
    colors: (N,3) RGB in [0,1] (or uint8 0..255), stored as 8-bit per channel.
    attributes: per-point arrays, (N,) or (N,k), e.g. {"radius": (N,) [m], "velocity": (N,3) [m/s],
    "age": (N,) [s]}. PLY stores a (N,k) attribute as properties `name_0 .. name_{k-1}`; PCD the same way
    (Open3D's PCD keeps only one column per field); .xyz holds positions only and rejects colours and
    attributes. Bool becomes uint8 and int64 int32 (PLY has no 64-bit integers).
    N == 0 writes a valid empty file. Returns the path written.
    """
    path = Path(path)
    fmt = _format(path, POINT_CLOUD_FORMATS, "point cloud")
    pos = _points("points", points).astype(_position_dtype(points))
    n = pos.shape[0]
    rgb = None if colors is None else validate.colors("colors", colors, n)
    attrs = {k: _attribute_array(k, v, n) for k, v in (attributes or {}).items()}
    if fmt == "xyz" and (rgb is not None or attrs):
        raise ParameterError(".xyz stores positions only; write .ply to keep colors and attributes")

    import open3d as o3d

    columns: dict[str, np.ndarray] = {}
    for name, a in attrs.items():
        if a.ndim == 1 or a.shape[1] == 1:
            columns[name] = a.reshape(n, 1)
        elif fmt == "pcd":
            for j in range(a.shape[1]):
                columns[f"{name}_{j}"] = np.ascontiguousarray(a[:, j : j + 1])
        else:
            columns[name] = np.ascontiguousarray(a)  # Open3D splits it into name_0.. itself
    with atomic_path(path) as tmp:
        if n == 0:
            _write_empty_point_cloud(tmp, fmt, pos.dtype, rgb is not None, columns)
            return path
        if fmt == "xyz":
            # The tensor XYZ writer fails on float64 positions (Open3D 0.20): use the legacy one.
            legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pos.astype(np.float64)))
            with _c_stderr_to_null():
                ok = o3d.io.write_point_cloud(str(tmp), legacy, print_progress=False)
        else:
            cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(pos))
            if rgb is not None:
                cloud.point.colors = o3d.core.Tensor(np.round(rgb * 255.0).astype(np.uint8))
            for name, a in columns.items():
                cloud.point[name] = o3d.core.Tensor(a)
            with _c_stderr_to_null():
                ok = o3d.t.io.write_point_cloud(str(tmp), cloud, print_progress=False)
        _check_written(ok, tmp, path, "point cloud", {b"": n} if fmt == "xyz" else None)
    return path


def _write_empty_point_cloud(tmp: Path, fmt: str, pos_dtype: np.dtype, has_colors: bool, columns) -> None:
    if fmt == "xyz":
        tmp.write_bytes(b"")  # an empty .xyz is simply an empty text file
    elif fmt == "pcd":
        tmp.write_text(
            "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
            "TYPE F F F\nCOUNT 1 1 1\nWIDTH 0\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA ascii\n",
            encoding="ascii",
        )
    else:
        # Keep the property list of a non-empty frame so every file of a sequence has the same schema.
        t = _PLY_TYPES[pos_dtype]
        props = [f"{t} x", f"{t} y", f"{t} z"]
        if has_colors:
            props += ["uchar red", "uchar green", "uchar blue"]
        for name, a in columns.items():
            t = _PLY_TYPES[a.dtype]
            props += [f"{t} {name}"] if a.shape[1] == 1 else [f"{t} {name}_{j}" for j in range(a.shape[1])]
        _write_empty_ply(tmp, [("vertex", props)])


def _existing(path, what: str) -> Path:
    # Regular files only, headers against sizes, bounded lines (read_guard): Open3D would block on a
    # FIFO, read /dev/zero until memory runs out, and return partial data from a truncated file.
    return read_guard.check_input(path, what)


def _quiet():
    import open3d as o3d

    # We raise our own errors, so Open3D's printed warnings would only be noise.
    return o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error)


def _merge_columns(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Join `v_0, v_1, v_2` back into one (N,3) `v` and flatten (N,1) columns to (N,)."""
    out: dict[str, np.ndarray] = {}
    done: set[str] = set()
    for name in sorted(columns):
        if name in done:
            continue
        m = re.fullmatch(r"(.+)_0", name)
        if m:
            base = m.group(1)
            parts = []
            while f"{base}_{len(parts)}" in columns:
                parts.append(f"{base}_{len(parts)}")
            if len(parts) > 1 and base not in columns:
                out[base] = np.concatenate([columns[p].reshape(-1, 1) for p in parts], axis=1)
                done.update(parts)
                continue
        a = columns[name]
        out[name] = a.reshape(-1) if a.ndim == 2 and a.shape[1] == 1 else a
    return out


def read_point_cloud(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a point cloud into NumPy arrays.

    Returns {"points": (N,3) float64 [m], "colors": (N,3) float64 in [0,1] if stored, "normals": (N,3) if
    stored, <attribute>: (N,) or (N,k) for each custom attribute (`velocity_0..2` are joined back into
    "velocity")}. Raises FileNotFoundError for a missing file and ParameterError for a file Open3D cannot
    parse (Open3D itself would return an empty cloud with only a printed warning).
    """
    path = _existing(path, "point cloud")
    fmt = path.suffix.lower().lstrip(".")
    import open3d as o3d

    with _quiet():
        cloud = o3d.t.io.read_point_cloud(str(path))
    if "positions" in cloud.point and cloud.point.positions.shape[0] > 0:
        columns = {k: cloud.point[k].numpy() for k in cloud.point}
        out = {"points": columns.pop("positions").astype(np.float64)}
        if "colors" in columns:
            c = columns.pop("colors")
            out["colors"] = c / 255.0 if c.dtype == np.uint8 else c.astype(np.float64)
        if "normals" in columns:
            out["normals"] = columns.pop("normals").astype(np.float64)
        out.update(_merge_columns(columns))
        return out
    if fmt == "ply":
        header = _ply_header(path)
        if header is not None and header.get("vertex", [None])[0] == 0:
            return _empty_cloud_from_properties(header["vertex"][1])
    elif fmt == "pcd" and _pcd_point_count(path) == 0:
        return {"points": np.zeros((0, 3))}
    elif fmt == "xyz" and _is_blank_text(path):
        return {"points": np.zeros((0, 3))}
    raise ParameterError(f"{path} is not a readable point cloud (unknown format, corrupt or truncated)")


def _empty_cloud_from_properties(props: list[str]) -> dict[str, np.ndarray]:
    out = {"points": np.zeros((0, 3))}
    if "red" in props:
        out["colors"] = np.zeros((0, 3))
    if "nx" in props:
        out["normals"] = np.zeros((0, 3))
    known = {"x", "y", "z", "red", "green", "blue", "alpha", "nx", "ny", "nz"}
    out.update(_merge_columns({p: np.zeros((0, 1)) for p in props if p not in known}))
    return out


# -------------------------------------------------------------------------------------- triangle meshes


def area_weighted_normals(vertices, triangles) -> np.ndarray:
    """Area-weighted unit vertex normals, (V,3); vertices in no (non-degenerate) triangle get (0,0,0).

    vertices: (V,3) [m]; triangles: (F,3) int, counter-clockwise seen from the front.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    # The cross product's length is twice the area, so summing it weights faces by area.
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    acc = np.zeros_like(v)
    for c in range(3):
        for k in range(3):
            acc[:, c] += np.bincount(f[:, k], weights=fn[:, c], minlength=len(v))
    length = np.linalg.norm(acc, axis=1, keepdims=True)
    # Divide only where the length is meaningful: 0/0 would give NaN normals for isolated vertices.
    return np.divide(acc, length, out=np.zeros_like(acc), where=length > 1e-30)


def write_triangle_mesh(
    path: str | os.PathLike,
    vertices,
    triangles,
    vertex_normals=None,
    vertex_colors=None,
    compute_normals: bool = True,
) -> Path:
    """Write a triangle mesh atomically as .ply (canonical: keeps vertex order and double precision) or .obj.

    vertices: (V,3) [m]; triangles: (F,3) int vertex indices, counter-clockwise from the front;
    vertex_normals: (V,3) unit normals, or None to compute area-weighted normals when compute_normals;
    vertex_colors: (V,3) RGB in [0,1] (PLY stores 8 bits per channel, OBJ text).
    OBJ keeps about 6 significant digits and readers renumber its vertices: use PLY for pinning by index.
    Returns the path written.
    """
    path = Path(path)
    fmt = _format(path, TRIANGLE_MESH_FORMATS, "triangle mesh")
    v = _points("vertices", vertices)
    nv = v.shape[0]
    f = validate.indices("triangles", triangles, 3, nv, "vertices")
    normals = None
    if vertex_normals is not None:
        normals = validate.finite_array("vertex_normals", vertex_normals, (3,))
        if normals.shape[0] != nv:
            raise ParameterError(
                f"vertex_normals must have one row per vertex ({nv}), got {normals.shape[0]}"
            )
    elif compute_normals and len(f):
        normals = area_weighted_normals(v, f)
    rgb = None if vertex_colors is None else validate.colors("vertex_colors", vertex_colors, nv)

    import open3d as o3d

    with atomic_path(path) as tmp:
        if nv == 0 and fmt == "ply":
            _write_empty_ply(
                tmp,
                [
                    ("vertex", ["double x", "double y", "double z"]),
                    ("face", ["list uchar int vertex_indices"]),
                ],
            )
            return path
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
        if normals is not None:
            mesh.vertex_normals = o3d.utility.Vector3dVector(normals)
        if rgb is not None:
            mesh.vertex_colors = o3d.utility.Vector3dVector(rgb)
        with _c_stderr_to_null():
            ok = o3d.io.write_triangle_mesh(
                str(tmp),
                mesh,
                write_vertex_normals=normals is not None,
                write_vertex_colors=rgb is not None,
                write_triangle_uvs=False,  # no UVs, so Open3D writes no .mtl named after the temporary file
                print_progress=False,
            )
        _check_written(ok, tmp, path, "triangle mesh", {b"v": nv, b"f": len(f)} if fmt == "obj" else None)
    return path


def read_triangle_mesh(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a triangle mesh into NumPy arrays.

    Returns {"vertices": (V,3) float64 [m], "triangles": (F,3) int64, "vertex_normals": (V,3) if stored,
    "vertex_colors": (V,3) in [0,1] if stored}. PLY keeps the file's vertex order; OBJ vertices come back
    renumbered in face order, quads triangulated. Raises FileNotFoundError / ParameterError as
    read_point_cloud does.
    """
    path = _existing(path, "triangle mesh")
    fmt = path.suffix.lower().lstrip(".")
    if fmt == "obj":
        return _read_obj(path)
    import open3d as o3d

    # The legacy reader keeps PLY doubles; the tensor reader would round them to float32.
    with _quiet():
        mesh = o3d.io.read_triangle_mesh(str(path), print_progress=False)
    if len(mesh.vertices):
        out = {
            "vertices": np.asarray(mesh.vertices, dtype=np.float64),
            "triangles": np.asarray(mesh.triangles, dtype=np.int64).reshape(-1, 3),
        }
        # Layouts read_guard cannot walk (polygons of mixed sizes) reach here unchecked.
        read_guard.check_indices(path, "face", out["triangles"], len(out["vertices"]))
        if mesh.has_vertex_normals():
            out["vertex_normals"] = np.asarray(mesh.vertex_normals, dtype=np.float64)
        if mesh.has_vertex_colors():
            out["vertex_colors"] = np.asarray(mesh.vertex_colors, dtype=np.float64)
        return out
    if fmt == "ply":
        header = _ply_header(path)
        if header is not None and header.get("vertex", [None])[0] == 0:
            return {"vertices": np.zeros((0, 3)), "triangles": np.zeros((0, 3), dtype=np.int64)}
    raise ParameterError(f"{path} is not a readable triangle mesh (unknown format, corrupt or truncated)")


def _read_obj(path: Path) -> dict[str, np.ndarray]:
    # Open3D 0.20's OBJ readers are fragile: the tensor one segfaults on an OBJ without vertices, raises
    # IndexError on one without faces or with an index out of range; the legacy one drops quads. Scan
    # first (bounded lines, every index checked) and call Open3D only for files with vertices and faces.
    scan = scan_obj(path)
    if scan.vertices is not None:  # no faces
        return {"vertices": scan.vertices, "triangles": np.zeros((0, 3), dtype=np.int64)}
    import open3d as o3d

    try:
        with _quiet():
            mesh = o3d.t.io.read_triangle_mesh(str(path))
    except (IndexError, RuntimeError) as e:  # what the scan did not foresee, named with the file
        raise ParameterError(f"{path} is not a readable OBJ mesh (Open3D: {e})") from None
    if "positions" not in mesh.vertex or mesh.vertex.positions.shape[0] == 0:
        raise ParameterError(f"{path} is not a readable OBJ mesh")
    out = {
        "vertices": mesh.vertex.positions.numpy().astype(np.float64),
        "triangles": mesh.triangle.indices.numpy().astype(np.int64).reshape(-1, 3),
    }
    read_guard.check_indices(path, "face", out["triangles"], len(out["vertices"]))
    if "normals" in mesh.vertex:
        out["vertex_normals"] = mesh.vertex.normals.numpy().astype(np.float64)
    if "colors" in mesh.vertex:
        out["vertex_colors"] = mesh.vertex.colors.numpy().astype(np.float64)
    return out


# ------------------------------------------------------------------------------------------- line sets


def write_line_set(path: str | os.PathLike, points, lines, colors=None) -> Path:
    """Write line segments atomically as PLY (vertex + edge elements).

    points: (P,3) [m]; lines: (L,2) int indices into points; colors: (L,3) RGB in [0,1], one per line.
    With L == 0 an empty file is written (no lines, no points: points only matter through lines).
    Returns the path written.
    """
    path = Path(path)
    _format(path, LINE_SET_FORMATS, "line set")
    p = _points("points", points)
    seg = validate.indices("lines", lines, 2, p.shape[0], "points")
    rgb = None if colors is None else validate.colors("colors", colors, seg.shape[0])

    import open3d as o3d

    with atomic_path(path) as tmp:
        if seg.shape[0] == 0:
            props = ["int vertex1", "int vertex2"] + (
                ["uchar red", "uchar green", "uchar blue"] if rgb is not None else []
            )
            _write_empty_ply(tmp, [("vertex", ["double x", "double y", "double z"]), ("edge", props)])
            return path
        ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(p), o3d.utility.Vector2iVector(seg))
        if rgb is not None:
            ls.colors = o3d.utility.Vector3dVector(rgb)
        with _c_stderr_to_null():
            ok = o3d.io.write_line_set(str(tmp), ls, print_progress=False)
        _check_written(ok, tmp, path, "line set")
    return path


def read_line_set(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a PLY line set: {"points": (P,3) float64 [m], "lines": (L,2) int64, "colors": (L,3) if stored}."""
    path = _existing(path, "line set")
    import open3d as o3d

    with _quiet():
        ls = o3d.io.read_line_set(str(path), print_progress=False)
    if len(ls.points):
        out = {
            "points": np.asarray(ls.points, dtype=np.float64),
            "lines": np.asarray(ls.lines, dtype=np.int64).reshape(-1, 2),
        }
        read_guard.check_indices(path, "edge", out["lines"], len(out["points"]))
        if ls.has_colors():
            out["colors"] = np.asarray(ls.colors, dtype=np.float64)
        return out
    header = _ply_header(path) if path.suffix.lower() == ".ply" else None
    if header is not None and header.get("vertex", [None])[0] == 0:
        return {"points": np.zeros((0, 3)), "lines": np.zeros((0, 2), dtype=np.int64)}
    raise ParameterError(f"{path} is not a readable line set (unknown format, corrupt or truncated)")


def trails_to_line_set(
    trails, *, min_length: float = 0.0, return_source: bool = False
) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Turn particle trails into one polyline per particle, as (points (P,3), lines (L,2) int32).

    trails: (N,K,3) positions [m] of N particles at K successive times. Segment k joins sample k and k+1
    of one particle; segments of length <= min_length [m] are dropped (a freshly emitted particle's trail
    is filled with its birth position), and points used by no remaining segment are removed.
    return_source also returns, per line, the particle index (L,) and the sample index k (L,), e.g. to
    fade colours along the trail.
    """
    t = validate.finite_array("trails", trails)
    if t.ndim != 3 or t.shape[2] != 3:
        raise ParameterError(f"trails must have shape (N, K, 3), got {t.shape}")
    min_length = validate.non_negative("min_length", min_length)
    n, k, _ = t.shape
    if n == 0 or k < 2:
        empty = (np.zeros((0, 3)), np.zeros((0, 2), dtype=np.int32))
        return empty + (np.zeros(0, np.int64), np.zeros(0, np.int64)) if return_source else empty
    length = np.linalg.norm(t[:, 1:] - t[:, :-1], axis=2)  # (N, K-1)
    particle, sample = np.nonzero(length > min_length)
    start = particle * k + sample
    lines = np.stack([start, start + 1], axis=1)
    # Compact: keep only referenced points, in their original (particle, sample) order.
    used = np.unique(lines)
    remap = np.full(n * k, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    points = t.reshape(-1, 3)[used]
    lines = remap[lines].astype(np.int32)
    if return_source:
        return points, lines, particle.astype(np.int64), sample.astype(np.int64)
    return points, lines
