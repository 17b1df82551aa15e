"""Hard cases for hostile files and absurd sizes: each is refused with a ParameterError naming the file
or the parameter and the numbers, within seconds and before memory is spent.

The cases run in a child process whose address space is capped (RLIMIT_AS, 3 GiB: Taichi itself
reserves ~1.5 GiB), so a regression that reads an 8 GiB file or allocates a 10^8-vertex cloth fails
with a MemoryError in the child instead of exhausting the machine, and a FIFO that blocks the reader
fails by the child's timeout instead of hanging the suite. The child reports, per case, the error, the
seconds it took and how much its peak resident size grew."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import taichi_anim
from taichi_anim.io import write_point_cloud, write_triangle_mesh

GIB = 1 << 30
LIMIT = 3 * GIB
INT32_MAX = 2**31 - 1

CHILD = textwrap.dedent(
    """
    import json, resource, signal, sys, time
    resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[1]), int(sys.argv[1])))
    import taichi_anim as ta
    from taichi_anim import validate
    from taichi_anim.geometry import load_mesh
    from taichi_anim.io import read_line_set, read_point_cloud, read_triangle_mesh
    from taichi_anim.spatial import BVH
    ta.init("cpu")

    def too_slow(signum, frame):
        raise TimeoutError("still running after 20 s")

    signal.signal(signal.SIGALRM, too_slow)
    out = {}
    for name, code in json.loads(sys.argv[2]).items():
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        start = time.perf_counter()
        errors = []
        for line in code.splitlines():  # each line one call that must raise
            signal.alarm(20)
            try:
                exec(line)
                errors.append(None)
            except Exception as e:
                errors.append([type(e).__name__, str(e)[:2000]])
            finally:
                signal.alarm(0)
        grew = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
        out[name] = dict(errors=errors, seconds=time.perf_counter() - start, grew_mib=grew / 1024)
    print("RESULT " + json.dumps(out))
    """
)


def run_limited(cases: dict[str, str], timeout: float = 120.0) -> dict:
    """Run each case's lines of code in a child capped at LIMIT bytes of address space."""
    root = str(Path(taichi_anim.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    run = subprocess.run(
        [sys.executable, "-c", CHILD, str(LIMIT), json.dumps(cases)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        cwd=root,
    )
    lines = [line for line in run.stdout.splitlines() if line.startswith("RESULT ")]
    assert run.returncode == 0 and lines, run.stdout[-2000:] + run.stderr[-2000:]
    return json.loads(lines[-1][len("RESULT ") :])


def sparse(path: Path, head: bytes = b"", size: int = 8 * GIB) -> Path:
    """A file of `size` bytes, `head` then zeros; sparse, so it takes no disk space."""
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def ply_header(fmt: str, vertices: int, faces: int | None = None, vertex_type: str = "float") -> bytes:
    lines = ["ply", f"format {fmt} 1.0", f"element vertex {vertices}"]
    lines += [f"property {vertex_type} {c}" for c in "xyz"]
    if faces is not None:
        lines += [f"element face {faces}", "property list uchar int vertex_indices"]
    return ("\n".join(lines + ["end_header"]) + "\n").encode()


TRIANGLE = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("hostile")
    f = {
        "big.obj": sparse(d / "big.obj"),
        "big.xyz": sparse(d / "big.xyz"),
        "zeros.ply": sparse(d / "zeros.ply", ply_header("ascii", 3)),
        "huge.ply": d / "huge.ply",
        "huge.pcd": d / "huge.pcd",
        "face99.obj": d / "face99.obj",
        "face0.obj": d / "face0.obj",
        "relative.obj": d / "relative.obj",
        "face99.ply": d / "face99.ply",
        "face99_ascii.ply": d / "face99_ascii.ply",
        "zero.ply": d / "zero.ply",
        "folder.ply": d / "folder.ply",
        "valid.ply": write_triangle_mesh(d / "valid.ply", TRIANGLE, [[0, 1, 2]]),
        "valid.obj": write_triangle_mesh(d / "valid.obj", TRIANGLE, [[0, 1, 2]]),
    }
    # 10^12 double vertices and two faces: Python's seek past the file system's limit raised OSError.
    f["huge.ply"].write_bytes(ply_header("binary_little_endian", 10**12, 2, "double") + bytes(1000))
    f["huge.pcd"].write_bytes(
        b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1000000000\nHEIGHT 1\n"
        b"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1000000000\nDATA binary\n" + bytes(1000)
    )
    vertex_lines = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
    f["face99.obj"].write_text(vertex_lines + "f 1 2 3\nf 1 2 99\n")
    f["face0.obj"].write_text(vertex_lines + "f 0 1 2\n")
    f["relative.obj"].write_text(vertex_lines + "f -1 -2 -4\n")
    face = np.uint8(3).tobytes() + np.array([0, 1, 99], "<i4").tobytes()
    f["face99.ply"].write_bytes(
        ply_header("binary_little_endian", 3, 1) + TRIANGLE.astype("<f4").tobytes() + face
    )
    f["face99_ascii.ply"].write_text(ply_header("ascii", 3, 1).decode() + "0 0 0\n1 0 0\n0 1 0\n3 0 1 99\n")
    os.symlink("/dev/zero", f["zero.ply"])
    f["folder.ply"].mkdir()
    return f


@pytest.fixture(scope="module")
def refused_files(files) -> tuple[dict, dict]:
    """The hostile files (all but the FIFO), read once in one capped child: (cases, results)."""
    p = {k: repr(str(v)) for k, v in files.items()}
    cases = {
        "sparse obj": f"read_triangle_mesh({p['big.obj']})\nload_mesh({p['big.obj']}, name='drape')",
        "sparse xyz": f"read_point_cloud({p['big.xyz']})",
        "ascii ply zeros": f"read_triangle_mesh({p['zeros.ply']})\nread_point_cloud({p['zeros.ply']})",
        "binary ply 1e12": "\n".join(
            f"{r}({p['huge.ply']})" for r in ("read_triangle_mesh", "read_point_cloud", "read_line_set")
        ),
        "pcd 1e9": f"read_point_cloud({p['huge.pcd']})",
        "obj face 99": "\n".join(
            f"{call}({p['face99.obj']})" for call in ("read_triangle_mesh", "ta.Builder().add_cloth_mesh")
        ),
        "obj face 0": f"read_triangle_mesh({p['face0.obj']})",
        "obj relative": f"read_triangle_mesh({p['relative.obj']})",
        "ply face 99": f"read_triangle_mesh({p['face99.ply']})\nread_triangle_mesh({p['face99_ascii.ply']})",
        "dev zero": f"read_triangle_mesh({p['zero.ply']})\nread_point_cloud({p['zero.ply']})",
        "folder": f"read_triangle_mesh({p['folder.ply']})\nload_mesh({p['folder.ply']})",
        "valid files": "\n".join(
            f"assert len(read_triangle_mesh({p[k]})['triangles']) == 1" for k in ("valid.ply", "valid.obj")
        ),
    }
    return cases, run_limited(cases)


@pytest.fixture(scope="module")
def refused_sizes() -> tuple[dict, dict]:
    """The absurd sizes, tried once in another capped child: (cases, results)."""
    cases = {
        "cloth grid": "ta.Builder().add_cloth_grid(resolution=(10**4, 10**4))",
        "cloth grid int32": "ta.Builder().add_cloth_grid(resolution=(10**5, 10**5))",
        "bvh": "BVH(2 * 10**9)",
        "emitter": "ta.Builder().add_particle_emitter(capacity=2**31 - 1, rate=1.0)",
        "blob grid": "ta.BlobField(capacity=10, sigma=0.1, bounds=((0, 0, 0), (1, 1, 1)), resolution=10**5)",
        # Memory said to be plentiful: only the int32 range stands between these and the allocation.
        "particle total": "validate.available_memory = lambda: 1 << 62\n"
        "b = ta.Builder(); [b.add_particle_emitter(capacity=1_200_000_000, rate=1.0) for _ in range(2)]; "
        "b.finalize()",
    }
    return cases, run_limited(cases)


def check(refused, case: str, *words, seconds: float = 5.0) -> None:
    """Every call of `case` raised ParameterError containing `words`, quickly and without growing."""
    cases, results = refused
    result = results[case]
    for line, error in zip(cases[case].splitlines(), result["errors"], strict=True):
        if line.startswith("validate.available_memory"):
            continue
        assert error is not None, f"{line}: no error"
        kind, message = error
        assert kind == "ParameterError", f"{line}: {kind}: {message}"
        for w in words:
            assert str(w) in message, f"{line}: {w!r} not in {message!r}"
    assert result["seconds"] < seconds, result
    assert result["grew_mib"] < 64, result


def test_sparse_8_gib_obj_and_xyz_are_refused_at_their_first_line(refused_files):
    check(refused_files, "sparse obj", "big.obj", "line 1", "1048576")
    assert "drape" in refused_files[1]["sparse obj"]["errors"][1][1]
    check(refused_files, "sparse xyz", "big.xyz", "line 1", "1048576")


def test_ascii_ply_header_then_8_gib_of_zeros_is_refused_at_its_first_data_line(refused_files):
    check(refused_files, "ascii ply zeros", "zeros.ply", "line 8", "1048576")


def test_binary_ply_declaring_10_12_vertices_names_the_file_and_both_sizes(refused_files):
    # 10^12 vertices of three doubles, two faces of at least a count byte: 24 * 10^12 + 2 bytes.
    check(
        refused_files,
        "binary ply 1e12",
        "huge.ply",
        "1000000000000 'vertex' rows",
        "24000000000002",
        "holds 1000",
    )
    check(refused_files, "pcd 1e9", "huge.pcd", "1000000000 points", "12000000000", "holds 1000")


def test_lying_ply_headers_are_refused_both_ways(tmp_path):
    from taichi_anim import ParameterError
    from taichi_anim.io import read_point_cloud, read_triangle_mesh

    v = np.array([[x, 0.0, z] for z in range(4) for x in range(4)])
    f = np.array([[0, 4, 1], [1, 4, 5], [5, 9, 6]])
    path = write_triangle_mesh(tmp_path / "m.ply", v, f, compute_normals=False)
    full = path.read_bytes()
    offset = full.index(b"end_header\n") + len(b"end_header\n")
    cut = tmp_path / "cut.ply"
    cut.write_bytes(full[:-10])  # a copy cut short: the last face loses 10 of its 13 bytes
    with pytest.raises(ParameterError) as e:
        read_triangle_mesh(cut)
    for w in (
        "cut.ply",
        "16 'vertex' rows",
        f"{len(full) - offset} bytes",
        f"holds {len(full) - offset - 10}",
    ):
        assert w in str(e.value)
    # Far less declared than held: 10^5 points of 12 bytes under a header that says 10.
    points = np.random.default_rng(0).random((10**5, 3)).astype(np.float32)
    cloud = write_point_cloud(tmp_path / "c.ply", points)
    data = cloud.read_bytes().replace(b"element vertex 100000\n", b"element vertex 10\n", 1)
    cloud.write_bytes(data)
    with pytest.raises(ParameterError) as e:
        read_point_cloud(cloud)
    for w in ("c.ply", "10 'vertex' rows", "far less", "120 bytes", "holds 1200000"):
        assert w in str(e.value)


def test_obj_face_index_out_of_range_names_the_file_face_and_index(refused_files):
    check(refused_files, "obj face 99", "face99.obj", "face 2", "line 5", "vertex index 99", "3 vertices")
    check(refused_files, "obj face 0", "face0.obj", "face 1", "vertex index 0")
    check(refused_files, "obj relative", "relative.obj", "face 1", "vertex index -4")


def test_ply_face_index_out_of_range_names_the_file_face_and_index(refused_files):
    check(refused_files, "ply face 99", "face 0", "vertex index 99", "outside [0, 3)")
    errors = refused_files[1]["ply face 99"]["errors"]
    assert "face99.ply" in errors[0][1] and "face99_ascii.ply" in errors[1][1]


def test_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    # Nobody writes to the FIFO: a reader that opened it would block until the timeout.
    result = run_limited({"fifo": f"read_triangle_mesh({str(fifo)!r})\nread_point_cloud({str(fifo)!r})"}, 60)
    for error in result["fifo"]["errors"]:
        assert error[0] == "ParameterError" and "pipe.ply" in error[1] and "FIFO" in error[1], error


def test_dev_zero_behind_a_link_and_a_folder_are_refused(refused_files):
    check(refused_files, "dev zero", "zero.ply", "a link to /dev/zero", "character device")
    check(refused_files, "folder", "folder.ply", "is a directory")


def test_huge_cloth_grid_fails_within_a_second_naming_resolution_and_bytes(refused_sizes):
    # 10^8 vertices at the measured ~2000 bytes each, against at most the child's 3 GiB.
    words = ("resolution (10000, 10000)", "100000000 cloth vertices", "200000000000 bytes", "available")
    check(refused_sizes, "cloth grid", *words, seconds=1.0)
    check(refused_sizes, "cloth grid int32", "resolution (100000, 100000)", "spring ends", str(INT32_MAX))


def test_bvh_capacity_beyond_int32_nodes_names_capacity_and_limit(refused_sizes):
    check(refused_sizes, "bvh", "capacity", "2000000000 boxes", "1073741824", str(INT32_MAX))


def test_huge_emitter_capacity_and_particle_total_are_refused(refused_sizes):
    check(
        refused_sizes,
        "emitter",
        "capacity",
        f"{INT32_MAX} emitter slots",
        f"{INT32_MAX * 140} bytes",
        "available",
    )
    check(
        refused_sizes, "particle total", "particles", "2400000000 particles and emitter slots", str(INT32_MAX)
    )


def test_blob_grid_beyond_int32_nodes_names_resolution(refused_sizes):
    check(refused_sizes, "blob grid", "resolution 100000", "1000000000000000 grid nodes", str(INT32_MAX))


def test_reasonable_sizes_pass_the_checks(refused_files, monkeypatch):
    """Pass: the estimates do not over-count: 10^7 emitter slots fit a machine with 24 GiB available
    (~1.4 GB), a 1000 x 1000 cloth too (~2 GB), and the capped child still reads valid files."""
    import taichi_anim as ta
    from taichi_anim import validate
    from taichi_anim.builder import CLOTH_GRID_BYTES_PER_VERTEX

    assert refused_files[1]["valid files"]["errors"] == [None, None]
    monkeypatch.setattr(validate, "available_memory", lambda: 24 * GIB)
    ta.Builder().add_particle_emitter(capacity=10**7, rate=1.0)
    validate.capacity("resolution", 1000 * 1000, bytes_each=CLOTH_GRID_BYTES_PER_VERTEX)


V4 = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
VT3 = "vt 0 0\nvt 1 0\nvt 0 1\n"


@pytest.mark.parametrize(
    "text, triangles",
    [
        (V4 + "f 1 2 3\nf 2 4 3\n", 2),
        (V4 + VT3 + "vn 0 0 1\nf 1/1/1 2/2/1 3/3/1\n", 1),
        (V4 + "vn 0 0 1\nf 1//1 2//1 3//1\n", 1),
        (V4 + VT3 + "f 1/1 2/2 3/3\n", 1),
        (V4 + VT3 + "f 1 2/2 3\n", 1),  # corners of mixed layouts: checked line by line
        (V4 + "f 1 2 4 3\n", 2),  # a quad, triangulated
        (V4 + "f -4 -3 -2\n", 1),  # relative to the last vertex defined
        (V4 + "f\t1\t2\t3\n", 1),
        (V4.replace("\n", "\r\n") + "f 1 2 3\r\n", 1),
        ("f 1 2 3\n" + V4, 1),  # vertices defined after the face
        (V4 + "# comment\n\ng group\ns off\no name\nusemtl m\nvp 0.5\nf 1 2 3", 1),
    ],
)
def test_valid_obj_layouts_are_read(tmp_path, text, triangles):
    from taichi_anim.io import read_triangle_mesh

    (tmp_path / "m.obj").write_text(text)
    assert read_triangle_mesh(tmp_path / "m.obj")["triangles"].shape == (triangles, 3)


@pytest.mark.parametrize(
    "text, words",
    [
        (V4 + "f 1/1 2/2 3/3\n", ["face 1 (line 5)", "texture coordinate index 1", "0 texture coordinates"]),
        (V4 + VT3 + "f 1/1 2/2 3/9\n", ["face 1 (line 8)", "texture coordinate index 9"]),
        (V4 + "f -4 -3 -5\n", ["face 1 (line 5)", "vertex index -5", "4 defined before it"]),
        ("f 1 2 5\n" + V4, ["face 1 (line 1)", "vertex index 5", "4 vertices"]),
        (V4 + "f 1 2\n", ["face 1 (line 5)", "2 corners"]),
        (V4 + "f 1.5 2 3\n", ["face 1 (line 5)", "'1.5'"]),
        (V4 + "xyz 1 2\n", ["line 5", "'xyz 1 2'"]),
        # Open3D's reader turns `l` elements into triangles with garbage indices and skips indented lines.
        (V4 + "f 1 2 3\nl 1 2\n", ["line 6", "'l 1 2'"]),
        (V4 + "  f 1 2 3\n", ["line 5", "indented"]),
    ],
)
def test_broken_obj_layouts_name_the_line(tmp_path, text, words):
    from taichi_anim import ParameterError
    from taichi_anim.io import read_triangle_mesh

    (tmp_path / "m.obj").write_text(text)
    with pytest.raises(ParameterError) as e:
        read_triangle_mesh(tmp_path / "m.obj")
    for w in ["m.obj", *words]:
        assert w in str(e.value)
