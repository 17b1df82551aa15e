"""README stills: run each demo for a short while and render one PNG of it into docs/images/<demo>.png.

Each demo runs at its default settings for the number of frames in FRAMES (a moment that shows its
point: the spheres' heap forming, the cloth's folds, the ball carrying the cloth), then its picture is
rendered by the headless renderer (`Scene.render_frame`, the demo's own camera and colouring) at
RESOLUTION and written as a palette PNG (256 colours, adaptive) to stay under ~200 KB.

    .venv/bin/python scripts/stills.py                    # every demo (the spheres take a few minutes)
    .venv/bin/python scripts/stills.py cloth flag         # some demos
    .venv/bin/python scripts/stills.py spheres --frames 8 # a quick look
"""

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import taichi_anim as ta  # noqa: E402
from taichi_anim.io.atomic import atomic_path  # noqa: E402
from taichi_anim.scenes import SCENES, make_scene  # noqa: E402

RESOLUTION = (800, 600)
# Frames to run before the still; a frame is 1/60 s (spheres: 1/30 s).
FRAMES = {
    "fountain": 90,
    "blobs": 90,
    "spheres": 14,
    "cloth": 28,
    "drape": 100,
    "flag": 90,
    "layers": 110,
    "tablecloth": 60,
    "moving_mesh": 130,
    "dominoes": 100,
    "pile": 120,
    "rigid_cloth": 42,
    "dam_break": 30,
    "pour": 60,
}


def still(name: str, frames: int, out: Path) -> Path:
    from PIL import Image

    ta.init("cpu")
    scene = make_scene(name)
    t0 = time.perf_counter()
    for _ in range(frames):
        scene.advance_frame()
    sim = time.perf_counter() - t0
    t0 = time.perf_counter()
    image = scene.render_frame(RESOLUTION)
    render = time.perf_counter() - t0
    path = out / f"{name}.png"
    with atomic_path(path) as tmp:
        Image.fromarray(image).quantize(256, method=Image.Quantize.MEDIANCUT).save(tmp, optimize=True)
    print(
        f"{name}: {frames} frames in {sim:.1f} s, render {render * 1e3:.0f} ms, {path} "
        f"({path.stat().st_size / 1024:.0f} kB)",
        flush=True,
    )
    return path


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("demos", nargs="*", default=list(SCENES), help="demos (default: all)")
    p.add_argument("--frames", type=int, default=None, help="frames for every demo (default: FRAMES)")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = p.parse_args(argv)
    for name in args.demos:
        still(name, args.frames or FRAMES[name], args.out)


if __name__ == "__main__":
    main()
