"""Video: MP4 and GIF read back (frame count, size, rate, frames that differ), odd sizes refused, atomic
publication, the completeness check, and `taichi-anim demo --video` recording the video in run.json."""

import json

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.errors import OutputError, ParameterError
from taichi_anim.io.atomic import incomplete_reason
from taichi_anim.render import VideoWriter
from taichi_anim.render.video import video_frame_count
from taichi_anim.scenes import Scene


def read_video(path):
    """(frames, metadata) of a video file, read by imageio."""
    import imageio.v3 as iio

    return iio.imread(path), iio.immeta(path)


def falling_points() -> Scene:
    """Twenty falling particles in a box: a scene that compiles and renders in moments."""
    b = ta.Builder()
    b.add_force_gravity((0.0, -9.81, 0.0))
    x = np.random.default_rng(0).uniform(-0.5, 0.5, (20, 3)) + [0.0, 1.0, 0.0]
    b.add_particles(x)
    model = b.finalize()
    return Scene(
        name="falling",
        description="twenty falling particles",
        model=model,
        state=model.state(),
        integrator=ta.make_integrator("symplectic_euler"),
        dt=1 / 30,
        substeps=1,
        bounds=((-1.0, 0.0, -1.0), (1.0, 2.0, 1.0)),
        point_radius=0.05,
    )


def frames(n: int, w: int = 64, h: int = 48) -> list[np.ndarray]:
    """n frames, each with a white bar at a different column."""
    out = []
    for k in range(n):
        img = np.full((h, w, 3), 30, dtype=np.uint8)
        img[:, 4 * k : 4 * k + 8] = 255
        out.append(img)
    return out


@pytest.mark.parametrize("ext", ["mp4", "gif"])
def test_video_reads_back_with_its_frames_size_and_rate(tmp_path, ext):
    path = tmp_path / f"v.{ext}"
    with VideoWriter(path, fps=30) as video:
        for img in frames(12):
            video.append(img)
    assert video.record() == {"path": str(path), "fps": 30.0, "frames": 12, "size": [64, 48]}
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temporary left
    back, meta = read_video(path)
    assert back.shape[:3] == (12, 48, 64)
    if ext == "mp4":
        assert meta["fps"] == pytest.approx(30.0)
    else:
        assert meta["duration"] == 30  # [ms]: GIF delays are whole centiseconds (30 fps -> 33.3 fps)
    diffs = [np.abs(back[k + 1].astype(int) - back[k]).mean() for k in range(11)]
    assert min(diffs) > 5  # the bar moved in every frame: frames differ
    # The bar is where it was drawn (lossy MP4: within a margin).
    assert back[3][:, 12:20].mean() > 200 and back[3][:, 40:].mean() < 80
    assert incomplete_reason(path) is None and video_frame_count(path) == 12


def test_odd_size_is_refused_naming_resolution(tmp_path):
    path = tmp_path / "odd.mp4"
    with pytest.raises(ParameterError, match="resolution"):
        with VideoWriter(path, fps=24) as video:
            video.append(np.zeros((47, 64, 3), dtype=np.uint8))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ParameterError, match="mp4 or .gif"):
        VideoWriter(tmp_path / "v.avi", fps=24)
    with pytest.raises(ParameterError, match="fps"):
        VideoWriter(tmp_path / "v.mp4", fps=0)


@pytest.mark.parametrize("ext", ["mp4", "gif"])
def test_a_failing_write_leaves_no_file_and_keeps_the_previous_one(tmp_path, ext):
    path = tmp_path / f"v.{ext}"
    with VideoWriter(path, fps=10) as video:
        for img in frames(3):
            video.append(img)
    before = path.read_bytes()
    with pytest.raises(RuntimeError, match="simulated"):
        with VideoWriter(path, fps=10) as video:
            for img in frames(5):
                video.append(img)
            raise RuntimeError("simulated crash mid-video")
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name] and path.read_bytes() == before
    with pytest.raises(OutputError, match="no frames"):
        with VideoWriter(tmp_path / "empty.mp4", fps=10):
            pass
    assert not (tmp_path / "empty.mp4").exists()


def test_completeness_check_catches_truncated_videos(tmp_path):
    for ext in ("mp4", "gif"):
        path = tmp_path / f"v.{ext}"
        with VideoWriter(path, fps=10) as video:
            for img in frames(4):
                video.append(img)
        data = path.read_bytes()
        cut = tmp_path / f"cut.{ext}"
        cut.write_bytes(data[: len(data) * 2 // 3])
        assert incomplete_reason(cut) is not None, ext
        cut.write_bytes(b"")
        assert incomplete_reason(cut) is not None, ext


def test_cli_demo_video_is_recorded_in_run_json(tmp_path, capsys, monkeypatch):
    import taichi_anim.scenes as scenes
    from taichi_anim.cli import main

    monkeypatch.setattr(scenes, "make_scene", lambda name, **options: falling_points())
    out = tmp_path / "run"
    argv = ["demo", "--frames", "4", "--out", str(out), "--quiet", "--video", "--color-by", "height"]
    assert main(argv) == 0
    doc = json.loads((out / "run.json").read_text())
    video = doc["timings"]["video"]
    assert video["path"] == str(out / "falling.mp4") and video["frames"] == 4 and video["size"] == [960, 720]
    assert video["fps"] == pytest.approx(30.0) and video["ms_per_frame"] > 0
    back, meta = read_video(out / "falling.mp4")
    assert back.shape == (4, 720, 960, 3) and meta["fps"] == pytest.approx(30.0)
    assert np.abs(back[3].astype(int) - back[0]).max() > 50  # the particles fell
    assert "falling.mp4" in [f["path"] for f in doc["files"]]
    assert "video" in capsys.readouterr().out
    assert main(["demo", "--frames", "1", "--out", str(out), "--video", "x.avi"]) == 2
