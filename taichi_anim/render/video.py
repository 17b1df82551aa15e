"""MP4 (H.264, libx264, yuv420p) and GIF video of rendered frames, written atomically.

MP4 goes through imageio's ffmpeg plugin (the ffmpeg binary bundled by imageio-ffmpeg), frame by frame;
GIF through Pillow, all frames at once (GIF stores delays in hundredths of a second, so 30 frames/s
becomes 3 cs per frame, i.e. 33.3 frames/s, and 60 becomes 2 cs; the exact rate is in the MP4). H.264
in 4:2:0 needs even sizes: an odd one is refused (ParameterError naming `resolution`) instead of being
silently resized, or with ffmpeg's block size 1 leaving an empty file. The file is published under its
name only after the encoder closed it and its frame count read back equals the frames given."""

import contextlib
import os
from pathlib import Path

import numpy as np

from .. import validate
from ..errors import DivergenceError, OutputError, ParameterError

FORMATS = (".mp4", ".gif")


def check_resolution(resolution) -> tuple[int, int]:
    """(width, height) as ints, both even and >= 2 (ParameterError naming `resolution` otherwise)."""
    res = tuple(resolution)
    if len(res) != 2 or any(isinstance(r, bool) or int(r) != r or r < 2 or int(r) % 2 for r in res):
        raise ParameterError(
            f"resolution must be two even integers >= 2 (width, height) for video, got {resolution!r}"
        )
    return int(res[0]), int(res[1])


def video_frame_count(path: str | os.PathLike) -> int:
    """Frames in an MP4 (decoded by ffmpeg) or GIF file."""
    path = Path(path)
    if path.suffix.lower() == ".gif":
        from PIL import Image

        with Image.open(path) as im:
            return int(getattr(im, "n_frames", 1))
    import imageio_ffmpeg

    return int(imageio_ffmpeg.count_frames_and_secs(str(path))[0])


class VideoWriter:
    """Write frames ((H, W, 3) uint8, row 0 at the top) to an MP4 or GIF at `fps` frames per second.

        with VideoWriter("out/run.mp4", fps=30) as video:
            for image in images:
                video.append(image)

    path: ".mp4" or ".gif"; fps > 0 (a demo's is 1 / scene.frame_dt); quality: libx264 quality 0-10
    (imageio's scale; 8 is visually clean at a few hundred kB per second of 960 x 720 animation).
    On an exception inside the block nothing is published under `path`, except a DivergenceError: the
    frames before it are published (and the error propagates)."""

    def __init__(self, path: str | os.PathLike, *, fps: float, quality: int = 8):
        self.path = Path(path)
        self.format = self.path.suffix.lower()
        if self.format not in FORMATS:
            raise ParameterError(f"video path must end in .mp4 or .gif, got {str(path)!r}")
        self.fps = validate.positive("fps", fps)
        self.quality = validate.count("quality", quality, 0, 10)
        self.frames = 0
        self.size: tuple[int, int] | None = None  # (width, height)
        self._stack: contextlib.ExitStack | None = None
        self._tmp: Path | None = None
        self._writer = None
        self._gif: list[np.ndarray] = []

    def __enter__(self) -> "VideoWriter":
        from ..io.atomic import atomic_path

        self._stack = contextlib.ExitStack()
        self._tmp = self._stack.enter_context(atomic_path(self.path))
        return self

    def append(self, image: np.ndarray) -> None:
        """Add one frame; every frame must have the first one's size."""
        if self._stack is None:
            raise RuntimeError("VideoWriter.append outside its `with` block")
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise ParameterError(f"a video frame must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
        size = check_resolution((img.shape[1], img.shape[0]))
        if self.size is None:
            self.size = size
            if self.format == ".mp4":
                import imageio.v2 as imageio

                self._writer = imageio.get_writer(
                    str(self._tmp),
                    format="FFMPEG",
                    mode="I",
                    fps=self.fps,
                    codec="libx264",
                    pixelformat="yuv420p",
                    quality=self.quality,
                    macro_block_size=2,  # even sizes pass as they are (16 would resize them)
                    ffmpeg_log_level="error",
                )
        elif size != self.size:
            raise ParameterError(f"resolution changed within a video: {self.size} then {size}")
        if self._writer is not None:
            self._writer.append_data(np.ascontiguousarray(img))
        else:
            self._gif.append(np.ascontiguousarray(img))
        self.frames += 1

    def __exit__(self, kind, error, trace) -> bool:
        stack, self._stack = self._stack, None
        # A run that diverged keeps the video of its frames before the divergence (so it can be watched),
        # as it keeps its other outputs; the DivergenceError still propagates.
        publish = kind is None or (issubclass(kind, DivergenceError) and self.frames > 0)
        try:
            if publish:
                self._finish()
            elif self._writer is not None:
                with contextlib.suppress(Exception):
                    self._writer.close()  # stop ffmpeg; the temporary is removed below
        except BaseException as e:
            if not stack.__exit__(type(e), e, e.__traceback__):
                raise
            return False
        if publish:
            stack.__exit__(None, None, None)
            return False
        return bool(stack.__exit__(kind, error, trace))

    def _finish(self) -> None:
        if self.frames == 0:
            raise OutputError(f"cannot write {self.path}: no frames were given")
        if self._writer is not None:
            self._writer.close()
        else:
            from PIL import Image

            first, *rest = (Image.fromarray(f) for f in self._gif)
            delay_ms = 10 * max(1, round(100.0 / self.fps))  # GIF delays are whole centiseconds
            first.save(self._tmp, format="GIF", save_all=True, append_images=rest, duration=delay_ms, loop=0)
            self._gif.clear()
        written = video_frame_count(self._tmp)
        if written != self.frames:
            raise OutputError(f"cannot write {self.path}: {self.frames} frames given, {written} in the file")

    def record(self) -> dict:
        """{"path", "fps", "frames", "size": [width, height]} for run records."""
        return {"path": str(self.path), "fps": self.fps, "frames": self.frames, "size": list(self.size or ())}
