"""USD export: one animated stage per run, written with usd-core (Pixar's OpenUSD) through UsdGeom's
schemas: Points (particles, hard spheres), Mesh (cloth, blob surfaces, colliders), BasisCurves (trails,
guides, container edges), Xformable ops (moving colliders: translate + orient) and the stage metadata of
the UsdGeom "Stage Metrics" (upAxis Y, metersPerUnit 1) and of Usd.Stage (timeCodesPerSecond =
framesPerSecond = the frame rate, startTimeCode / endTimeCode, defaultPrim /World).

Time: a frame at simulated time t [s] is authored at time code t * fps, so with a run's frames at
t = (k + 1) / fps, PLY frame k is time code k + 1 (Blender's first frame is 1). Values that do not change
(a static collider, a cloth's triangles) are authored once as default values, without time samples;
what changes is time-sampled. Prims: `/World/<scene>[_<item>]` for the frame's items
(content.py), `/World/colliders/<kind><k>` for the model's colliders.

Streaming: a binary stage (.usd, .usdc) is authored straight into a crate layer on a hidden temporary
beside the target, saved every FLUSH_BYTES of frame data. usd-core writes a crate layer's new values at
the end of the file on each save and then reads them back from the file on demand, so the frames already
saved leave memory: a long run keeps a bounded amount in memory (measured: the same ~25 MB growth after
100 and after 1,000 frames of 15,000 particles) and one file, which every USD reader opens as one stage.
A text stage (.usda) is rewritten whole by each save, so it is kept in memory and written once at the end.

A frame is all or nothing: add_frame journals how to undo every value it authors before it authors it,
and a frame counts only once all of it is authored; an exception or Ctrl-C anywhere inside add_frame
undoes the frame's values (the undo steps can be repeated, so an undo cut short is finished by the next
call), leaving the stage exactly as after the previous frame. At `save()` (or at the end of a `with`
block, also after an exception) the stage's frame and prim counts go into its customLayerData, it is
saved, checked (reopened, its time samples against those counts and endTimeCode) and renamed onto the
target (io/atomic.py): a reader never sees a half-written stage.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import validate
from ..collision.colliders import check_collider
from ..content import Lines, Mesh, Points
from ..errors import OutputError, ParameterError
from .atomic import atomic_path, output_error
from .export import area_weighted_normals
from .usd_bodies import author_bodies

USD_EXTENSIONS = (".usd", ".usdc", ".usda")
LAYER_KEY = "taichi_anim"  # customLayerData entry the completeness check reads (atomic.usd_problem)
GUIDE_WIDTH = 0.003  # [m] width of guide curves and container edges
COLLIDER_COLOR = (0.55, 0.58, 0.62)  # the grey the renderer draws props in
# Frame data [bytes] authored between two saves of a binary stage: what a long run holds in memory.
FLUSH_BYTES = 32 << 20
_ABSENT = object()  # "no value was authored here before the frame" in the undo journal


@dataclass
class _FrameUndo:
    """How to take back the frame being added: the bookkeeping before it and, newest last, one entry
    per authoring step: ("prim", path) for a prim it created (removed with everything under it),
    ("property", path) for an attribute it created on an older prim, ("sample", path, code, previous)
    and ("default", path, previous) for values it overwrote (previous may be _ABSENT)."""

    frames: int
    seen: dict
    created: set = field(default_factory=set)
    steps: list = field(default_factory=list)


class UsdStageWriter:
    """Writes frames into one USD stage, published atomically at `save()` (or at the end of a `with`
    block; after an exception the frames added before it are saved).

    path: the stage file (`.usd` binary crate, `.usdc`, or `.usda` text); fps: frames per second, also
    the time codes per second; name: prefix of the item prims (default: the file's stem);
    point_radius [m]: width / 2 of particles whose item has no radii; colliders: the model's colliders
    (`model.colliders`), written under /World/colliders (content items of role "collider" are then
    skipped: they draw the same colliders); bounds: (lo, hi) [m], the region a plane collider's square
    covers. Units: metres and seconds; Y up. A binary stage streams to a hidden temporary beside `path`
    (saved every FLUSH_BYTES of frame data) so memory stays bounded; a text stage is kept in memory."""

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
        from pxr import Sdf, Tf, Usd, UsdGeom

        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in USD_EXTENSIONS:
            raise ParameterError(f"path must end in one of {', '.join(USD_EXTENSIONS)}, got {str(path)!r}")
        self.fps = validate.positive("fps", fps)
        self.point_radius = validate.positive("point_radius", point_radius)
        self.name = Tf.MakeValidIdentifier(name or self.path.stem)
        self.bounds = None if bounds is None else tuple(np.asarray(b, dtype=float) for b in bounds)
        self.colliders = list(colliders)
        self.codes: list[float] = []
        self.times: list[float] = []
        self.saved = False
        self.streaming = suffix != ".usda"  # a crate layer can be saved as it grows; text cannot
        self._seen: dict[str, float] = {}  # prim path -> the first time code it was authored at
        self._undo: _FrameUndo | None = None  # the frame being added, until it counts
        self._unsaved = 0  # bytes of frame data authored since the last save
        self._publish = contextlib.ExitStack()
        tmp = self._publish.enter_context(atomic_path(self.path))  # the name only: nothing written yet
        try:
            file_format = Sdf.FileFormat.FindByExtension(suffix[1:])
            args = {"format": "usdc"} if suffix == ".usd" else {}
            self._layer = Sdf.Layer.New(file_format, str(tmp), args)
            stage = Usd.Stage.Open(self._layer)
            UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
            UsdGeom.SetStageMetersPerUnit(stage, 1.0)
            stage.SetTimeCodesPerSecond(self.fps)
            stage.SetFramesPerSecond(self.fps)
            world = UsdGeom.Xform.Define(stage, "/World")
            stage.SetDefaultPrim(world.GetPrim())
        except BaseException:
            self._publish.close()
            raise
        self.stage = stage

    # ------------------------------------------------------------------------------------------ frames

    def time_code(self, time: float) -> float:
        """The time code of simulated time `time` [s]: time * fps, snapped to the nearest integer when
        within 1e-6 of it (accumulated dt leaves 2.9999999 frames)."""
        code = float(time) * self.fps
        near = round(code)
        return float(near) if abs(code - near) <= 1e-6 * max(1.0, abs(code)) else code

    def add_frame(self, items: Iterable, *, time: float) -> float:
        """Author the content items (content.py: Points, Mesh, Lines) of the frame at `time` [s];
        return its time code. All or nothing: on any exception (a bad item, Ctrl-C) the frame's values
        are taken back and the stage is as after the previous frame."""
        if self.saved:
            raise ParameterError(f"the stage {self.path} is already saved; start a new UsdStageWriter")
        code = self.time_code(validate.finite("time", time))
        items = list(items)
        self.rollback()  # a frame cut short earlier (an interrupt while it was being undone)
        self._undo = _FrameUndo(len(self.codes), dict(self._seen))
        try:
            present = set()
            for item in items:
                if not isinstance(item, (Points, Mesh, Lines)):
                    raise ParameterError(f"items must be Points, Mesh or Lines, got {type(item).__name__}")
                if isinstance(item, Mesh) and item.role == "collider" and self.colliders:
                    continue
                path = "/World/" + _identifier(self.name + (f"_{item.name}" if item.name else ""))
                present.add(path)
                if isinstance(item, Points):
                    self._points(path, item, code)
                elif isinstance(item, Mesh) and item.parts is not None:
                    author_bodies(self, path, item, code)  # rigid bodies: a prim per body, posed
                elif isinstance(item, Mesh):
                    self._mesh(path, item, code)
                else:
                    self._lines(path, item, code)
            self._visibility(present, code)
            self.codes.append(code)
            self.times.append(float(time))
            self._undo = None  # the frame counts from here: one store, no interrupt can split it
        except BaseException:
            self.rollback()
            raise
        self._unsaved += _frame_bytes(items)
        if self.streaming and self._unsaved >= FLUSH_BYTES:
            self._save_layer()
        return code

    def rollback(self) -> None:
        """Take back the frame being added, if add_frame was cut short (done by add_frame itself, and
        finished here when an interrupt cut the undo short too). Each step is undone before it is
        dropped and can be undone twice, so an interrupt at any point leaves it to be finished."""
        undo = self._undo
        if undo is None:
            return
        while undo.steps:
            self._undo_step(undo.steps[-1])
            undo.steps.pop()
        del self.codes[undo.frames :], self.times[undo.frames :]
        self._seen = undo.seen
        self._undo = None

    def _undo_step(self, step: tuple) -> None:
        from pxr import Sdf

        kind, path = step[0], Sdf.Path(step[1])
        if kind == "prim":
            self.stage.RemovePrim(path)
            return
        if kind == "property":
            prim, prop = self._layer.GetPrimAtPath(path.GetPrimPath()), self._layer.GetPropertyAtPath(path)
            if prim and prop:
                prim.RemoveProperty(prop)
            return
        attr = self.stage.GetAttributeAtPath(path)
        if kind == "sample":
            code, previous = step[2], step[3]
            attr.ClearAtTime(code) if previous is _ABSENT else attr.Set(previous, code)
        else:
            attr.ClearDefault() if step[2] is _ABSENT else attr.Set(step[2])

    def _define(self, schema, path: str):
        """schema.Define(stage, path), journalled: a prim this frame creates is removed on undo."""
        undo = self._undo
        if undo is not None and path not in undo.created and not self._layer.GetPrimAtPath(path):
            undo.steps.append(("prim", path))
            undo.created.add(path)
        return schema.Define(self.stage, path)

    def _new_property(self, path: str) -> None:
        """Journal an attribute about to be created on a prim (removed on undo)."""
        undo = self._undo
        if (
            undo is not None
            and path.split(".")[0] not in undo.created
            and not self._layer.GetPropertyAtPath(path)
        ):
            undo.steps.append(("property", path))

    def _put(self, attr, value, code=None) -> None:
        """attr = value at time code `code`, or as its default value (no time sample) when code is None,
        journalled so that add_frame can take it back."""
        undo = self._undo
        path = attr.GetPath()
        if undo is not None and str(path.GetPrimPath()) not in undo.created:
            spec = self._layer.GetAttributeAtPath(path)
            if not spec:
                undo.steps.append(("property", str(path)))
            elif code is None:
                undo.steps.append(("default", str(path), spec.default if spec.HasDefaultValue() else _ABSENT))
            else:
                previous = self._layer.QueryTimeSample(path, code)
                undo.steps.append(("sample", str(path), code, _ABSENT if previous is None else previous))
        if code is None:
            attr.Set(value)
        else:
            attr.Set(value, code)

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
                    self._put(attr, UsdGeom.Tokens.inherited, first)  # shown until now
                self._put(attr, UsdGeom.Tokens.invisible, code)
            elif first == code and self.codes:  # appears after the first frame
                self._put(attr, UsdGeom.Tokens.invisible, self.codes[0])
                self._put(attr, UsdGeom.Tokens.inherited, code)
            elif sampled and attr.Get(code) == UsdGeom.Tokens.invisible:
                self._put(attr, UsdGeom.Tokens.inherited, code)

    def _points(self, path: str, item, code: float) -> None:
        from pxr import Sdf, UsdGeom, Vt

        geom = self._define(UsdGeom.Points, path)
        x = np.asarray(item.positions, dtype=np.float32).reshape(-1, 3)
        n = len(x)
        if self._first(path, code):
            geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
            if item.radii is None:
                geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
                geom.CreateWidthsAttr().Set(Vt.FloatArray([2.0 * self.point_radius]))
            else:
                geom.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
        self._put(geom.GetPointsAttr(), Vt.Vec3fArray.FromNumpy(x), code)
        half = self.point_radius
        if item.radii is not None:
            r = np.asarray(item.radii, dtype=np.float32).reshape(n)
            self._put(geom.GetWidthsAttr(), Vt.FloatArray.FromNumpy(2.0 * r), code)
            half = float(r.max()) if n else 0.0
        ids = Vt.Int64Array.FromNumpy(np.asarray(item.ids, dtype=np.int64).reshape(n))
        self._put(geom.GetIdsAttr(), ids, code)
        colors = np.asarray(item.colors, dtype=np.float32).reshape(n, 3)
        self._put(geom.GetDisplayColorPrimvar().GetAttr(), Vt.Vec3fArray.FromNumpy(colors), code)
        self._put(geom.GetExtentAttr(), _extent(x, half), code)
        primvars = UsdGeom.PrimvarsAPI(geom)
        for key, value in item.attributes.items():
            a = np.asarray(value, dtype=np.float32)
            if key == "velocity":
                self._put(geom.GetVelocitiesAttr(), Vt.Vec3fArray.FromNumpy(a.reshape(n, 3)), code)
                continue
            vec = a.ndim == 2 and a.shape[1] == 3
            kind = Sdf.ValueTypeNames.Float3Array if vec else Sdf.ValueTypeNames.FloatArray
            pv = primvars.GetPrimvar(_identifier(key))
            if not pv:
                self._new_property(f"{path}.primvars:{_identifier(key)}")
                pv = primvars.CreatePrimvar(_identifier(key), kind, UsdGeom.Tokens.vertex)
            data = Vt.Vec3fArray.FromNumpy(a.reshape(n, 3)) if vec else Vt.FloatArray.FromNumpy(a.reshape(n))
            self._put(pv.GetAttr(), data, code)

    def _mesh(self, path: str, item, code: float) -> None:
        from pxr import UsdGeom, Vt

        first = self._first(path, code)
        if not first and not item.animated:
            return  # a static mesh: written once
        geom = self._define(UsdGeom.Mesh, path)
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
            self._put(geom.GetFaceVertexCountsAttr(), counts, topology)
            self._put(geom.GetFaceVertexIndicesAttr(), Vt.IntArray.FromNumpy(f.reshape(-1)), topology)
        self._put(geom.GetPointsAttr(), Vt.Vec3fArray.FromNumpy(v), when)
        self._put(geom.GetNormalsAttr(), Vt.Vec3fArray.FromNumpy(np.asarray(normals, np.float32)), when)
        self._put(geom.GetExtentAttr(), _extent(v, 0.0), when)

    def _lines(self, path: str, item, code: float) -> None:
        from pxr import UsdGeom

        guide = item.role == "guide"
        first = self._first(path, code)
        if guide and not first:
            return  # guides (box edges, poles) do not move: written once
        geom = self._curves(path, item.color)
        if first:
            # Guides are context, not content: purpose "guide" (hidden unless a viewer shows guides).
            geom.CreatePurposeAttr(UsdGeom.Tokens.guide if guide else UsdGeom.Tokens.default_)
            geom.CreateWidthsAttr([GUIDE_WIDTH if guide else self.point_radius])
            geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        self._curve_points(geom, item.points, item.segments, None if guide else code)

    def _curves(self, path, color):
        """A BasisCurves prim of linear curves with a constant colour (defined once)."""
        from pxr import UsdGeom, Vt

        geom = self._define(UsdGeom.BasisCurves, path)
        if not geom.GetTypeAttr().HasAuthoredValue():
            geom.CreateTypeAttr(UsdGeom.Tokens.linear)
            color = Vt.Vec3fArray([tuple(map(float, color))])
            geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(color)
        return geom

    def _curve_points(self, geom, points, segments, code) -> None:
        """Each segment as one linear curve of two vertices."""
        from pxr import Vt

        seg = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
        p = np.asarray(points, dtype=np.float32).reshape(-1, 3)[seg.reshape(-1)]
        counts = Vt.IntArray.FromNumpy(np.full(len(seg), 2, np.int32))
        self._put(geom.GetCurveVertexCountsAttr(), counts, code)
        self._put(geom.GetPointsAttr(), Vt.Vec3fArray.FromNumpy(p), code)
        self._put(geom.GetExtentAttr(), _extent(p, GUIDE_WIDTH), code)

    # --------------------------------------------------------------------------------------- colliders

    def _author_colliders(self) -> None:
        from pxr import UsdGeom

        if not self.colliders:
            return
        UsdGeom.Scope.Define(self.stage, "/World/colliders")
        for k, (kind, collider, shape) in enumerate(collider_shapes(self.colliders, self.bounds)):
            path = f"/World/colliders/{_identifier(kind)}{k}"
            if kind == "container":
                lo, hi = shape
                begin, end = _box_edges(lo, hi)
                points = np.vstack([begin, end])
                segments = np.stack([np.arange(12), np.arange(12) + 12], axis=1)
                geom = self._curves(path, COLLIDER_COLOR)
                geom.CreateWidthsAttr([GUIDE_WIDTH])
                geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
                self._curve_points(geom, points, segments, None)
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
        if not collider.deforming:
            v = np.asarray(vertices, dtype=np.float32)
            geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(v))
            geom.CreateExtentAttr(_extent(v, 0.0))
            return
        for t, code in zip(self.times, self.codes, strict=True):  # a deforming surface: its vertices now
            v = np.asarray(collider.surface_at(t, self.bounds), dtype=np.float64).astype(np.float32)
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

    def _save_layer(self) -> None:
        """Write what was authored to the temporary (OutputError naming the path if it cannot be)."""
        from pxr import Tf

        try:
            ok = self._layer.Save()
        except Tf.ErrorException as e:
            raise _write_error(self.path, str(e)) from None
        if not ok:
            raise OutputError(f"cannot write {self.path}: the USD writer reported a failure")
        self._unsaved = 0

    def save(self) -> Path:
        """Write the stage to `path` (atomically; OutputError naming the path if it cannot be written)
        and return the path. A frame cut short is left out. Later calls do nothing."""
        if self.saved:
            return self.path
        self.rollback()
        self.saved = True
        try:
            self._author_colliders()
            stage = self.stage
            if self.codes:
                stage.SetStartTimeCode(min(self.codes))
                stage.SetEndTimeCode(max(self.codes))
            prims = sum(1 for _ in stage.Traverse())
            self._layer.customLayerData = {LAYER_KEY: {"frames": len(set(self.codes)), "prims": prims}}
            self._save_layer()
        except BaseException as e:
            self._release()
            if not self._publish.__exit__(type(e), e, e.__traceback__):
                raise
            return self.path
        self._release()  # before the rename: a crate layer keeps its file mapped
        self._publish.close()  # check, flush and rename (OutputError if incomplete)
        return self.path

    def discard(self) -> None:
        """Drop the stage without publishing it (its temporary is removed)."""
        self.rollback()
        self.saved = True
        self._release()
        self._publish.__exit__(OutputError, OutputError("discarded"), None)

    def _release(self) -> None:
        self.stage = None
        self._layer = None

    close = save

    def __enter__(self) -> UsdStageWriter:
        return self

    def __exit__(self, kind, error, trace) -> bool:
        if error is None:
            self.save()
        elif not self.saved:
            self.rollback()
            if not self.codes:
                self.discard()
                return False
            # Keep the frames before the failure (a diverged or interrupted run's good frames), as the
            # PLY frames are.
            try:
                self.save()
            except OutputError as e:
                error.add_note(f"the USD stage could not be saved: {e}")
        return False


def write_usd(path: str | os.PathLike, frames: Iterable, *, fps: float, **options) -> Path:
    """Write a USD stage from `frames`, an iterable of (time [s], items) with items the content list of
    that instant (content.py; a Scene's frame_content()); options as for UsdStageWriter
    (name, point_radius [m], colliders, bounds). Returns the path."""
    with UsdStageWriter(path, fps=fps, **options) as writer:
        for time, items in frames:
            writer.add_frame(items, time=time)
    return writer.path


# ------------------------------------------------------------------------------------------- geometry


def collider_shapes(colliders, bounds=None) -> list[tuple[str, object, tuple]]:
    """[(kind, collider, shape)] in the collider's own frame: "container" (lo, hi) for six planes added
    by one add_collider_box (solid=False), else the collider's own `kind` ("plane", "box", "sphere",
    "mesh", or a user collider's) with its `surface(bounds)`: vertices (V,3) [m], faces (F,k). A plane is
    a square covering `bounds` (lo, hi) [m], or 1 m on a side without them. Each collider is asked,
    never its class; one that lacks the protocol raises ParameterError naming it."""
    out, k, cs = [], 0, list(colliders)
    while k < len(cs):
        c = cs[k]
        check_collider(c)
        box = _container(cs[k : k + 6])
        if box is not None:
            out.append(("container", c, box))
            k += 6
            continue
        vertices, faces = c.surface(bounds)
        out.append((str(c.kind), c, (vertices, faces)))
        k += 1
    return out


def _container(group) -> tuple | None:
    """(lo, hi) if `group` is the six inward planes add_collider_box(solid=False) adds, in its order:
    per axis +e_a at lo_a, then -e_a at -hi_a, all with one motion; else None."""
    planes = [c.half_space() for c in group]
    if len(group) != 6 or any(p is None for p in planes):
        return None
    if any(c.motion is not group[0].motion for c in group):
        return None
    lo, hi = np.zeros(3), np.zeros(3)
    for axis in range(3):
        (na, oa), (nb, ob) = planes[2 * axis], planes[2 * axis + 1]
        e = np.eye(3)[axis]
        if not (np.allclose(na, e) and np.allclose(nb, -e)):
            return None
        lo[axis], hi[axis] = oa, -ob
    return (lo, hi) if np.all(hi > lo) else None


def _box_edges(lo, hi):
    corners = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    pairs = [(i, i | 1 << k) for i in range(8) for k in range(3) if not i >> k & 1]
    return corners[[a for a, _ in pairs]], corners[[b for _, b in pairs]]


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


def _extent(x: np.ndarray, half: float):
    from pxr import Vt

    if not len(x):
        return Vt.Vec3fArray([(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)])
    return Vt.Vec3fArray.FromNumpy(np.stack([x.min(axis=0) - half, x.max(axis=0) + half]).astype(np.float32))


def _frame_bytes(items) -> int:
    """Bytes of array data in a frame's content items (what authoring it adds to the stage, roughly)."""
    total = 0
    for item in items:
        for value in [*vars(item).values(), *getattr(item, "attributes", {}).values()]:
            if isinstance(value, np.ndarray):
                total += value.nbytes
    return total
