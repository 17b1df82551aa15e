"""Checks a file must pass before anything parses it (Open3D, or the OBJ scan here), so that a hostile
or broken file is refused with a ParameterError naming it instead of hanging the reader, exhausting
memory or crashing Open3D.

- Only regular files are read: a FIFO would block the reader forever, /dev/zero never ends, a directory
  is no file. The type is taken from os.stat (links followed), then again from the opened descriptor
  (opened with O_NONBLOCK, so a FIFO swapped in between cannot block the check).
- Headers must agree with the file size: a PLY or PCD header may not declare more data than the file
  holds (a binary vertex of three floats needs 12 bytes, an ASCII value at least 2), nor, for binary
  data, far less (more than twice the declared data plus 64 KiB of trailing bytes).
- Text is read line by line, each line at most MAX_LINE_BYTES: a file of zeros without a newline is
  refused at its first line instead of being read into memory whole.
- Counts must fit 32-bit indices, and face (and edge) vertex indices must lie in range, before Open3D
  sees them (its OBJ reader raises a bare IndexError on `f 1 2 99`; its PLY reader keeps the index).
"""

from __future__ import annotations

import os
import stat
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np

from .. import validate
from ..errors import ParameterError
from .atomic import PLY_SIZES, pcd_header, pcd_layout, ply_layout

MAX_LINE_BYTES = 1 << 20  # longest text line read [bytes], its line end included
_BLOCK_BYTES = 1 << 22  # text read at once
_SPACE_BYTES = b" \t\n\r\v\f"
_SPACE = np.isin(np.arange(256), list(_SPACE_BYTES))  # bytes that separate tokens
# A line that starts with one of these may be blank (the first line, or after b"\\n").
_BLANK_STARTS = tuple(b"\n" + bytes([c]) for c in b" \t\n\r\v\f")
TRAILING_SLACK = 1 << 16  # bytes tolerated after a binary file's declared data (on top of doubling it)
_CHUNK_ROWS = 1 << 16  # binary rows read at once while checking indices
_PLY_NUMPY = {
    "char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4",
    "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4",
    "uint32": "u4", "float32": "f4", "float64": "f8",
}  # fmt: skip
# Properties holding vertex indices, per element (Open3D's names for faces and line-set edges).
_INDEX_PROPERTIES = {"face": ("vertex_indices", "vertex_index"), "edge": ("vertex1", "vertex2")}
_NOT_REGULAR = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


# ------------------------------------------------------------------------------------------ the file


def regular_file(path: str | os.PathLike, what: str) -> tuple[Path, int]:
    """(path, size in bytes) of an existing regular file; FileNotFoundError if it does not exist,
    ParameterError if it is anything else (directory, FIFO, device, socket) or cannot be opened."""
    path = Path(path)
    try:
        kind = _not_regular(os.stat(path).st_mode)
        if kind is None:
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
            try:
                st = os.fstat(fd)
            finally:
                os.close(fd)
            kind = _not_regular(st.st_mode)
    except FileNotFoundError:
        raise FileNotFoundError(f"no such file: {path}") from None
    except OSError as e:
        raise ParameterError(f"cannot read {path} as a {what}: {e.strerror or e}") from None
    if kind is not None:
        real = os.path.realpath(path)
        link = f" (a link to {real})" if real != os.path.abspath(path) else ""
        raise ParameterError(f"{path}{link} is {kind}, not a regular file: refusing to read it as a {what}")
    return path, st.st_size


def _not_regular(mode: int) -> str | None:
    if stat.S_ISREG(mode):
        return None
    return next((kind for test, kind in _NOT_REGULAR if test(mode)), "not a regular file")


def line_blocks(f: BinaryIO, path: Path, line: int = 0) -> Iterator[tuple[int, list[bytes]]]:
    """(number of the first line, lines without their line ends) for blocks of whole lines from f's
    position on; `line` lines came before. Raises ParameterError, naming the file and the line, at a
    line longer than MAX_LINE_BYTES. Memory stays within a block (4 MiB) and one line."""
    tail = b""
    while True:
        data = f.read(_BLOCK_BYTES)
        if not data:
            if tail:
                yield line + 1, [tail]
            return
        data = tail + data
        cut = data.rfind(b"\n") + 1
        lines = data[: cut - 1].split(b"\n") if cut else []
        tail = data[cut:]
        if lines and max(map(len, lines)) >= MAX_LINE_BYTES:
            long = next(k for k, text in enumerate(lines) if len(text) >= MAX_LINE_BYTES)
            raise _long_line(path, line + long + 1)
        if len(tail) >= MAX_LINE_BYTES:
            raise _long_line(path, line + len(lines) + 1)
        if lines:
            yield line + 1, lines
        line += len(lines)


def bounded_lines(f: BinaryIO, path: Path, line: int = 0) -> Iterator[tuple[int, bytes]]:
    """(line number, line without its line end) for each line of line_blocks."""
    for first, lines in line_blocks(f, path, line):
        yield from enumerate(lines, first)


def _long_line(path: Path, line: int) -> ParameterError:
    return ParameterError(
        f"{path}: line {line} is longer than {MAX_LINE_BYTES} bytes (1 MiB) without a line end: not a text "
        "file of this format (corrupt, or binary data)"
    )


def token_starts(text: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(text as uint8, offsets where its whitespace-separated tokens start)."""
    b = np.frombuffer(text, np.uint8)
    space = _SPACE[b]
    starts = np.flatnonzero(space[:-1] & ~space[1:]) + 1
    if b.size and not space[0]:
        starts = np.concatenate([[0], starts])
    return b, starts


def token_counts(text: bytes, lines: int) -> np.ndarray:
    """Whitespace-separated tokens on each of the `lines` lines of `text` (lines joined by b"\\n")."""
    b, starts = token_starts(text)
    return np.bincount(np.searchsorted(np.flatnonzero(b == 10), starts), minlength=lines)


def numbers(text: bytes, dtype) -> np.ndarray | None:
    """Every whitespace-separated number of `text` as `dtype` (parsed in C), or None if any is not one."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return np.fromstring(text, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None


def check_input(path: str | os.PathLike, what: str) -> Path:
    """The checks of the module docstring for a file about to be read as a `what`; returns its path.
    OBJ files are checked by scan_obj, which reads them anyway."""
    path, size = regular_file(path, what)
    fmt = path.suffix.lower()
    if fmt == ".ply":
        check_ply(path, size, what)
    elif fmt == ".pcd":
        check_pcd(path, size, what)
    elif fmt == ".xyz":
        with open(path, "rb") as f:
            for _ in line_blocks(f, path):
                pass
    return path


def _lying(path: Path, what: str, declared: str, need: int, holds: int, more: bool = True) -> ParameterError:
    side = "more" if more else "far less"
    return ParameterError(
        f"{path} is not a readable {what}: it is truncated or corrupt (its header declares {declared}, "
        f"{side} data than the file holds: {'at least ' if more else ''}{need} bytes of data expected, "
        f"the file holds {holds})"
    )


# ----------------------------------------------------------------------------------------------- PLY


def check_ply(path: Path, size: int, what: str) -> None:
    """Header against size, bounded text, element counts, and face/edge indices against the vertex count."""
    layout = ply_layout(path)
    if layout is None:
        raise ParameterError(
            f"{path} is not a readable {what}: it is truncated or corrupt (no valid PLY header: 'ply' "
            "first and 'end_header' within 64 KiB)"
        )
    fmt, offset, elements = layout
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ParameterError(f"{path} is not a readable {what}: unknown PLY format {fmt!r}")
    for name, count, props in elements:
        for prop, kind in props:
            types = kind[1:] if isinstance(kind, tuple) else (kind,)
            if any(t not in PLY_SIZES for t in types):
                raise ParameterError(f"{path}: property {prop!r} of element {name!r} has an unknown type")
        if count < 0:
            raise ParameterError(f"{path}: element {name!r} declares a negative count ({count})")
    data = size - offset
    if fmt == "ascii":
        # Every value is at least one character and a separator.
        need = sum(count * 2 * len(props) for _, count, props in elements)
        if need > data:
            raise _lying(path, what, _declared(elements), need, data)
        _check_counts(path, elements)
        _walk_ascii_ply(path, offset, elements, what)
        return
    least = sum(count * _row_bytes(props, 0) for _, count, props in elements)
    if least > data:
        raise _lying(path, what, _declared(elements), least, data)
    _check_counts(path, elements)
    end = _walk_binary_ply(path, offset, elements, fmt, what)
    if end is not None:
        if end > size:
            raise _lying(path, what, _declared(elements), end - offset, data)
        if size - end > (end - offset) + TRAILING_SLACK:
            raise _lying(path, what, _declared(elements), end - offset, data, more=False)


def _declared(elements) -> str:
    return ", ".join(f"{count} {name!r} rows" for name, count, _ in elements) or "no elements"


def _row_bytes(props, list_length: int) -> int:
    """Bytes of one binary row whose lists all hold `list_length` items."""
    total = 0
    for _, kind in props:
        if isinstance(kind, tuple):
            total += PLY_SIZES[kind[1]] + list_length * PLY_SIZES[kind[2]]
        else:
            total += PLY_SIZES[kind]
    return total


def _check_counts(path: Path, elements) -> None:
    for name, count, props in elements:
        # Open3D keeps a float64 per value and the readers return another copy.
        validate.capacity(f"{path}: element {name!r}", count, bytes_each=16 * max(len(props), 1), unit="rows")


def _vertex_count(elements) -> int:
    return next((count for name, count, _ in elements if name == "vertex"), 0)


def _index_columns(name: str, props) -> list[int]:
    """Positions of the vertex-index properties of element `name` among its properties."""
    wanted = _INDEX_PROPERTIES.get(name, ())
    return [k for k, (prop, _) in enumerate(props) if prop in wanted]


def _bad_index(path: Path, element: str, row: int, index: int, vertices: int) -> ParameterError:
    return ParameterError(
        f"{path}: {element} {row} has vertex index {index}, outside [0, {vertices}) (the file declares "
        f"{vertices} vertices)"
    )


def _walk_ascii_ply(path: Path, offset: int, elements, what: str) -> None:
    """Read the declared rows with bounded lines, checking face/edge indices in chunks; the text after
    the last declared row is not read."""
    vertices = _vertex_count(elements)
    with open(path, "rb") as f:
        rows = _Rows(line_blocks(f, path, f.read(offset).count(b"\n")))
        for name, count, props in elements:
            columns = _index_columns(name, props)
            checked = bool(columns) and (all(not isinstance(k, tuple) for _, k in props) or len(props) == 1)
            row = 0
            while row < count:
                numbers_, lines = rows.take(min(count - row, _CHUNK_ROWS))
                if not lines:
                    raise ParameterError(
                        f"{path} is not a readable {what}: it is truncated or corrupt (its header declares "
                        f"{count} {name!r} rows, the file ends after {row})"
                    )
                if checked:
                    _check_ascii_rows(path, name, row, numbers_, lines, props, columns, vertices)
                row += len(lines)


class _Rows:
    """Non-blank lines taken from line_blocks a chunk at a time."""

    def __init__(self, blocks: Iterator[tuple[int, list[bytes]]]):
        self.blocks = blocks
        self.first = 1
        self.lines: list[bytes] = []
        self.pos = 0

    def take(self, most: int) -> tuple[np.ndarray, list[bytes]]:
        """(line numbers, lines) of up to `most` non-blank lines; none only at the end of the file."""
        while True:
            while self.pos >= len(self.lines):
                block = next(self.blocks, None)
                if block is None:
                    return np.zeros(0, np.int64), []
                (self.first, self.lines), self.pos = block, 0
            chunk = self.lines[self.pos : self.pos + most]
            text = b"\n".join(chunk)
            blank = not text or text[0] in _SPACE_BYTES or any(s in text for s in _BLANK_STARTS)
            keep = np.flatnonzero(token_counts(text, len(chunk))) if blank else np.arange(len(chunk))
            numbers_ = self.first + self.pos + keep
            self.pos += len(chunk)
            if keep.size == len(chunk):
                return numbers_, chunk
            if keep.size:
                return numbers_, [chunk[k] for k in keep]


def _check_ascii_rows(path: Path, name: str, first: int, line_numbers, rows, props, columns, vertices: int):
    """Vertex indices of ASCII rows first, first+1, ... in range: parsed at once where the rows share
    one layout, else row by row (which also names a malformed row)."""
    text = b"\n".join(rows)
    tokens = token_counts(text, len(rows))
    values = numbers(text, np.int64) if np.all(tokens == tokens[0]) else None
    if values is not None and values.size == tokens.sum():
        table = values.reshape(len(rows), -1)
        idx = table[:, 1:] if isinstance(props[0][1], tuple) else table[:, columns]
        if not isinstance(props[0][1], tuple) or np.all(table[:, 0] == table.shape[1] - 1):
            bad = np.flatnonzero(((idx < 0) | (idx >= vertices)).any(axis=1))
            if bad.size:
                r = int(bad[0])
                raise _bad_index(
                    path, name, first + r, int(idx[r][(idx[r] < 0) | (idx[r] >= vertices)][0]), vertices
                )
            return
    for k, (number, line) in enumerate(zip(line_numbers.tolist(), rows, strict=True)):
        tokens = line.split()
        try:
            if isinstance(props[0][1], tuple):
                values = [int(t) for t in tokens[1 : 1 + int(tokens[0])]]
            else:
                values = [int(tokens[c]) for c in columns]
        except (ValueError, IndexError):
            raise ParameterError(
                f"{path}: line {number} ({name} {first + k}) does not hold integer vertex indices"
            ) from None
        bad = [v for v in values if not 0 <= v < vertices]
        if bad:
            raise _bad_index(path, name, first + k, bad[0], vertices)


def _walk_binary_ply(path: Path, offset: int, elements, fmt: str, what: str) -> int | None:
    """Walk a binary PLY element by element: fixed rows are skipped, rows with one list are read in
    chunks (assuming every list as long as the first, and checking that), face/edge indices checked.
    Returns the offset where the declared data ends, or None for layouts this walk cannot follow (more
    than one list per row, lists of varying length): their bounds were checked, Open3D parses them and
    the readers check the indices it returns."""
    order = "<" if fmt == "binary_little_endian" else ">"
    vertices = _vertex_count(elements)
    pos = offset
    with open(path, "rb") as f:
        for name, count, props in elements:
            lists = [k for k, (_, kind) in enumerate(props) if isinstance(kind, tuple)]
            columns = _index_columns(name, props)
            if count == 0:
                continue
            if len(lists) > 1:
                return None
            length = 0
            if lists:
                f.seek(pos + _row_bytes(props[: lists[0]], 0))
                count_bytes = PLY_SIZES[props[lists[0]][1][1]]
                head = f.read(count_bytes)
                if len(head) < count_bytes:
                    raise ParameterError(
                        f"{path} is not a readable {what}: it is truncated or corrupt (its data ends "
                        f"before element {name!r})"
                    )
                length = int.from_bytes(head, "little" if order == "<" else "big", signed=True)
                if length < 0:
                    return None  # a negative list length: Open3D's parser rejects the file
            if not lists and not columns:
                pos += count * _row_bytes(props, 0)
                continue
            dtype = _row_dtype(props, length, order)
            f.seek(pos)
            for start in range(0, count, _CHUNK_ROWS):
                rows = min(_CHUNK_ROWS, count - start)
                buf = f.read(rows * dtype.itemsize)
                if len(buf) < rows * dtype.itemsize:
                    return pos + count * dtype.itemsize  # truncated: the caller reports it
                table = np.frombuffer(buf, dtype)
                if lists and np.any(table["n"] != length):
                    return None  # polygons of mixed sizes
                if columns:
                    idx = np.stack([table[f"p{k}"].reshape(rows, -1) for k in columns], axis=1)
                    idx = idx.reshape(rows, -1).astype(np.int64)
                    bad = np.flatnonzero(((idx < 0) | (idx >= vertices)).any(axis=1))
                    if bad.size:
                        row = int(bad[0])
                        index = int(idx[row][(idx[row] < 0) | (idx[row] >= vertices)][0])
                        raise _bad_index(path, name, start + row, index, vertices)
            pos += count * dtype.itemsize
    return pos


def _row_dtype(props, length: int, order: str) -> np.dtype:
    fields = []
    for k, (_, kind) in enumerate(props):
        if isinstance(kind, tuple):
            fields.append(("n", order + _PLY_NUMPY[kind[1]]))
            fields.append((f"p{k}", order + _PLY_NUMPY[kind[2]], (length,)))
        else:
            fields.append((f"p{k}", order + _PLY_NUMPY[kind]))
    return np.dtype(fields)


# ----------------------------------------------------------------------------------------------- PCD


def check_pcd(path: Path, size: int, what: str) -> None:
    """POINTS against the data size (binary both ways, ASCII at least 2 bytes per value), bounded text."""
    parsed = pcd_header(path)
    if parsed is None:
        raise ParameterError(
            f"{path} is not a readable {what}: it is truncated or corrupt (no valid PCD header)"
        )
    fields, offset = parsed
    try:
        points, data_kind, row, values = pcd_layout(fields)
    except (KeyError, IndexError, ValueError):
        raise ParameterError(f"{path} is not a readable {what}: a malformed PCD header") from None
    if points < 0 or row <= 0:
        raise ParameterError(f"{path} is not a readable {what}: a malformed PCD header (POINTS {points})")
    data = size - offset
    declared = f"{points} points"
    if data_kind == "ascii":
        if points * 2 * values > data:
            raise _lying(path, what, declared, points * 2 * values, data)
        validate.capacity(f"{path}: POINTS", points, bytes_each=16 * values, unit="points")
        with open(path, "rb") as f:
            f.seek(offset)
            rows = 0
            for _, text in bounded_lines(f, path, _count_lines(path, offset)):
                rows += bool(text.strip())
                if rows >= points:
                    return
        if rows < points:
            raise _lying(path, what, declared, points, rows)
    elif data_kind == "binary":
        need = points * row
        if need > data:
            raise _lying(path, what, declared, need, data)
        if data - need > need + TRAILING_SLACK:
            raise _lying(path, what, declared, need, data, more=False)
        validate.capacity(f"{path}: POINTS", points, bytes_each=16 * values, unit="points")
    elif data_kind == "binary_compressed":
        with open(path, "rb") as f:
            f.seek(offset)
            head = f.read(8)
        if len(head) < 8:
            raise _lying(path, what, declared, 8, data)
        packed, unpacked = int.from_bytes(head[:4], "little"), int.from_bytes(head[4:], "little")
        if unpacked != points * row or packed + 8 > data:
            raise ParameterError(
                f"{path} is not a readable {what}: it is truncated or corrupt (its header declares "
                f"{declared} of {row} bytes = {points * row} bytes; the compressed block says {unpacked} "
                f"bytes, packed into {packed}, and the file holds {data - 8})"
            )
        validate.capacity(f"{path}: POINTS", points, bytes_each=16 * values, unit="points")


def _count_lines(path: Path, offset: int) -> int:
    with open(path, "rb") as f:
        return f.read(offset).count(b"\n")


def check_indices(path: Path, name: str, indices: np.ndarray, vertices: int) -> None:
    """Raise for the first row of (M,k) `indices` (a reader's faces or lines) outside [0, vertices)."""
    if indices.size == 0:
        return
    bad = np.flatnonzero(((indices < 0) | (indices >= vertices)).any(axis=1))
    if bad.size:
        row = int(bad[0])
        index = int(indices[row][(indices[row] < 0) | (indices[row] >= vertices)][0])
        raise _bad_index(path, name, row, index, vertices)
