"""MP4 (H.264, libx264, yuv420p) and GIF video of rendered frames, streamed to the encoder and written
atomically.

Both formats go through the ffmpeg binary bundled by imageio-ffmpeg, fed one frame at a time through a
pipe, so memory stays bounded however long the run (a few frames in flight, never the whole video). A
GIF gets a 256-colour palette of its own per frame (ffmpeg's palettegen / paletteuse, no dithering:
dithering noise crawls from frame to frame) and keeps its frame delays in whole hundredths of a second:
30 frames/s becomes 3 cs per frame, i.e. 33.3 frames/s, and 60 becomes 2 cs (browsers slow delays under
2 cs down to 10 cs); the exact rate is in the MP4. H.264 in 4:2:0 needs even sizes: an odd one is
refused (ParameterError naming `resolution`) instead of being silently resized, or with ffmpeg's block
size 1 leaving an empty file.

A frame is handed whole to an encoder thread that writes it to ffmpeg's pipe: an interrupt (Ctrl-C) in
the caller's thread can stop the run between two frames but never cut a frame in half, so the encoder
always sees whole frames. ffmpeg runs in its own session, so the terminal's Ctrl-C reaches only us and
the frames before it are still encoded and published. The file is published under its name (renamed
from a hidden `.NAME.tmp-XXXXXXXX.EXT` beside it, io/atomic.py) only after ffmpeg exited cleanly and the
frame count read back equals the frames written. When ffmpeg fails (a full disk, a file size limit,
permissions), the error says why in one line (OutputError), never ffmpeg's command line."""

import collections
import contextlib
import errno
import os
import re
import signal
import subprocess
import tempfile
import threading
from fractions import Fraction
from pathlib import Path

import numpy as np

from .. import validate
from ..errors import DivergenceError, OutputError, ParameterError
from ..io.atomic import atomic_path, output_error

FORMATS = (".mp4", ".gif")
# Exceptions after which the frames written so far are still published: a diverged run (its frames up
# to the divergence are worth watching) and an interrupted one (Ctrl-C, or a stop requested by signal).
PUBLISH_ON = (DivergenceError, KeyboardInterrupt, SystemExit)
IN_FLIGHT = 2  # frames waiting for the encoder thread: bounds memory, lets rendering overlap encoding
# ffmpeg's messages for the OSErrors a user can act on (its strerror text); see io/atomic.output_error.
_KNOWN_ERRNOS = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS)


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


def gif_delay_cs(fps: float) -> int:
    """The GIF frame delay [1/100 s] for `fps` frames per second: whole centiseconds, at least 1."""
    return max(1, round(100.0 / fps))


class VideoWriter:
    """Write frames ((H, W, 3) uint8, row 0 at the top) to an MP4 or GIF at `fps` frames per second.

        with VideoWriter("out/run.mp4", fps=30) as video:
            for image in images:
                video.append(image)

    path: ".mp4" or ".gif"; fps > 0 (a demo's is 1 / scene.frame_dt); quality: libx264 quality 0-10
    (imageio's scale, crf = 51 (1 - quality / 10); 8 is visually clean at a few hundred kB per second of
    960 x 720 animation). On an exception inside the block nothing is published under `path`, except a
    DivergenceError or an interruption (PUBLISH_ON): the frames before it are published (and the error
    propagates)."""

    def __init__(self, path: str | os.PathLike, *, fps: float, quality: int = 8):
        self.path = Path(path)
        self.format = self.path.suffix.lower()
        if self.format not in FORMATS:
            raise ParameterError(f"video path must end in .mp4 or .gif, got {str(path)!r}")
        self.fps = validate.positive("fps", fps)
        self.quality = validate.count("quality", quality, 0, 10)
        self.size: tuple[int, int] | None = None  # (width, height)
        self._stack: contextlib.ExitStack | None = None
        self._tmp: Path | None = None
        self._encoder: _FfmpegEncoder | None = None

    @property
    def frames(self) -> int:
        """Frames accepted so far (each is encoded whole, or the video is not published)."""
        return 0 if self._encoder is None else self._encoder.accepted()

    def __enter__(self) -> "VideoWriter":
        self._stack = contextlib.ExitStack()
        self._tmp = self._stack.enter_context(atomic_path(self.path))
        return self

    def append(self, image: np.ndarray) -> None:
        """Add one frame; every frame must have the first one's size. OutputError if the encoder has
        stopped (a full disk, ...)."""
        if self._stack is None:
            raise RuntimeError("VideoWriter.append outside its `with` block")
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise ParameterError(f"a video frame must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
        size = check_resolution((img.shape[1], img.shape[0]))
        if self.size is None:
            assert self._tmp is not None
            self._encoder = _FfmpegEncoder(self.path, self._tmp, self._ffmpeg_output(), size, self._rate())
            self._encoder.start()
            self.size = size
        elif size != self.size:
            raise ParameterError(f"resolution changed within a video: {self.size} then {size}")
        assert self._encoder is not None
        # A copy: the caller may reuse its buffer while the encoder thread still holds this frame.
        self._encoder.put(np.array(img, order="C", copy=True))

    def _rate(self) -> Fraction:
        """ffmpeg's input frame rate: the fps, or for GIF the rate its whole-centisecond delay plays at."""
        if self.format == ".gif":
            return Fraction(100, gif_delay_cs(self.fps))
        return Fraction(self.fps).limit_denominator(1_000_000)

    def _ffmpeg_output(self) -> list[str]:
        if self.format == ".gif":
            palette = (
                "split[a][b];[a]palettegen=stats_mode=single:reserve_transparent=0[p];"
                "[b][p]paletteuse=new=1:dither=none"
            )
            return ["-vf", palette, "-loop", "0", "-f", "gif"]
        crf = int((1.0 - self.quality / 10.0) * 51)
        return ["-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", str(crf), "-f", "mp4"]

    def __exit__(self, kind, error, trace) -> bool:
        stack, self._stack = self._stack, None
        assert stack is not None
        # A run that diverged or was interrupted keeps the video of its frames before (so it can be
        # watched), as it keeps its other outputs; the exception still propagates.
        publish = kind is None or (issubclass(kind, PUBLISH_ON) and self.frames > 0)
        try:
            if publish:
                self._finish()
            elif self._encoder is not None:
                self._encoder.abort()  # stop ffmpeg; the temporary is removed below
        except BaseException as e:
            if self._encoder is not None:
                self._encoder.abort()
            if not stack.__exit__(type(e), e, e.__traceback__):
                if error is not None and e is not error:
                    e.__context__ = error
                raise
            return False
        if publish:
            stack.__exit__(None, None, None)
            return False
        return bool(stack.__exit__(kind, error, trace))

    def _finish(self) -> None:
        if self._encoder is None or self.frames == 0:
            raise OutputError(f"cannot write {self.path}: no frames were given")
        written = self._encoder.close()
        assert self._tmp is not None
        found = video_frame_count(self._tmp)
        if found != written:
            raise OutputError(f"cannot write {self.path}: {written} frames given, {found} in the file")

    def record(self) -> dict:
        """{"path", "fps", "frames", "size": [width, height]} for run records."""
        return {"path": str(self.path), "fps": self.fps, "frames": self.frames, "size": list(self.size or ())}


class _FfmpegEncoder:
    """ffmpeg reading raw RGB frames from a pipe, started, fed and stopped by a thread of its own.

    Frames are handed over whole (`put`): the thread writes each one completely before it counts it, and
    a KeyboardInterrupt is only ever raised in the main thread, so the pipe never holds part of a frame;
    nor can an interrupt leave ffmpeg running unowned, since the thread starts it and always ends it.
    At most IN_FLIGHT frames wait; `put` blocks while they do."""

    def __init__(self, path: Path, tmp: Path, output: list[str], size: tuple[int, int], rate: Fraction):
        import imageio_ffmpeg

        self.path = path  # the name the user gave (error messages name it, not the temporary)
        command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-nostats", "-v", "error"]
        command += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{size[0]}x{size[1]}", "-r", str(rate)]
        self._command = [*command, "-i", "-", "-an", *output, str(tmp)]
        self._log = tempfile.TemporaryFile()  # ffmpeg's messages: read for the cause when it fails
        self._process: subprocess.Popen | None = None
        self._waiting: collections.deque = collections.deque()
        self._lock = threading.Lock()
        self._wake = threading.Semaphore(0)
        self._space = threading.Semaphore(IN_FLIGHT)
        self._taken = 0  # frames the thread took from _waiting (under _lock)
        self.written = 0  # frames written to the pipe completely
        self._error: BaseException | None = None
        self._stop = False  # no more frames: end the stream
        self._abort = False  # discard the video: kill ffmpeg
        self._ended = threading.Event()  # ffmpeg has exited
        self._thread = threading.Thread(target=self._run, name="video-encoder", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def accepted(self) -> int:
        with self._lock:
            return self._taken + len(self._waiting)

    def put(self, frame: np.ndarray) -> None:
        while not self._space.acquire(timeout=0.1):
            self._raise_if_failed()
        self._raise_if_failed()
        # The handover is this one append: an interrupt lands before it (frame not given) or after it
        # (frame given, and counted by accepted()), never in between.
        self._waiting.append(frame)
        self._wake.release()

    def _run(self) -> None:
        try:
            # Its own session: the terminal's Ctrl-C (and hang-up) reaches only this process, which then
            # finishes the file with the frames before the interrupt.
            self._process = subprocess.Popen(
                self._command,
                stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL,
                stderr=self._log,
                start_new_session=True,
            )
        except BaseException as e:  # noqa: BLE001 - reported to the main thread
            self._error = e
        try:
            self._feed()
        finally:
            self._end()

    def _feed(self) -> None:
        while True:
            self._wake.acquire()
            while not self._abort:
                with self._lock:
                    if not self._waiting:
                        break
                    frame = self._waiting.popleft()
                    self._taken += 1
                self._space.release()
                if self._error is None:
                    try:
                        self._write(self._process.stdin, frame)  # type: ignore[union-attr]
                        self.written += 1
                    except BaseException as e:  # noqa: BLE001 - reported to the main thread
                        self._error = e
                        self._end()  # its exit status and last message tell the cause
            if self._stop or self._abort:
                return

    def _write(self, stdin, frame: np.ndarray) -> None:
        stdin.write(memoryview(frame).cast("B"))

    def _close_input(self) -> None:
        if self._process is not None:
            try:
                self._process.stdin.close()  # type: ignore[union-attr]
            except OSError as e:
                self._error = self._error or e

    def _end(self) -> None:
        """End ffmpeg: its input closed (it finishes the file), or killed when aborting; wait for it."""
        process = self._process
        if process is not None and process.returncode is None:
            if self._abort:
                process.kill()
            else:
                self._close_input()
            process.wait()
        self._ended.set()

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            self._ended.wait(timeout=10.0)  # ffmpeg's exit status and last message tell the cause
            raise self._failure(self._error) from None

    def close(self) -> int:
        """Write what waits, end the stream and wait for ffmpeg; return the frames written, or raise
        OutputError saying why the video could not be written."""
        self._stop = True
        self._wake.release()
        self._thread.join()
        code = None if self._process is None else self._process.returncode
        if self._error is not None or code != 0:
            raise self._failure(self._error)
        return self.written

    def abort(self) -> None:
        """Stop ffmpeg now (what it wrote is discarded with the temporary)."""
        self._abort = True
        self._wake.release()
        process = self._process
        if process is not None:
            with contextlib.suppress(OSError):
                process.kill()  # a write the thread is blocked in then fails at once
        if self._thread.ident is not None:
            self._thread.join(timeout=10.0)

    def _failure(self, error: BaseException | None) -> OutputError:
        """One line saying why the video could not be written: a full disk, a file size limit or
        permissions (from the pipe's error, ffmpeg's messages or its exit signal), else ffmpeg's last
        message; never its command line."""
        code = None if self._process is None else self._process.poll()
        self._log.seek(0)
        log = self._log.read()[-4000:].decode("utf-8", "replace")
        if isinstance(error, OSError) and error.errno in _KNOWN_ERRNOS:
            return output_error(self.path, error)
        for number in _KNOWN_ERRNOS:
            if os.strerror(number) in log:
                return output_error(self.path, OSError(number, os.strerror(number)))
        if code == -getattr(signal, "SIGXFSZ", 0):  # ffmpeg killed for passing the file size limit
            return output_error(self.path, OSError(errno.EFBIG, os.strerror(errno.EFBIG)))
        # ffmpeg prefixes its messages with their context ("[out#0/gif @ 0x55...] "): keep the words.
        lines = [re.sub(r"^(\[[^\]]*\]\s*)+", "", line).strip() for line in log.splitlines()]
        lines = [line for line in lines if line]
        if lines:
            reason = f"the video encoder stopped: {lines[-1][:200]}"
        elif code is not None and code < 0:
            reason = f"the video encoder was killed by {signal.Signals(-code).name}"
        elif code:
            reason = f"the video encoder exited with status {code}"
        else:
            reason = f"writing to the video encoder failed: {error}"
        return OutputError(f"cannot write {self.path}: {reason}")
