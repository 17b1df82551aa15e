"""Publishing output files safely: write to a hidden temporary beside the target, verify that every byte
the file announces is there, flush it to the disk, then rename it onto its final name.

This is the write-temporary-then-rename protocol of POSIX `rename(2)` (as used by databases and
package managers): readers only ever see a complete old or a complete new file. The completeness check
matters because writers that go through C stdio may ignore write errors: on a full disk (ENOSPC) or past
a file size limit (EFBIG), Open3D's PLY and OBJ writers report success and leave a short file. Every
OSError while publishing (disk full, permissions, a file where a folder must be) becomes an
`OutputError` naming the path, and the temporary is removed.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import hashlib
import json
import os
import re
import secrets
from collections.abc import Iterator
from pathlib import Path

from ..errors import OutputError, ParameterError

# `.NAME.tmp-1a2b3c4d.EXT`: hidden (a viewer polling the folder skips it), the target's extension kept
# (Open3D and image writers pick the format from it).
TEMPORARY_NAME = re.compile(r"\.(?P<stem>.+)\.tmp-[0-9a-f]{8}(?P<ext>\.[^.]+)?\Z")

_REASONS = {
    errno.ENOSPC: "no space left on the device",
    errno.EFBIG: "the file is larger than the allowed file size",
    errno.EDQUOT: "the disk quota is exhausted",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "the file system is read-only",
}


# While a run records what it writes (recording_files): (root folder, list of file records).
_RECORDER: contextvars.ContextVar[tuple[Path, list] | None] = contextvars.ContextVar("recorder", default=None)


def file_record(path: str | os.PathLike, root: str | os.PathLike, *, name: str | None = None) -> dict:
    """{"path": name, or path relative to root (POSIX), "bytes": size, "sha256": hex digest} of a file."""
    path, digest, size = Path(path), hashlib.sha256(), 0
    try:
        with open(path, "rb") as f:
            while chunk := f.read(1 << 20):
                digest.update(chunk)
                size += len(chunk)
    except OSError as e:
        raise output_error(path, e) from e
    if name is None:
        try:
            name = path.relative_to(root).as_posix()
        except ValueError:
            name = str(path)
    return {"path": name, "bytes": size, "sha256": digest.hexdigest()}


@contextlib.contextmanager
def recording_files(root: str | os.PathLike) -> Iterator[list[dict]]:
    """Within the block, every file atomic_path publishes is appended to the yielded list as a
    file_record (path relative to `root`), whichever writer published it; a run lists what it wrote,
    even a frame cut short by an error halfway through its files."""
    files: list[dict] = []
    token = _RECORDER.set((Path(root), files))
    try:
        yield files
    finally:
        _RECORDER.reset(token)


def output_error(path: str | os.PathLike, error: OSError) -> OutputError:
    """An OutputError for `error` while writing `path`, with a reason a user can act on."""
    reason = _REASONS.get(error.errno) if error.errno is not None else None
    if error.errno in (errno.ENOTDIR, errno.EEXIST):
        where = error.filename or Path(path).parent
        reason = f"{where} exists and is not a folder"
    elif error.errno == errno.EISDIR:
        reason = "a folder of that name exists"
    if reason is None:
        # The first line only: some tools append their command line and log to the message.
        lines = (error.strerror or str(error)).strip().splitlines()
        reason = lines[0] if lines else type(error).__name__
    return OutputError(f"cannot write {path}: {reason}")


def temporary_path(path: Path) -> Path:
    """A fresh hidden temporary name beside `path` (see TEMPORARY_NAME)."""
    # A random name instead of mkstemp: mkstemp creates the file with mode 0600, which os.replace would
    # carry over to the result; a fresh file gets the usual umask permissions.
    while True:
        tmp = path.with_name(f".{path.stem}.tmp-{secrets.token_hex(4)}{path.suffix}")
        if not tmp.exists():
            return tmp


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success verify it, flush it and move it onto `path`; on any
    error delete it.

    Readers (a viewer polling the output folder, Blender importing a sequence) then never see a
    half-written file, and a crash leaves the previous version in place. Before the rename the file is
    checked against what it announces (`incomplete_reason`: PLY and PCD sizes against their headers, PNG
    and JSON for their ends) and fsync'ed; after it, the folder is fsync'ed so the new name survives a
    power cut. The parent folder is created if missing. OSErrors become OutputError (see output_error).
    """
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = temporary_path(path)
        yield tmp
        reason = incomplete_reason(tmp)
        if reason is not None:
            raise OutputError(
                f"cannot write {path}: the written file is incomplete ({reason}); the disk may be full "
                "or a file size limit reached"
            )
        _fsync(tmp)
        recorder = _RECORDER.get()
        if recorder is not None:
            # Hash the temporary: the same bytes that the rename publishes.
            root = recorder[0]
            try:
                rel = path.relative_to(root).as_posix()
            except ValueError:
                rel = str(path)
            record = file_record(tmp, root, name=rel)
        os.replace(tmp, path)
        if recorder is not None:
            recorder[1].append(record)
        _fsync_folder(path.parent)
    except BaseException as e:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()
        if isinstance(e, OSError):
            raise output_error(path, e) from e
        raise


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)  # where delayed allocation meets a full disk, ENOSPC surfaces here
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    if not hasattr(os, "O_DIRECTORY"):  # Windows: folders cannot be opened; NTFS journals the rename
        return
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    except OSError as e:
        # Some file systems (network, FUSE) cannot sync a folder; the rename itself has succeeded.
        if e.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def remove_stale_temporaries(
    folder: str | os.PathLike, *, target: str | os.PathLike | None = None
) -> list[Path]:
    """Delete the temporaries (TEMPORARY_NAME) that killed runs left in `folder`, or with `target` (a
    file in some other folder, e.g. a video beside the user's files) only the temporaries of that one
    name; return what was removed.

    Call it while holding the folder's (or the target's) run lock (io/lock.py): a run owns its output
    folder, so a temporary found when a run starts belongs to no living writer.
    """
    folder = Path(folder)
    removed = []
    if not folder.is_dir():
        return removed
    own = None if target is None else (Path(target).stem, Path(target).suffix or None)
    for entry in sorted(folder.iterdir()):
        match = TEMPORARY_NAME.match(entry.name)
        if not match or not (entry.is_file() or entry.is_symlink()):
            continue
        if own is not None and (match["stem"], match["ext"]) != own:
            continue
        if remove_file(entry):
            removed.append(entry)
    return removed


def remove_file(entry: Path) -> bool:
    """Delete `entry`: True if it was removed, False if it was already gone; OutputError otherwise."""
    try:
        entry.unlink()
    except FileNotFoundError:
        return False
    except OSError as e:
        raise output_error(entry, e) from e
    return True


# ------------------------------------------------------------------------------------ completeness


def incomplete_reason(path: Path) -> str | None:
    """Why the file at `path` is not complete by its own description, or None if it is (or its format
    has no such description). PLY and PCD: data size against the header; PNG: the closing IEND chunk;
    JSON: it parses; USD: usd_problem; MP4: its boxes fill the file exactly and hold the movie header and
    data; GIF: the trailer byte."""
    ext = path.suffix.lower()
    if ext in (".usd", ".usdc", ".usda"):
        return usd_problem(path)
    if ext == ".ply":
        return ply_problem(path)
    if ext == ".pcd":
        return pcd_problem(path)
    if ext == ".png":
        with open(path, "rb") as f:
            f.seek(max(path.stat().st_size - 12, 0))
            # An empty IEND chunk: length 0, type, CRC.
            return None if f.read() == b"\0\0\0\0IEND\xaeB`\x82" else "the PNG has no closing IEND chunk"
    if ext == ".mp4":
        return mp4_problem(path)
    if ext == ".gif":
        with open(path, "rb") as f:
            head = f.read(6)
            f.seek(max(path.stat().st_size - 1, 0))
            ok = head in (b"GIF87a", b"GIF89a") and f.read(1) == b";"
        return None if ok else "the GIF has no header or no closing trailer"
    if ext == ".json":
        try:
            json.loads(path.read_bytes())
        except ValueError as e:
            return f"the JSON does not parse: {e}"
    return None


def usd_problem(path: Path) -> str | None:
    """Why a USD layer is not complete, or None: it must open (a crate file cut short loses its table of
    contents, a text file its closing brackets); a stage written by io/usd.py also records its frame and
    prim counts (customLayerData "taichi_anim"), checked against its time samples, endTimeCode and prims."""
    from pxr import Sdf, Tf

    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path))
    except Tf.ErrorException as e:
        return f"the USD layer does not open: {' '.join(str(e).split())[:200]}"
    if layer is None:
        return "the USD layer does not open"
    expected = layer.customLayerData.get("taichi_anim")
    if not isinstance(expected, dict):
        return None
    samples = layer.ListAllTimeSamples()
    if len(samples) != expected.get("frames", len(samples)):
        return f"{expected['frames']} frames announced, {len(samples)} time codes written"
    if samples and layer.HasEndTimeCode() and max(samples) != layer.endTimeCode:
        return f"its last time sample is {max(samples)}, its endTimeCode {layer.endTimeCode}"
    prims = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: prims.append(p) if p.IsPrimPath() else None)
    if len(prims) != expected.get("prims", len(prims)):
        return f"{expected['prims']} prims announced, {len(prims)} written"
    return None


def mp4_problem(path: Path) -> str | None:
    """Why an MP4 (ISO base media file) is not complete, or None: its top-level boxes (32-bit size, or 1
    and a 64-bit size, then the type; ISO/IEC 14496-12) must end exactly at the end of the file, and
    the movie header "moov" and the media data "mdat" must be there (an encoder that stopped early
    leaves an empty file, no "moov", or a box running past the end)."""
    size, pos, kinds = path.stat().st_size, 0, set()
    if size == 0:
        return "the MP4 is empty"
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            head = f.read(16)
            if len(head) < 8:
                return "the MP4 ends inside a box header"
            length, kind = int.from_bytes(head[:4], "big"), head[4:8]
            if length == 1 and len(head) == 16:
                length = int.from_bytes(head[8:16], "big")
            elif length == 0:  # the last box runs to the end of the file
                length = size - pos
            if length < 8 or pos + length > size:
                return f"the MP4 box {kind!r} at byte {pos} runs past the end of the file"
            kinds.add(kind)
            pos += length
    missing = [k.decode() for k in (b"moov", b"mdat") if k not in kinds]
    return f"the MP4 has no {' or '.join(missing)} box" if missing else None


def text_rows_problem(path: Path, expected: dict[bytes, int]) -> str | None:
    """For header-less text formats (OBJ, XYZ): compare the number of lines starting with each key of
    `expected` (b"" counts every non-blank line) and check that the last line is complete."""
    counts = dict.fromkeys(expected, 0)
    last = b"\n"
    with open(path, "rb") as f:
        for line in f:
            key = line.split(maxsplit=1)[:1]
            if not key:
                continue
            last = line[-1:]
            if key[0] in counts:
                counts[key[0]] += 1
            if b"" in counts:
                counts[b""] += 1
    for key, n in expected.items():
        if counts[key] != n:
            what = f"'{key.decode()}' lines" if key else "lines"
            return f"{n} {what} expected, {counts[key]} written"
    return None if last == b"\n" else "the last line is cut off"


PLY_SIZES = {"char": 1, "uchar": 1, "short": 2, "ushort": 2, "int": 4, "uint": 4, "float": 4, "double": 8}
PLY_SIZES.update(int8=1, uint8=1, int16=2, uint16=2, int32=4, uint32=4, float32=4, float64=8)


def ply_layout(path: Path) -> tuple[str, int, list] | None:
    """(format, offset of the data, [(element, count, [(property, type or ("list", count_t, item_t))])])
    from a PLY header, or None if the file is not PLY."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return None
    data_start = head.index(b"\n", end) + 1 if b"\n" in head[end:] else len(head)
    fmt, elements = "", []
    for line in head[:end].decode("ascii", "replace").splitlines():
        parts = line.split()
        try:
            if parts[:1] == ["format"]:
                fmt = parts[1]
            elif parts[:1] == ["element"]:
                elements.append((parts[1], int(parts[2]), []))
            elif parts[:1] == ["property"] and elements:
                kind = ("list", parts[2], parts[3]) if parts[1] == "list" else parts[1]
                elements[-1][2].append((parts[-1], kind))
        except (IndexError, ValueError):
            return None
    return fmt, data_start, elements


def ply_problem(path: Path) -> str | None:
    """Why a PLY file is not complete (no header, or less data than its header announces), or None."""
    layout = ply_layout(path)
    if layout is None:
        return "no valid PLY header"
    fmt, offset, elements = layout
    size = path.stat().st_size
    if fmt == "ascii":
        with open(path, "rb") as f:
            f.seek(offset)
            rows = sum(1 for line in f if line.strip())
        needed = sum(count for _, count, _ in elements)
        return None if rows >= needed else f"its header announces {needed} rows, it holds {rows}"
    expected = offset
    with open(path, "rb") as f:
        for name, count, props in elements:
            lists = [k for _, k in props if isinstance(k, tuple)]
            try:
                fixed = sum(PLY_SIZES[k] for _, k in props if not isinstance(k, tuple))
            except KeyError:
                return None  # an unusual type: leave the judgement to Open3D
            if not lists:
                expected += count * fixed
                continue
            if len(lists) > 1 or count == 0 or props[0][1] != lists[0]:
                return None  # layouts we do not write; checking them would need a row-by-row walk
            # Meshes store one `list uchar int` per face; all triangles have the same length.
            _, count_t, item_t = lists[0]
            f.seek(expected)
            first = f.read(PLY_SIZES[count_t])
            if len(first) < PLY_SIZES[count_t]:
                return f"its data ends before element {name!r}"
            order = "little" if fmt == "binary_little_endian" else "big"
            length = int.from_bytes(first, order)
            expected += count * (PLY_SIZES[count_t] + length * PLY_SIZES[item_t] + fixed)
    if size < expected:
        return f"its header announces {expected - offset} bytes of data, it holds {size - offset}"
    return None


def pcd_header(path: Path) -> tuple[dict[str, list[str]], int] | None:
    """({field: values} of a PCD header up to DATA, offset of the data), or None if there is no header."""
    with open(path, "rb") as f:
        head = f.read(1 << 14)
    fields: dict[str, list[str]] = {}
    offset = 0
    for raw in head.splitlines(keepends=True):
        offset += len(raw)
        parts = raw.decode("ascii", "replace").split()
        if not parts or parts[0].startswith("#"):
            continue
        fields[parts[0]] = parts[1:]
        if parts[0] == "DATA":
            return fields, offset
    return None


def pcd_layout(fields: dict) -> tuple[int, str, int, int]:
    """(points, data kind, bytes per point, values per point) of a parsed PCD header (pcd_header);
    raises KeyError, IndexError or ValueError when a field is missing or malformed."""
    points = int(fields["POINTS"][0])
    row = sum(int(s) * int(c) for s, c in zip(fields["SIZE"], fields["COUNT"], strict=True))
    return points, fields["DATA"][0], row, sum(int(c) for c in fields["COUNT"])


def pcd_problem(path: Path) -> str | None:
    """Why a PCD file is not complete (no header, or fewer points than POINTS announces), or None."""
    parsed = pcd_header(path)
    if parsed is None:
        return "no valid PCD header"
    fields, offset = parsed
    try:
        points, data, row, _ = pcd_layout(fields)
    except (KeyError, IndexError, ValueError):
        return "a malformed PCD header"
    if data == "ascii":
        with open(path, "rb") as f:
            f.seek(offset)
            rows = sum(1 for line in f if line.strip())
        return None if rows >= points else f"its header announces {points} points, it holds {rows}"
    if data == "binary":
        size = path.stat().st_size - offset
        return None if size >= points * row else f"its header announces {points * row} bytes, it holds {size}"
    return None  # binary_compressed: its own length fields; we do not write it


def check_complete(path: Path, what: str) -> None:
    """Raise ParameterError if the file at `path` (read as a `what`) is incomplete (see incomplete_reason).

    Open3D reads a truncated PLY (an interrupted copy, a full disk) with only a printed warning and
    returns the rows it got, or for the tensor reader uninitialised memory, so readers check first.
    """
    reason = incomplete_reason(path)
    if reason is not None:
        raise ParameterError(f"{path} is not a readable {what}: it is truncated or corrupt ({reason})")
