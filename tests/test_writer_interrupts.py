"""The USD stage and video writers under interruption and failure: a frame is added all or nothing (an
interrupt injected at every authoring step of add_frame, and into the video writer's hand-over, or a
real SIGINT at several instants), long runs stream (bounded memory, data on disk before the end), and a
failing encoder reports its cause in one line. Each test's docstring states its pass criterion."""

import errno
import itertools
import os
import re
import signal
import threading
import time

import numpy as np
import pytest

from taichi_anim.content import Lines, Mesh, Points
from taichi_anim.errors import OutputError
from taichi_anim.io import UsdStageWriter
from taichi_anim.io import usd as usd_module
from taichi_anim.io.atomic import TEMPORARY_NAME, incomplete_reason
from taichi_anim.render import VideoWriter
from taichi_anim.render import video as video_module
from taichi_anim.render.video import video_frame_count

from .hard_cases.test_output import file_size_limit

Sdf = pytest.importorskip("pxr.Sdf")
FPS = 24


def frame_items(k: int) -> list:
    """Frame k (1-based) exercising every authoring path: points with radii and attributes (a new one,
    "temperature", from frame 4), a cloth (fixed topology), a surface (topology per frame), a static
    ground written once, trails, a guide, an item that leaves at frame 4 and one that arrives there."""
    rng = np.random.default_rng(k)
    n = 5 + k
    x = rng.random((n, 3)).astype(np.float32)
    attributes = {"velocity": -x, "age": np.full(n, 0.1 * k, np.float32)}
    if k >= 4:
        attributes["temperature"] = np.arange(n, dtype=np.float32)
    grid = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, 1]], np.float32) + [0, 0.1 * k, 0]
    quads = np.array([[0, 2, 1], [1, 2, 3]])
    surface_v = rng.random((3 + k, 3))
    surface_f = np.array([[0, 1, i] for i in range(2, 3 + k)])
    items = [
        Points("", x, rng.random((n, 3)), np.arange(n) + k, 0.01 + 0.001 * np.arange(n), attributes),
        Mesh("cloth", grid, quads, role="cloth"),
        Mesh("surface", surface_v, surface_f, role="surface"),
        Mesh("ground", grid * [2, 0, 2], quads, role="collider", animated=False),
        Lines("trails", x, np.array([[i, i + 1] for i in range(n - 1)]), role="trails"),
        Lines("guides", grid, np.array([[0, 1], [2, 3]]), role="guide"),
    ]
    if k < 4:
        items.append(Points("leaves", x[:2], np.ones((2, 3)), np.array([1, 2])))
    else:
        items.append(Points("arrives", x[:3], np.zeros((3, 3)), np.array([4, 5, 6])))
    return items


def layer_text(writer: UsdStageWriter) -> str:
    return writer.stage.GetRootLayer().ExportToString()


def file_text(path) -> str:
    return Sdf.Layer.OpenAsAnonymous(str(path)).ExportToString()


class Fault:
    """Raises KeyboardInterrupt at the k-th call of the armed writer methods, before or after the call."""

    def __init__(self, monkeypatch, names=("_put", "_define")):
        self.calls, self.at, self.after = 0, None, False
        for name in names:
            original = getattr(UsdStageWriter, name)
            monkeypatch.setattr(UsdStageWriter, name, self.wrap(original))

    def wrap(self, original):
        def method(*args, **kwargs):
            if self.at is None:
                return original(*args, **kwargs)
            self.calls += 1
            if self.calls == self.at and not self.after:
                raise KeyboardInterrupt
            result = original(*args, **kwargs)
            if self.calls == self.at and self.after:
                raise KeyboardInterrupt
            return result

        return method

    def arm(self, at, after):
        self.calls, self.at, self.after = 0, at, after

    def disarm(self) -> int:
        calls, self.at = self.calls, None
        return calls


@pytest.mark.parametrize("suffix", [".usda", ".usd"])
def test_usd_frame_interrupted_at_every_step_leaves_the_previous_frames(tmp_path, monkeypatch, suffix):
    """Pass: for every authoring step k of frame 4 (each value set and prim definition), with a
    KeyboardInterrupt raised just before and just after it, add_frame raises, the stage's layer is
    exactly (as text) what it was after frame 3 and its codes are [1, 2, 3]; adding frame 4 again and
    saving gives a file identical to an uninterrupted run's, which passes the completeness check. The
    binary stage is saved after every frame (FLUSH_BYTES = 0), so undo also works on saved samples."""
    monkeypatch.setattr(usd_module, "FLUSH_BYTES", 0)
    clean = tmp_path / f"clean{suffix}"
    with UsdStageWriter(clean, fps=FPS, name="t") as w:
        for k in range(1, 5):
            w.add_frame(frame_items(k), time=k / FPS)
    fault = Fault(monkeypatch)
    probe = UsdStageWriter(tmp_path / f"probe{suffix}", fps=FPS, name="t")
    for k in range(1, 4):
        probe.add_frame(frame_items(k), time=k / FPS)
    fault.arm(10**9, False)  # count the steps of frame 4
    probe.add_frame(frame_items(4), time=4 / FPS)
    steps = fault.disarm()
    probe.discard()
    assert steps > 30  # every item of frame 4 went through the journalled helpers
    for at in range(1, steps + 1):
        for after in (False, True):
            path = tmp_path / f"s{at}{after:d}{suffix}"
            w = UsdStageWriter(path, fps=FPS, name="t")
            for k in range(1, 4):
                w.add_frame(frame_items(k), time=k / FPS)
            before = layer_text(w)
            fault.arm(at, after)
            with pytest.raises(KeyboardInterrupt):
                w.add_frame(frame_items(4), time=4 / FPS)
            fault.disarm()
            assert layer_text(w) == before, (at, after)
            assert w.codes == [1.0, 2.0, 3.0]
            w.add_frame(frame_items(4), time=4 / FPS)
            w.save()
            assert incomplete_reason(path) is None
            assert file_text(path) == file_text(clean), (at, after)


def test_usd_interrupt_during_undo_is_finished_by_the_save(tmp_path, monkeypatch):
    """Pass: when a second KeyboardInterrupt cuts the undo of an interrupted frame short, the `with`
    block's save finishes the undo: the published stage equals a clean three-frame stage, passes the
    completeness check and announces 3 frames; no temporary is left."""
    clean = tmp_path / "clean.usd"
    with UsdStageWriter(clean, fps=FPS, name="t") as w:
        for k in range(1, 4):
            w.add_frame(frame_items(k), time=k / FPS)
    fault = Fault(monkeypatch)
    undo = UsdStageWriter._undo_step
    cut = {"calls": 0}

    def undo_step(self, step):
        cut["calls"] += 1
        if cut["calls"] == 3:
            raise KeyboardInterrupt  # the second Ctrl-C, while the first frame is being undone
        undo(self, step)

    monkeypatch.setattr(UsdStageWriter, "_undo_step", undo_step)
    path = tmp_path / "s.usd"
    with pytest.raises(KeyboardInterrupt):
        with UsdStageWriter(path, fps=FPS, name="t") as w:
            for k in range(1, 4):
                w.add_frame(frame_items(k), time=k / FPS)
            fault.arm(25, True)
            w.add_frame(frame_items(4), time=4 / FPS)
    assert cut["calls"] > 3  # the undo was cut, then finished
    assert incomplete_reason(path) is None
    assert file_text(path) == file_text(clean)
    assert Sdf.Layer.OpenAsAnonymous(str(path)).customLayerData["taichi_anim"]["frames"] == 3
    assert not [p for p in tmp_path.iterdir() if TEMPORARY_NAME.match(p.name)]


def test_usd_bad_item_mid_frame_is_taken_back(tmp_path):
    """Pass: a frame whose third item is not a content item raises ParameterError and leaves nothing of
    its first two items (same layer text as before); the stage saves with its one good frame."""
    path = tmp_path / "s.usda"
    w = UsdStageWriter(path, fps=FPS, name="t")
    w.add_frame(frame_items(1), time=1 / FPS)
    before = layer_text(w)
    with pytest.raises(Exception, match="Points, Mesh or Lines"):
        w.add_frame([*frame_items(4)[:2], "not an item"], time=2 / FPS)
    assert layer_text(w) == before and w.codes == [1.0]
    w.save()
    assert incomplete_reason(path) is None


def test_usd_binary_stage_streams_to_disk_with_bounded_memory(tmp_path):
    """Pass: writing 20 then 60 more frames of 40,000 points (points and velocities that change: 0.96 MB
    per frame; colours and ids that repeat, which the crate file stores once) into a binary stage, the
    hidden temporary on disk holds at least 60 frames' worth of the changing data before the writer
    is closed, and the process's resident memory grows by less than 50 MB over the 60 frames (holding
    them takes ~60-120 MB); the published stage has all 80."""
    psutil = pytest.importorskip("psutil")
    path = tmp_path / "big.usd"
    n = 40_000
    rng = np.random.default_rng(0)
    x = rng.random((n, 3)).astype(np.float32)
    colors, ids = rng.random((n, 3)).astype(np.float32), np.arange(n)

    def add(w, k):
        y = x + np.float32(0.01 * k)  # every frame's values differ (the crate would share equal ones)
        w.add_frame([Points("", y, colors, ids, attributes={"velocity": -y})], time=k / FPS)

    process = psutil.Process()
    with UsdStageWriter(path, fps=FPS) as w:
        for k in range(1, 21):
            add(w, k)
        start = process.memory_info().rss
        for k in range(21, 81):
            add(w, k)
        grown = process.memory_info().rss - start
        (tmp,) = [p for p in tmp_path.iterdir() if TEMPORARY_NAME.match(p.name)]
        on_disk = tmp.stat().st_size
    assert on_disk >= 60 * 2 * x.nbytes, on_disk
    assert grown < 50 << 20, grown
    assert incomplete_reason(path) is None
    assert Sdf.Layer.OpenAsAnonymous(str(path)).customLayerData["taichi_anim"]["frames"] == 80


# -------------------------------------------------------------------------------------------- video


def bar_frame(k: int, w: int = 64, h: int = 48) -> np.ndarray:
    """Frame k: a white bar at column 4 (k mod 15) on grey."""
    img = np.full((h, w, 3), 30, dtype=np.uint8)
    img[:, 4 * (k % 15) : 4 * (k % 15) + 4] = 255
    return img


def bar_frames(n: int) -> list[np.ndarray]:
    return [bar_frame(k) for k in range(n)]


def read_frames(path) -> np.ndarray:
    import imageio.v3 as iio

    return iio.imread(path)


def assert_frames_match(path, count: int) -> None:
    """The video holds `count` frames, frame k with its bar where bar_frames drew it."""
    back = read_frames(path)
    assert len(back) == count == video_frame_count(path)
    source = bar_frames(count)
    for k in range(count):
        assert np.abs(back[k].astype(int) - source[k]).mean() < 6, k  # lossy MP4: a small margin


class FlakyWake:
    """Stands in for the encoder's wake-up semaphore: KeyboardInterrupt at the k-th release."""

    def __init__(self, wake, at):
        self.wake, self.at, self.calls = wake, at, 0

    def acquire(self, *args, **kwargs):
        return self.wake.acquire(*args, **kwargs)

    def release(self):
        self.calls += 1
        if self.calls == self.at:
            raise KeyboardInterrupt  # after the frame was handed over, before the encoder is woken
        self.wake.release()


@pytest.mark.parametrize("ext", ["mp4", "gif"])
@pytest.mark.parametrize("where", ["before hand-over", "after hand-over", "after append"])
def test_video_interrupted_mid_append_publishes_the_whole_frames(tmp_path, monkeypatch, ext, where):
    """Pass: a KeyboardInterrupt in the 6th append (before the frame is handed to the encoder thread,
    after it but before the thread is woken, or after append returned) propagates, and the published
    video holds exactly the frames given whole (5, 6 and 6), each intact, frames == the file's count,
    and no temporary is left."""
    path = tmp_path / f"v.{ext}"
    put = video_module._FfmpegEncoder.put
    calls = {"n": 0}

    def interrupted_put(self, frame):
        calls["n"] += 1
        if calls["n"] == 6 and where == "before hand-over":
            raise KeyboardInterrupt
        if calls["n"] == 6 and where == "after hand-over":
            self._wake = FlakyWake(self._wake, 1)
        put(self, frame)
        if calls["n"] == 6 and where == "after append":
            raise KeyboardInterrupt

    monkeypatch.setattr(video_module._FfmpegEncoder, "put", interrupted_put)
    with pytest.raises(KeyboardInterrupt):
        with VideoWriter(path, fps=10) as video:
            for img in bar_frames(20):
                video.append(img)
    expected = 5 if where == "before hand-over" else 6
    assert video.frames == expected
    assert_frames_match(path, expected)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


@pytest.mark.parametrize("ext", ["mp4", "gif"])
def test_video_real_sigint_at_several_instants(tmp_path, ext):
    """Pass: a real SIGINT sent to the process at 6 instants while frames are appended stops the loop
    with a KeyboardInterrupt, and each published video holds every frame it reports, all intact."""
    handler = signal.getsignal(signal.SIGINT)

    class Stop(KeyboardInterrupt):
        pass

    def raise_stop(signum, frame):
        raise Stop

    signal.signal(signal.SIGINT, raise_stop)
    counts = []
    try:
        for delay in (0.002, 0.01, 0.03, 0.06, 0.1, 0.2):
            path = tmp_path / f"v{delay}.{ext}"
            timer = threading.Timer(delay, os.kill, (os.getpid(), signal.SIGINT))
            with pytest.raises(Stop):
                with VideoWriter(path, fps=10) as video:
                    timer.start()
                    for k in itertools.count():
                        video.append(bar_frame(k))
            timer.join()
            counts.append(video.frames)
            if video.frames == 0:  # stopped before the first frame: nothing to publish
                assert not path.exists()
            else:
                assert_frames_match(path, video.frames)
    finally:
        signal.signal(signal.SIGINT, handler)
    assert max(counts) > 0  # some runs stopped mid-video (the frame counts depend on the machine)
    assert not [p for p in tmp_path.iterdir() if TEMPORARY_NAME.match(p.name)]


def test_video_disk_full_is_one_line_naming_the_cause(tmp_path, monkeypatch):
    """Pass: when the write to the encoder fails with ENOSPC at the 3rd frame, the writer raises
    OutputError "cannot write PATH: no space left on the device" (one line, no ffmpeg command line);
    neither the video nor a temporary is left."""
    path = tmp_path / "v.mp4"
    write = video_module._FfmpegEncoder._write
    calls = {"n": 0}

    def full_disk(self, stdin, frame):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        write(self, stdin, frame)

    monkeypatch.setattr(video_module._FfmpegEncoder, "_write", full_disk)
    with pytest.raises(OutputError) as info:
        with VideoWriter(path, fps=10) as video:
            for img in bar_frames(40):
                video.append(img)
    assert str(info.value) == f"cannot write {path}: no space left on the device"
    assert list(tmp_path.iterdir()) == []


def test_video_broken_pipe_and_file_size_limit_are_one_line(tmp_path, monkeypatch):
    """Pass: an MP4 of noise past a 30 kB file size limit (ffmpeg is stopped by the limit) raises
    OutputError naming the path and "larger than the allowed file size"; a broken pipe with no known
    cause gives ffmpeg's last message without its context prefix; both are one line without
    ffmpeg's command line, and leave no file."""
    rng = np.random.default_rng(0)
    noise = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(60)]
    path = tmp_path / "big.mp4"
    with file_size_limit(30_000), pytest.raises(OutputError) as info:
        with VideoWriter(path, fps=10) as video:
            for img in noise:
                video.append(img)
    message = str(info.value)
    assert message == f"cannot write {path}: the file is larger than the allowed file size"

    def broken(self, stdin, frame):
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    monkeypatch.setattr(video_module._FfmpegEncoder, "_write", broken)
    path = tmp_path / "v.gif"
    with pytest.raises(OutputError) as info:
        with VideoWriter(path, fps=10) as video:
            for img in noise:
                video.append(img)
    message = str(info.value)
    assert message.startswith(f"cannot write {path}: the video encoder stopped: ")
    assert "\n" not in message and "-pix_fmt" not in message and "ffmpeg" not in message.lower()
    assert list(tmp_path.iterdir()) == []


def test_gif_streams_frames_to_disk_and_keeps_few_in_memory(tmp_path):
    """Pass: while a GIF is written, at most IN_FLIGHT frames wait for the encoder after any append,
    and the hidden temporary grows on disk before the writer is closed (the frames are encoded as they
    come, not kept for the end); the GIF's frames have the 2 cs delay of 50 frames/s and a 256-colour
    palette of their own, so a smooth gradient comes back within 2 levels on average."""
    from PIL import Image

    h, w = 96, 128
    ramp = np.linspace(0, 255, w)[None, :, None] * np.linspace(0.2, 1.0, h)[:, None, None]
    base = (ramp * [1.0, 0.6, 0.3]).astype(np.uint8)
    path = tmp_path / "v.gif"
    waiting = []
    with VideoWriter(path, fps=50) as video:
        for k in range(60):
            video.append(np.roll(base, k, axis=1))
            waiting.append(len(video._encoder._waiting))
        (tmp,) = [p for p in tmp_path.iterdir() if TEMPORARY_NAME.match(p.name)]
        deadline = time.monotonic() + 10.0
        while tmp.stat().st_size == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert tmp.stat().st_size > 0
    assert max(waiting) <= video_module.IN_FLIGHT
    back = read_frames(path)
    assert len(back) == 60
    errors = [np.abs(back[k].astype(int) - np.roll(base, k, axis=1)).mean() for k in range(60)]
    assert max(errors) < 2.0, max(errors)
    with Image.open(path) as im:
        assert im.info["duration"] == 20


def test_video_temporary_follows_the_hidden_temporary_pattern(tmp_path):
    """Pass: while a video is written, the only file beside it is `.NAME.tmp-XXXXXXXX.EXT`
    (io/atomic.TEMPORARY_NAME, which a later run's cleanup removes), named after the target."""
    path = tmp_path / "clip.mp4"
    with VideoWriter(path, fps=10) as video:
        video.append(bar_frames(1)[0])
        deadline = time.monotonic() + 10.0
        while not list(tmp_path.iterdir()) and time.monotonic() < deadline:
            time.sleep(0.02)  # ffmpeg creates its output when it starts
        names = [p.name for p in tmp_path.iterdir()]
    assert len(names) == 1 and re.fullmatch(r"\.clip\.tmp-[0-9a-f]{8}\.mp4", names[0])
    assert TEMPORARY_NAME.match(names[0])
