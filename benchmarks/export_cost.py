"""Export cost per frame: PLY files (Open3D, one per item and frame) against one USD stage (usd-core:
frames collected into an in-memory stage, written once as a binary crate at the end), on four demos.

For each demo: the scene is built and stepped WARMUP frames (JIT compile and a non-trivial state), then
FRAMES frames are stepped (not timed) and after each one the frame's content items are made once
(`Scene.frame_content`, timed apart: both formats read the same items), written as PLY
(`write_items_ply`, atomic, verified complete) and added to a `UsdStageWriter`; at the end the stage is
saved (atomic, reopened to check it). Reported: ms per frame for content, PLY, USD collect, USD save
(its total over the frames, divided by FRAMES) and USD total, the USD/PLY ratio, bytes per frame of
each. A first PLY write and a first one-frame stage are made and discarded before timing (imports, first
use). Files go to a temporary folder on the local disk.

    .venv/bin/python benchmarks/export_cost.py [--quick]
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import taichi as ti
from harness import Page, init, log, parse_args

from taichi_anim.io import UsdStageWriter
from taichi_anim.scenes import make_scene
from taichi_anim.scenes.base import write_items_ply

# (demo, options): spheres at a reduced count and fewer substeps (the simulation is not what is timed).
DEMOS = (
    ("fountain", {}),
    ("spheres", {"particles": 20_000, "steps_per_frame": 40}),
    ("cloth", {}),
    ("blobs", {}),
)
WARMUP, FRAMES = 5, 30
QUICK_FRAMES = 5


def folder_bytes(folder: Path, pattern: str) -> int:
    return sum(p.stat().st_size for p in folder.glob(pattern))


def measure(name: str, options: dict, frames: int, scratch: Path) -> dict:
    scene = make_scene(name, **options)
    for _ in range(WARMUP):
        scene.advance_frame()
    warm = scratch / f"warm_{name}"
    items = scene.frame_content()
    write_items_ply(items, warm, name, 0)
    with UsdStageWriter(warm / f"{name}.usd", fps=1 / scene.frame_dt, colliders=scene.model.colliders) as w:
        w.add_frame(items, time=scene.state.time)
    out = scratch / name
    writer = UsdStageWriter(
        out / f"{name}.usd",
        fps=1.0 / scene.frame_dt,
        name=name,
        point_radius=scene.point_radius,
        colliders=scene.model.colliders,
        bounds=scene.bounds,
    )
    t = {"content": 0.0, "ply": 0.0, "usd_collect": 0.0}
    for frame in range(frames):
        scene.advance_frame()
        ti.sync()
        a = time.perf_counter()
        items = scene.frame_content()
        b = time.perf_counter()
        write_items_ply(items, out, name, frame)
        c = time.perf_counter()
        writer.add_frame(items, time=scene.state.time)
        d = time.perf_counter()
        t["content"] += b - a
        t["ply"] += c - b
        t["usd_collect"] += d - c
    a = time.perf_counter()
    writer.save()
    save = time.perf_counter() - a
    ms = {k: 1e3 * v / frames for k, v in t.items()}
    ms["usd_save"] = 1e3 * save / frames
    ms["usd"] = ms["usd_collect"] + ms["usd_save"]
    counts = {i.role: len(getattr(i, "positions", getattr(i, "vertices", getattr(i, "points", None))))
              for i in items}  # fmt: skip
    row = {
        "demo": name,
        "options": options,
        "frames": frames,
        "last_frame_items": counts,
        "ms_per_frame": ms,
        "usd_over_ply": ms["usd"] / ms["ply"],
        "ply_bytes_per_frame": folder_bytes(out, "*.ply") / frames,
        "usd_bytes_per_frame": folder_bytes(out, "*.usd") / frames,
        "usd_save_s": save,
    }
    log(f"{name}: PLY {ms['ply']:.2f} ms/frame, USD {ms['usd']:.2f} ms/frame (save {save:.2f} s)")
    return row


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    init("f32")
    frames = QUICK_FRAMES if args.quick else FRAMES
    with tempfile.TemporaryDirectory() as scratch:
        data = [measure(name, options, frames, Path(scratch)) for name, options in DEMOS]
    rows = []
    for r in data:
        m = r["ms_per_frame"]
        items = ", ".join(f"{k} {v}" for k, v in r["last_frame_items"].items())
        cols = ("content", "ply", "usd_collect", "usd_save", "usd")
        rows.append([r["demo"], items, *(f"{m[k]:.2f}" for k in cols), f"{r['usd_over_ply']:.2f}"])
        rows[-1] += [f"{r['ply_bytes_per_frame'] / 1e3:.0f}", f"{r['usd_bytes_per_frame'] / 1e3:.0f}"]
    page = Page(
        "export_cost",
        "Export cost: PLY frames against one USD stage",
        args,
        {
            "demos": ", ".join(f"{d} {o}" if o else d for d, o in DEMOS),
            "frames": f"{WARMUP} warm-up, then {frames}; per frame the content items made once, written as "
            "PLY (atomic, verified) and added to one USD stage saved once at the end (its save / frames)",
        },
    )
    page.table(
        "ms and kB per frame",
        [
            "demo",
            "items (last frame)",
            "content",
            "PLY",
            "USD collect",
            "USD save",
            "USD",
            "USD / PLY",
            "PLY kB",
            "USD kB",
        ],
        rows,
    )
    page.write(data)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
