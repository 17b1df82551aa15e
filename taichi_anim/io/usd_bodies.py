"""Rigid bodies in a USD stage: one Xform prim per body, its mesh authored once in the body's frame and
its pose time-sampled as `xformOp:translate` and `xformOp:orient` (what Blender and Houdini import as
animated objects), instead of the posed vertices of every body rewritten per frame. Called by
UsdStageWriter.add_frame for a Mesh item that carries `parts` (content.RigidParts), through the writer's
journalled helpers, so a frame cut short is taken back like any other."""

import numpy as np


def author_bodies(writer, path: str, item, code: float) -> None:
    """Author the bodies of `item` (a Mesh with parts) under `path` at time code `code`."""
    from pxr import Gf, UsdGeom, Vt

    parts = item.parts
    first = writer._first(path, code)
    if first:
        writer._define(UsdGeom.Xform, path)
    for k, (vertices, faces) in enumerate(parts.meshes):
        body = f"{path}/body_{k:04d}"
        xf = UsdGeom.Xformable(writer.stage.GetPrimAtPath(body)) if not first else None
        if first:
            xf = UsdGeom.Xformable(writer._define(UsdGeom.Xform, body).GetPrim())
            xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble)
            xf.AddOrientOp(UsdGeom.XformOp.PrecisionDouble)
            geom = writer._define(UsdGeom.Mesh, f"{body}/mesh")
            v = np.asarray(vertices, dtype=np.float32)
            f = np.asarray(faces, dtype=np.int32)
            geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(f), 3, np.int32)))
            geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(f.reshape(-1)))
            geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(v))
            geom.CreateExtentAttr(
                Vt.Vec3fArray([Gf.Vec3f(*map(float, v.min(0))), Gf.Vec3f(*map(float, v.max(0)))])
            )
            geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(
                Vt.Vec3fArray([tuple(float(c) for c in item.color)])
            )
        translate, orient = xf.GetOrderedXformOps()
        x, y, z, w = (float(c) for c in parts.orientations[k])
        writer._put(translate.GetAttr(), Gf.Vec3d(*map(float, parts.positions[k])), code)
        writer._put(orient.GetAttr(), Gf.Quatd(w, x, y, z), code)
