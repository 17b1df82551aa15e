"""Render cost per frame: the headless rasterizer (taichi_anim.render) against the earlier ti.GUI painter
(benchmarks/peers/gui_render.py) on the same frames, same camera, same resolution, in the same process.

Frames (each demo's own content items and camera, `Scene.frame_content()` / `Scene.view_camera`,
960 x 720 pixels):
- spheres: the `spheres` demo's first frame, 10^5 spheres of 6 mm (the column) and the box's edges,
  coloured by speed (its default);
- cloth: the `cloth` demo at 64 x 64 vertices after 30 frames of swinging (a folded sheet, 7,938
  triangles) and its bar;
- blobs: the `blobs` demo after 60 frames: the jet's isosurface (tens of thousands of triangles), its
  particles as balls and the box's edges.
New renderer: `render_items` (visibility buffer, per-sample ray casts, deferred shading) at 2 x 2 and
1 x 1 samples per pixel, the image only and with `write_png`; its first call, holding the JIT compile of
the four kernels, is reported apart (compile = first call - median call). Peer: the ti.GUI renderer,
flat discs of 2 px (1.5 px for the spheres, as that demo drew them), flat-shaded triangles in painter's
order, the PNG written by ti.GUI (its only output). Each figure is the median of REPEATS calls after one
warm-up call, `ti.sync()` before each clock read; float32, Taichi's default CPU threads.

    .venv/bin/python benchmarks/render_cost.py [--quick]   # --quick: 10^4 spheres, 32^2 cloth
"""

import statistics
import tempfile
from pathlib import Path

import numpy as np
from harness import Page, clock, fmt_s, init, parse_args

from taichi_anim.content import Lines, Mesh, Points
from taichi_anim.render import render_items, write_png
from taichi_anim.scenes import make_scene

RESOLUTION = (960, 720)
REPEATS = 5


def frames(quick: bool) -> list[tuple[str, object]]:
    """(name, scene at the frame to draw) for each workload."""
    spheres = make_scene("spheres", particles=10_000 if quick else 100_000)
    cloth = make_scene("cloth", resolution=32 if quick else 64)
    for _ in range(30):
        cloth.advance_frame()
    blobs = make_scene("blobs")
    for _ in range(20 if quick else 60):
        blobs.advance_frame()
    return [("spheres", spheres), ("cloth", cloth), ("blobs", blobs)]


def timed(call, repeats: int = REPEATS) -> tuple[float, float]:
    """(first call, median of `repeats` further calls) in seconds."""
    t0 = clock()
    call()
    first = clock() - t0
    times = []
    for _ in range(repeats):
        t0 = clock()
        call()
        times.append(clock() - t0)
    return first, statistics.median(times)


def old_call(items, camera, path: Path):
    """The ti.GUI peer's call for the same items: points with their colours, lines, meshes with one
    colour per item (Lambert from its headlight)."""
    from peers.gui_render import render_png as gui_png

    pts = [i for i in items if isinstance(i, Points) and len(i.positions)]
    lines = [i for i in items if isinstance(i, Lines) and len(i.segments)]
    meshes = [i for i in items if isinstance(i, Mesh) and len(i.triangles)]
    radius = 1.5 if any(p.radii is not None for p in pts) else 2.0
    kwargs = {"camera": camera, "radius_px": radius}
    if pts:
        kwargs["points"] = np.vstack([p.positions for p in pts])
        kwargs["colors"] = np.vstack([p.colors for p in pts])
    if lines:
        kwargs["lines"] = (
            np.vstack([i.points[i.segments[:, 0]] for i in lines]),
            np.vstack([i.points[i.segments[:, 1]] for i in lines]),
        )
    if meshes:
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        kwargs["triangles"] = (
            np.vstack([m.vertices for m in meshes]),
            np.vstack([m.triangles + o for m, o in zip(meshes, offsets, strict=True)]),
            np.vstack([np.tile(m.color, (len(m.triangles), 1)) for m in meshes]),
        )
    return lambda: gui_png(path, **kwargs)


def measure(name: str, scene, folder: Path) -> dict:
    items = scene.frame_content()
    camera = scene.view_camera(RESOLUTION)
    spec = scene.color_spec()
    kw = {"point_radius": scene.point_radius, "color_by": spec}
    n_sph = sum(len(i.positions) for i in items if isinstance(i, Points))
    n_tri = sum(len(i.triangles) for i in items if isinstance(i, Mesh))
    row = {"workload": name, "spheres": n_sph, "triangles": n_tri}
    first, row["new_2x2_s"] = timed(lambda: render_items(items, camera, samples=2, **kw))
    row["new_compile_s"] = max(first - row["new_2x2_s"], 0.0)
    image = render_items(items, camera, samples=2, **kw)
    _, row["png_s"] = timed(lambda: write_png(folder / f"{name}.png", image))
    _, row["new_1x1_s"] = timed(lambda: render_items(items, camera, samples=1, **kw))
    _, row["old_gui_png_s"] = timed(old_call(items, camera, folder / f"{name}_gui.png"))
    row["new_2x2_png_s"] = row["new_2x2_s"] + row["png_s"]
    row["ratio_new_png_over_old"] = row["new_2x2_png_s"] / row["old_gui_png_s"]
    return row


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    init("f32")
    with tempfile.TemporaryDirectory() as tmp:
        data = [measure(name, scene, Path(tmp)) for name, scene in frames(args.quick)]
    rows = [
        [
            r["workload"],
            f"{r['spheres']:,}",
            f"{r['triangles']:,}",
            fmt_s(r["old_gui_png_s"]),
            fmt_s(r["new_2x2_s"]),
            fmt_s(r["new_2x2_png_s"]),
            fmt_s(r["new_1x1_s"]),
            f"{r['ratio_new_png_over_old']:.2f}",
            fmt_s(r["new_compile_s"]),
        ]
        for r in data
    ]
    page = Page(
        "render_cost",
        "Render cost per frame",
        args,
        {
            "frames": "spheres demo's first frame; cloth demo (64², --quick 32²) after 30 frames; blobs",
            "image": f"{RESOLUTION[0]} x {RESOLUTION[1]} px, each demo's camera and colours, f32",
            "repeats": f"median of {REPEATS} calls after a first call (whose extra time is the compile)",
        },
    )
    page.table(
        "Per frame",
        [
            "frame",
            "spheres / points",
            "triangles",
            "ti.GUI painter, PNG included",
            "new 2x2, image",
            "new 2x2 + PNG",
            "new 1x1, image",
            "new (2x2 + PNG) / ti.GUI",
            "new: first call's extra time",
        ],
        rows,
    )
    page.write(data)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
