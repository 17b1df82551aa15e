"""USD export: one animated stage per run, written with usd-core (Pixar's OpenUSD) through UsdGeom's
schemas: Points (particles, hard spheres), Mesh (cloth, blob surfaces, colliders), BasisCurves (trails,
guides, container edges), Xformable ops (moving colliders: translate + orient) and the stage metadata of
the UsdGeom "Stage Metrics" (upAxis Y, metersPerUnit 1) and of Usd.Stage (timeCodesPerSecond =
framesPerSecond = the frame rate, startTimeCode / endTimeCode, defaultPrim /World).

Time: a frame at simulated time t [s] is authored at time code t * fps, so with a run's frames at
t = (k + 1) / fps, PLY frame k is time code k + 1 (Blender's first frame is 1). Values that do not change
(a static collider, a cloth's triangles) are authored once as default values, without time samples;
what changes is time-sampled. Prims: `/World/<scene>[_<item>]` for the frame's items
(scenes/content.py), `/World/colliders/<kind><k>` for the model's colliders.

The stage is collected in memory and written once, at `save()`, to a temporary beside the target that
is checked (reopened, its last time sample against endTimeCode) before it is renamed (io/atomic.py):
a reader never sees a half-written stage.
"""

from __future__ import annotations

import errno
import math
import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .. import validate
from ..errors import OutputError, ParameterError
from .atomic import atomic_path, output_error
from .export import area_weighted_normals

USD_EXTENSIONS = (".usd", ".usdc", ".usda")
LAYER_KEY = "taichi_anim"  # customLayerData entry the completeness check reads (atomic.usd_problem)
GUIDE_WIDTH = 0.003  # [m] width of guide curves and container edges
COLLIDER_COLOR = (0.55, 0.58, 0.62)  # the grey the renderer draws props in
PLANE_HALF_SIZE = 1.0  # [m] half side of the square drawn for a plane collider without scene bounds


class UsdStageWriter:
    """Collects frames into one USD stage and writes it atomically at `save()` (or at the end of a
    `with` block; after an exception the frames collected so far are saved).

    path: the stage file (`.usd` binary crate, `.usdc`, or `.usda` text); fps: frames per second, also
    the time codes per second; name: prefix of the item prims (default: the file's stem);
    point_radius [m]: width / 2 of particles whose item has no radii; colliders: the model's colliders
    (`model.colliders`), written under /World/colliders (content items of role "collider" are then
    skipped: they draw the same colliders); bounds: (lo, hi) [m], the region a plane collider's square
    covers. Units: metres and seconds; Y up."""

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        fps: float,
        name: str | None = None,
        point_radius: float = 0.01,
        colliders: Iterable = (),
        bounds=None,
    ):
        from pxr import Tf, Usd, UsdGeom

        self.path = Path(path)
        if self.path.suffix.lower() not in USD_EXTENSIONS:
            raise ParameterError(f"path must end in one of {', '.join(USD_EXTENSIONS)}, got {str(path)!r}")
        self.fps = validate.positive("fps", fps)
        self.point_radius = validate.positive("point_radius", point_radius)
        self.name = Tf.MakeValidIdentifier(name or self.path.stem)
        self.bounds = None if bounds is None else tuple(np.asarray(b, dtype=float) for b in bounds)
        self.colliders = list(colliders)
        self.codes: list[float] = []
        self.times: list[float] = []
        self.saved = False
        self._seen: dict[str, float] = {}  # prim path -> the first time code it was authored at
        stage = Usd.Stage.CreateInMemory()
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        self.stage = stage

    # ------------------------------------------------------------------------------------------ frames

    def time_code(self, time: float) -> float:
        """The time code of simulated time `time` [s]: time * fps, snapped to the nearest integer when
        within 1e-6 of it (accumulated dt leaves 2.9999999 frames)."""
        code = float(time) * self.fps
        near = round(code)
        return float(near) if abs(code - near) <= 1e-6 * max(1.0, abs(code)) else code

    def add_frame(self, items: Iterable, *, time: float) -> float:
        """Author the content items (scenes/content.py: Points, Mesh, Lines) of the frame at `time` [s];
        return its time code."""
        if self.saved:
            raise ParameterError(f"the stage {self.path} is already saved; start a new UsdStageWriter")
        from ..scenes.content import Lines, Mesh, Points

        code = self.time_code(validate.finite("time", time))
        present = set()
        for item in items:
            if isinstance(item, Mesh) and item.role == "collider" and self.colliders:
                continue
            path = "/World/" + _identifier(self.name + (f"_{item.name}" if item.name else ""))
            present.add(path)
            if isinstance(item, Points):
                self._points(path, item, code)
            elif isinstance(item, Mesh):
                self._mesh(path, item, code)
            elif isinstance(item, Lines):
                self._lines(path, item, code)
            else:
                raise ParameterError(f"items must be Points, Mesh or Lines, got {type(item).__name__}")
        self._visibility(present, code)
        self.codes.append(code)
        self.times.append(float(time))
        return code

    def _first(self, path: str, code: float) -> bool:
        """True the first time `path` is authored (remembered with its first code)."""
        if path in self._seen:
            return False
        self._seen[path] = code
        return True

    def _visibility(self, present: set, code: float) -> None:
        # An item absent from a frame (none so far in the demos) is hidden at that frame, shown again
        # when it comes back; one that appears late is hidden before it appears.
        from pxr import UsdGeom

        for path, first in self._seen.items():
            attr = UsdGeom.Imageable(self.stage.GetPrimAtPath(path)).GetVisibilityAttr()
            sampled = attr.GetNumTimeSamples() > 0
            if path not in present:
                if not sampled:
                    attr.Set(UsdGeom.Tokens.inherited, first)  # shown until now
                attr.Set(UsdGeom.Tokens.invisible, code)
            elif first == code and self.codes:  # appears after the first frame
                attr.Set(UsdGeom.Tokens.invisible, self.codes[0])
                attr.Set(UsdGeom.Tokens.inherited, code)
            elif sampled and attr.Get(code) == UsdGeom.Tokens.invisible:
                attr.Set(UsdGeom.Tokens.inherited, code)

    def _points(self, path: str, item, code: float) -> None:
        from pxr import Sdf, UsdGeom, Vt

        geom = UsdGeom.Points.Define(self.stage, path)
        x = np.asarray(item.positions, dtype=np.float32).reshape(-1, 3)
        n = len(x)
        if self._first(path, code):
            geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
            if item.radii is None:
                geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
                geom.CreateWidthsAttr().Set(Vt.FloatArray([2.0 * self.point_radius]))
            else:
                geom.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
        geom.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(x), code)
        half = self.point_radius
        if item.radii is not None:
            r = np.asarray(item.radii, dtype=np.float32).reshape(n)
            geom.GetWidthsAttr().Set(Vt.FloatArray.FromNumpy(2.0 * r), code)
            half = float(r.max()) if n else 0.0
        geom.GetIdsAttr().Set(Vt.Int64Array.FromNumpy(np.asarray(item.ids, dtype=np.int64).reshape(n)), code)
        colors = np.asarray(item.colors, dtype=np.float32).reshape(n, 3)
        geom.GetDisplayColorPrimvar().Set(Vt.Vec3fArray.FromNumpy(colors), code)
        geom.GetExtentAttr().Set(_extent(x, half), code)
        primvars = UsdGeom.PrimvarsAPI(geom)
        for key, value in item.attributes.items():
            a = np.asarray(value, dtype=np.float32)
            if key == "velocity":
                geom.GetVelocitiesAttr().Set(Vt.Vec3fArray.FromNumpy(a.reshape(n, 3)), code)
                continue
            vec = a.ndim == 2 and a.shape[1] == 3
            kind = Sdf.ValueTypeNames.Float3Array if vec else Sdf.ValueTypeNames.FloatArray
            pv = primvars.GetPrimvar(_identifier(key))
            if not pv:
                pv = primvars.CreatePrimvar(_identifier(key), kind, UsdGeom.Tokens.vertex)
            data = Vt.Vec3fArray.FromNumpy(a.reshape(n, 3)) if vec else Vt.FloatArray.FromNumpy(a.reshape(n))
            pv.Set(data, code)

    def _mesh(self, path: str, item, code: float) -> None:
        from pxr import UsdGeom, Vt

        first = self._first(path, code)
        if not first and not item.animated:
            return  # a static mesh: written once
        geom = UsdGeom.Mesh.Define(self.stage, path)
        v = np.asarray(item.vertices, dtype=np.float32).reshape(-1, 3)
        f = np.asarray(item.triangles, dtype=np.int32).reshape(-1, 3)
        normals = item.normals if item.normals is not None else area_weighted_normals(v, f)
        when = code if item.animated else None  # None: the default value, no time sample
        if first:
            geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            geom.CreateDoubleSidedAttr(item.role == "cloth")  # a sheet is seen from both sides
            geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(
                Vt.Vec3fArray([tuple(float(c) for c in item.color)])
            )
        if first or not item.fixed_topology:
            topology = code if (item.animated and not item.fixed_topology) else None
            counts = Vt.IntArray.FromNumpy(np.full(len(f), 3, np.int32))
            _set(geom.GetFaceVertexCountsAttr(), counts, topology)
            _set(geom.GetFaceVertexIndicesAttr(), Vt.IntArray.FromNumpy(f.reshape(-1)), topology)
        _set(geom.GetPointsAttr(), Vt.Vec3fArray.FromNumpy(v), when)
        _set(geom.GetNormalsAttr(), Vt.Vec3fArray.FromNumpy(np.asarray(normals, np.float32)), when)
        _set(geom.GetExtentAttr(), _extent(v, 0.0), when)

    def _lines(self, path: str, item, code: float) -> None:
        from pxr import UsdGeom

        guide = item.role == "guide"
        first = self._first(path, code)
        if guide and not first:
            return  # guides (box edges, poles) do not move: written once
        geom = _curves(self.stage, path, item.color)
        if first:
            # Guides are context, not content: purpose "guide" (hidden unless a viewer shows guides).
            geom.CreatePurposeAttr(UsdGeom.Tokens.guide if guide else UsdGeom.Tokens.default_)
            geom.CreateWidthsAttr([GUIDE_WIDTH if guide else self.point_radius])
            geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        _curve_points(geom, item.points, item.segments, None if guide else code)

    # --------------------------------------------------------------------------------------- colliders

    def _author_colliders(self) -> None:
        from pxr import UsdGeom

        if not self.colliders:
            return
        UsdGeom.Scope.Define(self.stage, "/World/colliders")
        for k, (kind, collider, shape) in enumerate(collider_shapes(self.colliders, self.bounds)):
            path = f"/World/colliders/{kind}{k}"
            if kind == "container":
                lo, hi = shape
                begin, end = _box_edges(lo, hi)
                points = np.vstack([begin, end])
                segments = np.stack([np.arange(12), np.arange(12) + 12], axis=1)
                geom = _curves(self.stage, path, COLLIDER_COLOR)
                geom.CreateWidthsAttr([GUIDE_WIDTH])
                geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
                _curve_points(geom, points, segments, None)
            else:
                vertices, faces = shape
                self._collider_mesh(path, collider, vertices, faces)
            prim = self.stage.GetPrimAtPath(path)
            prim.SetCustomDataByKey(
                "taichi_anim:collider",
                {
                    "kind": kind,
                    "restitution": float(collider.restitution),
                    "friction": float(collider.friction),
                },
            )
            motion = getattr(collider, "motion", None)
            if motion is not None:
                self._rigid_motion(prim, motion)

    def _collider_mesh(self, path, collider, vertices, faces) -> None:
        from pxr import UsdGeom, Vt

        geom = UsdGeom.Mesh.Define(self.stage, path)
        faces = np.asarray(faces, dtype=np.int32)
        counts = np.full(len(faces), faces.shape[1], np.int32)
        geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts))
        geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
        geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([COLLIDER_COLOR]))
        frames = getattr(collider, "frames", None)
        if frames is None:
            v = np.asarray(vertices, dtype=np.float32)
            geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(v))
            geom.CreateExtentAttr(_extent(v, 0.0))
            return
        for t, code in zip(self.times, self.codes, strict=True):  # a deforming mesh: its vertices now
            v = _interpolate_frames(frames, t).astype(np.float32)
            geom.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(v), code)
            geom.GetExtentAttr().Set(_extent(v, 0.0), code)

    def _rigid_motion(self, prim, motion) -> None:
        from pxr import Gf, UsdGeom

        xf = UsdGeom.Xformable(prim)
        translate = xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble)
        orient = xf.AddOrientOp(UsdGeom.XformOp.PrecisionDouble)
        for t, code in zip(self.times, self.codes, strict=True):
            r, tr = motion.pose(t)
            # Gf matrices act on row vectors (p' = p M): the rotation's matrix there is R^T.
            q = Gf.Matrix3d(*np.asarray(r, dtype=float).T.reshape(-1)).ExtractRotation().GetQuat()
            translate.Set(Gf.Vec3d(*map(float, tr)), code)
            orient.Set(q, code)

    # ------------------------------------------------------------------------------------------ saving

    def save(self) -> Path:
        """Write the stage to `path` (atomically; OutputError naming the path if it cannot be written)
        and return the path. Later calls do nothing."""
        if self.saved:
            return self.path
        self.saved = True
        self._author_colliders()
        stage = self.stage
        if self.codes:
            stage.SetStartTimeCode(min(self.codes))
            stage.SetEndTimeCode(max(self.codes))
        layer = stage.GetRootLayer()
        prims = sum(1 for _ in stage.Traverse())
        layer.customLayerData = {LAYER_KEY: {"frames": len(set(self.codes)), "prims": prims}}
        fmt = "usda" if self.path.suffix.lower() == ".usda" else "usdc"
        from pxr import Tf

        with atomic_path(self.path) as tmp:
            try:
                ok = layer.Export(str(tmp), args={"format": fmt})
            except Tf.ErrorException as e:
                raise _write_error(self.path, str(e)) from None
            if not ok:
                raise OutputError(f"cannot write {self.path}: the USD writer reported a failure")
        return self.path

    close = save

    def __enter__(self) -> UsdStageWriter:
        return self

    def __exit__(self, kind, error, trace) -> bool:
        if error is None:
            self.save()
        elif self.codes and not self.saved:
            # Keep the frames before the failure (a diverged run's good frames), as the PLY frames are.
            try:
                self.save()
            except OutputError as e:
                error.add_note(f"the USD stage could not be saved: {e}")
        return False


def write_usd(path: str | os.PathLike, frames: Iterable, *, fps: float, **options) -> Path:
    """Write a USD stage from `frames`, an iterable of (time [s], items) with items the content list of
    that instant (scenes/content.py; a Scene's frame_content()); options as for UsdStageWriter
    (name, point_radius [m], colliders, bounds). Returns the path."""
    with UsdStageWriter(path, fps=fps, **options) as writer:
        for time, items in frames:
            writer.add_frame(items, time=time)
    return writer.path


# ------------------------------------------------------------------------------------------- geometry


def collider_shapes(colliders, bounds=None) -> list[tuple[str, object, tuple]]:
    """[(kind, collider, shape)] in the collider's own frame: "container" (lo, hi) for six planes added
    by one add_collider_box (solid=False), "plane" / "box" / "sphere" / "mesh" (vertices (V,3) [m],
    faces (F,k)). A plane is a square covering `bounds` (lo, hi) [m], or PLANE_HALF_SIZE without them."""
    from ..collision.colliders import ColliderPlane, ColliderSolidBox, ColliderSphere

    out, k, cs = [], 0, list(colliders)
    while k < len(cs):
        c = cs[k]
        box = _container(cs[k : k + 6])
        if box is not None:
            out.append(("container", c, box))
            k += 6
            continue
        if isinstance(c, ColliderPlane):
            out.append(("plane", c, _plane_square(np.asarray(c.n), c.offset, bounds)))
        elif isinstance(c, ColliderSolidBox):
            out.append(("box", c, _box_mesh(np.asarray(c.lo), np.asarray(c.hi))))
        elif isinstance(c, ColliderSphere):
            out.append(("sphere", c, _sphere_mesh(np.asarray(c.center), c.radius)))
        elif hasattr(c, "faces") and hasattr(c, "vertices"):
            out.append(("mesh", c, (c.vertices, c.faces)))
        k += 1
    return out


def _container(group) -> tuple | None:
    """(lo, hi) if `group` is the six inward planes add_collider_box(solid=False) adds, in its order:
    per axis +e_a at lo_a, then -e_a at -hi_a, all with one motion; else None."""
    from ..collision.colliders import ColliderPlane

    if len(group) != 6 or not all(isinstance(c, ColliderPlane) for c in group):
        return None
    if any(c.motion is not group[0].motion for c in group):
        return None
    lo, hi = np.zeros(3), np.zeros(3)
    for axis in range(3):
        a, b = group[2 * axis], group[2 * axis + 1]
        e = np.eye(3)[axis]
        if not (np.allclose(a.n, e) and np.allclose(b.n, -e)):
            return None
        lo[axis], hi[axis] = a.offset, -b.offset
    return (lo, hi) if np.all(hi > lo) else None


def _plane_square(n, offset, bounds):
    """A square (4 vertices, 1 quad facing n) on the plane n.x = offset, centred on the projection of
    the bounds' centre (or the origin), half side half the bounds' diagonal (or PLANE_HALF_SIZE)."""
    centre, half = np.zeros(3), PLANE_HALF_SIZE
    if bounds is not None:
        lo, hi = bounds
        centre, half = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    centre = centre - (centre @ n - offset) * n
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)  # u, w, n right-handed: the quad u, w, -u, -w runs counter-clockwise about n
    v = centre + half * np.array([u + w, -u + w, -u - w, u - w])
    return v, np.array([[0, 1, 2, 3]])


def _box_mesh(lo, hi):
    """The box lo..hi as 8 vertices and 6 outward-facing quads."""
    v = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    return v, np.array(faces)


def _sphere_mesh(centre, radius, rings: int = 16, segments: int = 32):
    """A UV sphere: vertices on the sphere of `radius` [m] at `centre`, outward triangles."""
    theta = np.linspace(0.0, math.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), -np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    v = np.vstack([[0.0, 1.0, 0.0], ring, [0.0, -1.0, 0.0]]) * radius + centre
    faces = []
    s = segments
    for j in range(s):
        faces.append([0, 1 + j, 1 + (j + 1) % s])
        last = 1 + (rings - 2) * s
        faces.append([len(v) - 1, last + (j + 1) % s, last + j])
        for i in range(rings - 2):
            a, b = 1 + i * s + j, 1 + i * s + (j + 1) % s
            faces += [[a, a + s, b + s], [a, b + s, b]]
    return v, np.array(faces)


def _box_edges(lo, hi):
    corners = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    pairs = [(i, i | 1 << k) for i in range(8) for k in range(3) if not i >> k & 1]
    return corners[[a for a, _ in pairs]], corners[[b for _, b in pairs]]


def _interpolate_frames(frames, t: float) -> np.ndarray:
    """A deforming mesh's vertices at t [s]: linear between its frames, held outside them."""
    times, x = frames
    if t <= times[0]:
        return x[0]
    if t >= times[-1]:
        return x[-1]
    k = int(np.searchsorted(times, t, side="right")) - 1
    s = (t - times[k]) / (times[k + 1] - times[k])
    return (1.0 - s) * x[k] + s * x[k + 1]


# ---------------------------------------------------------------------------------------------- helpers


def _write_error(path: Path, message: str) -> OutputError:
    """An OutputError for a Tf error raised while writing `path` ("Error in 'F' at line N in file P :
    'what'", repeated): in atomic.output_error's words where it names a known OSError (a full disk, a
    file size limit, permissions), else with its first message."""
    for number in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS):
        if os.strerror(number) in message:
            return output_error(path, OSError(number, os.strerror(number)))
    found = re.findall(r" : '([^']*)'", message)
    return OutputError(f"cannot write {path}: {found[0] if found else ' '.join(message.split())[:200]}")


def _identifier(name: str) -> str:
    from pxr import Tf

    return Tf.MakeValidIdentifier(name)


def _set(attr, value, code) -> None:
    """attr = value at time code `code`, or as its default value (no time sample) when code is None."""
    if code is None:
        attr.Set(value)
    else:
        attr.Set(value, code)


def _extent(x: np.ndarray, half: float):
    from pxr import Vt

    if not len(x):
        return Vt.Vec3fArray([(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)])
    return Vt.Vec3fArray.FromNumpy(np.stack([x.min(axis=0) - half, x.max(axis=0) + half]).astype(np.float32))


def _curves(stage, path, color):
    """A BasisCurves prim of linear curves with a constant colour (defined once)."""
    from pxr import UsdGeom, Vt

    geom = UsdGeom.BasisCurves.Define(stage, path)
    if not geom.GetTypeAttr().HasAuthoredValue():
        geom.CreateTypeAttr(UsdGeom.Tokens.linear)
        geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([tuple(map(float, color))]))
    return geom


def _curve_points(geom, points, segments, code) -> None:
    """Each segment as one linear curve of two vertices."""
    from pxr import Vt

    seg = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)[seg.reshape(-1)]
    _set(geom.GetCurveVertexCountsAttr(), Vt.IntArray.FromNumpy(np.full(len(seg), 2, np.int32)), code)
    _set(geom.GetPointsAttr(), Vt.Vec3fArray.FromNumpy(p), code)
    _set(geom.GetExtentAttr(), _extent(p, GUIDE_WIDTH), code)
