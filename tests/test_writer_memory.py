"""Long runs keep memory bounded: the USD stage and GIF writers fed 1,000 frames of fountain-sized
content (15,000 particles with velocity, age, colour and id, 87,000 trail points, a 960 x 720 picture)
need no more memory than after 100 frames. Slow (minutes): run with `-m slow`."""

import threading

import numpy as np
import pytest

from taichi_anim.content import Lines, Points
from taichi_anim.io import UsdStageWriter
from taichi_anim.io.atomic import incomplete_reason
from taichi_anim.render import VideoWriter
from taichi_anim.render.video import video_frame_count

PARTICLES, TRAIL_POINTS = 15_000, 87_000  # the fountain demo's content per frame in steady state


def fountain_like(k: int, rng) -> list:
    """Frame k: fresh values every frame (a crate file would store repeated arrays only once)."""
    x = rng.random((PARTICLES, 3), dtype=np.float32)
    trail = rng.random((TRAIL_POINTS, 3), dtype=np.float32)
    segments = np.stack([np.arange(0, TRAIL_POINTS, 2), np.arange(1, TRAIL_POINTS, 2)], axis=1)
    attributes = {"velocity": -x, "age": np.full(PARTICLES, 0.01 * k, np.float32)}
    return [
        Points(
            "", x, rng.random((PARTICLES, 3), dtype=np.float32), np.arange(PARTICLES) + k, None, attributes
        ),
        Lines("trails", trail, segments, role="trails"),
    ]


class PeakMemory:
    """The process's peak resident memory [bytes], sampled every 20 ms by a thread."""

    def __init__(self):
        psutil = pytest.importorskip("psutil")
        self.process = psutil.Process()
        self.peak = self.process.memory_info().rss
        self.done = threading.Event()
        threading.Thread(target=self._sample, daemon=True).start()

    def _sample(self):
        while not self.done.wait(0.02):
            self.peak = max(self.peak, self.process.memory_info().rss)

    def take(self) -> int:
        self.peak = max(self.peak, self.process.memory_info().rss)
        peak, self.peak = self.peak, self.process.memory_info().rss
        return peak


@pytest.mark.slow
def test_usd_and_gif_memory_after_1000_frames_is_that_after_100(tmp_path):
    """Pass: writing a .usd stage and a .gif together, the peak resident memory over frames 101-1000
    exceeds the peak over frames 1-100 by less than 100 MB (holding the frames would take ~1.9 GB of
    stage data and ~2 GB of pictures); both files are published complete with 1,000 frames."""
    rng = np.random.default_rng(0)
    h, w = 720, 960
    ramp = np.linspace(0.0, 1.0, w)[None, :, None] * np.linspace(0.3, 1.0, h)[:, None, None]
    picture = (255 * ramp * [1.0, 0.7, 0.4]).astype(np.uint8)  # a smooth picture, like a render's
    memory = PeakMemory()
    try:
        with (
            UsdStageWriter(tmp_path / "f.usd", fps=60, name="f") as stage,
            VideoWriter(tmp_path / "f.gif", fps=60) as video,
        ):
            for k in range(1, 1001):
                stage.add_frame(fountain_like(k, rng), time=k / 60)
                video.append(np.roll(picture, 8 * k, axis=1))
                if k == 100:
                    first = memory.take()
            later = memory.take()
    finally:
        memory.done.set()
    assert later - first < 100 << 20, (first >> 20, later >> 20)
    assert incomplete_reason(tmp_path / "f.usd") is None
    assert video_frame_count(tmp_path / "f.gif") == 1000
