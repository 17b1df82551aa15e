"""A bounded, checking scan of OBJ files before Open3D reads them (read_guard's rules for OBJ).

Lines are read in blocks with read_guard.line_blocks (none longer than 1 MiB); every line must start
with a known keyword; vertices are three numbers; every face corner `v`, `v/vt`, `v//vn` or `v/vt/vn`
must refer to an existing vertex, texture coordinate and normal. OBJ indices start at 1, a negative
index counts back from the last element defined before the face (-1 is the last), and 0 is invalid.
References to elements defined later in the file are allowed, as most readers allow them, and checked
against the whole file. Faces and vertices are parsed a block at a time with NumPy; a block whose
lines do not share one layout, or that holds an error, is re-read line by line to name the line.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .. import validate
from ..errors import ParameterError
from .read_guard import line_blocks, numbers, regular_file, token_counts, token_starts

_KEYWORDS = frozenset({b"v", b"vn", b"vt", b"vp", b"f", b"l", b"p", b"o", b"g", b"s", b"mtllib", b"usemtl"})
KINDS = (b"v", b"vt", b"vn")  # what the fields of a face corner `v/vt/vn` refer to, in order
_NAMES = {b"v": "vertex", b"vt": "texture coordinate", b"vn": "normal"}
_PLURALS = {b"v": "vertices", b"vt": "texture coordinates", b"vn": "normals"}
_ABSENT = np.iinfo(np.int64).max  # stands for the empty field of `1//3`
_CODES = {b"v": 1, b"vt": 2, b"vn": 3, b"f": 4}
_SPACES = list(b" \t\n\r\v\f")


class ObjScan:
    """What scan_obj found: counts {b"v", b"vt", b"vn", b"f": lines}, and for a file without faces
    its vertices (V,3) float64 (else None: Open3D reads them)."""

    def __init__(self, counts: dict[bytes, int], vertices: np.ndarray | None):
        self.counts = counts
        self.vertices = vertices


def scan_obj(path: str | os.PathLike, what: str = "triangle mesh") -> ObjScan:
    """Scan an OBJ file by the rules of the module docstring; ParameterError names the file, the line,
    the face and the index of the first problem."""
    path, _ = regular_file(path, what)
    counts = dict.fromkeys((*KINDS, b"f"), 0)
    forward = dict.fromkeys(KINDS, 0)  # largest index beyond what was defined before its face
    misread = None  # the first line Open3D's reader would get wrong
    with open(path, "rb") as fh:
        for first, lines in line_blocks(fh, path):
            codes, odd = _line_codes(path, first, lines)
            if odd is not None and misread is None:
                misread = (first + odd, lines[odd].strip()[:60].decode("utf-8", "replace"))
            rows = {key: np.flatnonzero(codes == code) for key, code in _CODES.items()}
            if rows[b"f"].size:
                known = {k: counts[k] + np.searchsorted(rows[k], rows[b"f"]) for k in KINDS}
                _faces(path, first, counts[b"f"], rows[b"f"], lines, known, forward)
            for key in counts:
                counts[key] += int(rows[key].size)
    for kind, largest in forward.items():
        if largest > counts[kind]:
            _find_forward(path, kind, counts[kind])
    if misread is not None and counts[b"f"]:
        raise ParameterError(
            f"{path}: line {misread[0]} ({misread[1]!r}) cannot be read: Open3D's OBJ reader turns line "
            "('l') and point ('p') elements into broken triangles and skips indented lines; remove "
            "them, unindent, or convert the mesh to PLY"
        )
    for kind, n in counts.items():
        validate.capacity(str(path), n, bytes_each=0, unit=f"'{kind.decode()}' lines")
    # Open3D's tensors and the arrays returned: ~80 bytes per vertex and 60 per face, at most.
    validate.memory_fits(str(path), 80 * counts[b"v"] + 60 * counts[b"f"], "its vertices and faces")
    return ObjScan(counts, None if counts[b"f"] else _all_vertices(path))


def _all_vertices(path: Path) -> np.ndarray:
    """(V,3) positions of every vertex line (a second pass, for files without faces)."""
    coords = [np.zeros((0, 3))]
    with open(path, "rb") as fh:
        for first, lines in line_blocks(fh, path):
            rows = np.flatnonzero(_line_codes(path, first, lines)[0] == _CODES[b"v"])
            if rows.size:
                coords.append(_vertices(path, first, rows, _rests(lines, rows)))
    return np.concatenate(coords)


def _line_codes(path: Path, first: int, lines: list[bytes]) -> tuple[np.ndarray, int | None]:
    """(per line: _CODES[keyword] for v, vt, vn and f lines, 0 for the others (comments, blank, other
    keywords); the first line Open3D misreads (an `l` or `p` element, an indented element) or None).
    Raises at an unknown keyword. Lines that start with their keyword are told apart by their first
    three bytes at once; the rest (indented, long keywords) one by one."""
    b = np.frombuffer(b"\n".join(lines) + b"\n\n\n", np.uint8)
    starts = np.concatenate([[0], np.flatnonzero(b[:-3] == 10) + 1])
    c0, c1, c2 = b[starts], b[starts + 1], b[starts + 2]
    gap1, gap2 = np.isin(c1, _SPACES), np.isin(c2, _SPACES)
    codes = np.full(len(lines), -1, np.int8)
    codes[(c0 == ord("v")) & gap1] = _CODES[b"v"]
    codes[(c0 == ord("v")) & (c1 == ord("t")) & gap2] = _CODES[b"vt"]
    codes[(c0 == ord("v")) & (c1 == ord("n")) & gap2] = _CODES[b"vn"]
    codes[(c0 == ord("f")) & gap1] = _CODES[b"f"]
    elements = np.isin(c0, list(b"lp")) & gap1
    codes[
        (c0 == ord("#"))
        | elements
        | (np.isin(c0, list(b"osg")) & gap1)
        | ((c0 == ord("v")) & (c1 == ord("p")) & gap2)
    ] = 0
    odd = [int(np.argmax(elements))] if elements.any() else []
    for k in np.flatnonzero(codes < 0).tolist():
        key = lines[k].split(None, 1)[:1]
        if not key or key[0].startswith(b"#"):
            codes[k] = 0
        elif key[0] in _KEYWORDS:
            codes[k] = _CODES.get(key[0], 0)
            if key[0] in (*_CODES, b"l", b"p") and lines[k][:1].isspace():
                odd.append(k)
        else:
            shown = lines[k].strip()[:60].decode("utf-8", "replace")
            raise ParameterError(f"{path} is not an OBJ file: unexpected line {first + k} {shown!r}")
    return codes, min(odd, default=None)


def _rests(lines: list[bytes], rows: np.ndarray) -> list[bytes]:
    """The lines `rows` after their one-letter keyword (`v` or `f`), indented or not."""
    return [
        line[1:] if line[:1] in (b"v", b"f") else (line.split(None, 1) + [b""])[1]
        for line in (lines[i] for i in rows.tolist())
    ]


def _vertices(path: Path, first: int, rows: np.ndarray, texts: list[bytes]) -> np.ndarray:
    """(n,3) positions of the vertex lines `texts` (lines first + rows), `x y z` and anything after."""
    text = b"\n".join(texts)
    tokens = token_counts(text, len(texts))
    if tokens.min() >= 3 and np.all(tokens == tokens[0]):
        values = numbers(text, np.float64)
        if values is not None and values.size == tokens.sum():
            return values.reshape(len(texts), -1)[:, :3]
    out = np.zeros((len(texts), 3))
    for k, line in enumerate(texts):
        parts = line.split()
        try:
            if len(parts) < 3:
                raise ValueError
            out[k] = [float(t) for t in parts[:3]]
        except ValueError:
            raise ParameterError(
                f"{path}: line {first + int(rows[k])}: a vertex needs three numbers x y z, got "
                f"{line.strip()[:60].decode('utf-8', 'replace')!r}"
            ) from None
    return out


def _faces(path: Path, first: int, face0: int, rows: np.ndarray, lines: list[bytes], known, forward) -> None:
    """Check the face lines `rows` of the block `lines` (line first + row, faces face0 + 1, ...);
    `known[kind]` holds how many elements of each kind were defined before each face. Updates
    `forward`."""
    text = b"\n".join([lines[i] for i in rows.tolist()])
    if text[:1] == b"f" and text.count(b"\nf") == rows.size - 1:  # every line starts with its `f`
        text = b" " + text[1:].replace(b"\nf", b"\n ")
    else:
        text = b"\n".join(_rests(lines, rows))
    fields = _corner_fields(text, rows.size)
    if fields is not None:
        corners, table = fields
        ok = True
        for j, kind in enumerate(KINDS[: table.shape[1]]):
            col = table[:, j]
            have = np.repeat(known[kind], corners)
            present = col != _ABSENT
            bad = present & ((col == 0) | ((col < 0) & (have + col < 0)))
            if bad.any():
                ok = False
                break
            beyond = present & (col > have)
            if beyond.any():
                forward[kind] = max(forward[kind], int(col[beyond].max()))
        if ok:
            return
    # An unusual layout or an error: line by line, to name it.
    for k, text in enumerate(_rests(lines, rows)):
        have = {kind: int(known[kind][k]) for kind in KINDS}
        _face(path, first + int(rows[k]), face0 + k + 1, text.split(), have, forward)


def _corner_fields(text: bytes, faces: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(corners per face (F,), the fields of every corner (C, k) int64, _ABSENT for an empty one) of
    the face lines `text` (keywords removed) when every face has at least 3 corners and every corner
    the same k <= 3 fields; else None."""
    b, starts = token_starts(text)
    corners = np.bincount(np.searchsorted(np.flatnonzero(b == 10), starts), minlength=faces)
    if corners.size != faces or corners.min() < 3:
        return None
    width = 1
    slashes = np.flatnonzero(b == ord("/"))
    if slashes.size:
        per_corner = np.bincount(np.searchsorted(starts, slashes, side="right") - 1, minlength=starts.size)
        width = int(per_corner[0]) + 1
        if width > 3 or np.any(per_corner != width - 1):
            return None
        text = text.replace(b"//", b"/%d/" % _ABSENT).replace(b"/", b" ")
    values = numbers(text, np.int64)
    if values is None or values.size != int(corners.sum()) * width:
        return None
    return corners, values.reshape(-1, width)


def _face(path: Path, number: int, face: int, corners: list[bytes], have: dict, forward: dict) -> None:
    """Check one face line's corners (slow path); raise for the first bad one."""
    if len(corners) < 3:
        raise ParameterError(
            f"{path}: face {face} (line {number}) has {len(corners)} corners; a face needs 3"
        )
    for corner in corners:
        for kind, token in zip(KINDS, corner.split(b"/"), strict=False):
            if not token and kind != b"v":
                continue  # `1//3`: no texture coordinate
            try:
                index = int(token)
            except ValueError:
                raise ParameterError(
                    f"{path}: face {face} (line {number}) has a corner {corner.decode('ascii', 'replace')!r} "
                    "that is not an index"
                ) from None
            if index > 0:
                if index > have[kind]:  # a forward reference: checked against the whole file at the end
                    forward[kind] = max(forward[kind], index)
                continue
            if index < 0 and have[kind] + index >= 0:
                continue
            name = _NAMES[kind]
            raise ParameterError(
                f"{path}: face {face} (line {number}) has {name} index {index}, which refers to no {name}: "
                f"{have[kind]} defined before it (OBJ indices start at 1; -1 is the last one defined)"
            )


def _find_forward(path: Path, kind: bytes, total: int) -> None:
    """Raise for the first face with a `kind` index beyond the file's `total` (a second, rare pass)."""
    face, position = 0, KINDS.index(kind)
    with open(path, "rb") as fh:
        for first, lines in line_blocks(fh, path):
            for number, text in enumerate(lines, first):
                parts = text.split()
                if parts[:1] != [b"f"]:
                    continue
                face += 1
                for corner in parts[1:]:
                    tokens = corner.split(b"/")
                    if len(tokens) > position and tokens[position] and int(tokens[position]) > total:
                        index, name = int(tokens[position]), _NAMES[kind]
                        raise ParameterError(
                            f"{path}: face {face} (line {number}) has {name} index {index}, outside "
                            f"1..{total} (the file has {total} {_PLURALS[kind]})"
                        )
