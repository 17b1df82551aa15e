"""Hard cases for runs that must survive their surroundings: two runs into one folder, signals from
`timeout`/docker/Slurm/Ctrl-C, options that are wrong only in a way found late, a run.json that is not a
file, and the compile figure. Each test's docstring states its pass criterion. Processes that could
hang (a FIFO) run in a subprocess with a timeout, so a regression fails instead of stalling the suite."""

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from taichi_anim import FolderBusyError, RunInterrupted
from taichi_anim.cli import EXIT_OUTPUT, EXIT_PARAMETER, main
from taichi_anim.errors import OutputError, ParameterError
from taichi_anim.io import read_manifest, write_manifest
from taichi_anim.io.atomic import incomplete_reason
from taichi_anim.io.lock import LOCK_NAME
from taichi_anim.scenes.runner import run_scene, summary_line

from .test_output import TEMPORARY, assert_manifest_matches_folder, listing, tiny_scene

pytest.importorskip("fcntl")  # POSIX only
ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}

# Takes the folder lock as a run does (flock on the lock file, its PID inside) and keeps it.
HOLD_LOCK = (
    "import fcntl, os, sys, time\n"
    "fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)\n"
    "fcntl.flock(fd, fcntl.LOCK_EX)\n"
    "os.ftruncate(fd, 0); os.write(fd, f'{os.getpid()}\\n'.encode())\n"
    "print('locked', flush=True)\n"
    "time.sleep(300)\n"
)


@contextlib.contextmanager
def lock_held_by_another_process(lock: Path):
    proc = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(lock)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        yield proc
    finally:
        proc.kill()
        proc.wait()


def contents(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file() and p.name != LOCK_NAME}


def previous_run(out: Path) -> dict[str, bytes]:
    """A complete 2-frame run of the tiny scene in `out` and a user's file; returns the folder's bytes."""
    run_scene(tiny_scene(), frames=2, out_dir=out, progress=False)
    (out / "user_notes.txt").write_text("mine")
    return contents(out)


# --------------------------------------------------------------------------------- one run per folder


def test_a_second_run_into_a_busy_folder_stops_before_touching_anything(tmp_path, capsys):
    """Pass: while another process holds the folder's lock, run_scene raises FolderBusyError (an
    OutputError) naming the folder and that process's PID, and the CLI exits 3 with one line saying the
    same; every file of the previous run, run.json included, is unchanged, and the lock stays theirs."""
    out = tmp_path / "out"
    before = previous_run(out)
    with lock_held_by_another_process(out / LOCK_NAME) as other:
        with pytest.raises(FolderBusyError) as info:
            run_scene(tiny_scene(), frames=1, out_dir=out, progress=False)
        assert isinstance(info.value, OutputError) and info.value.pid == other.pid
        assert str(out) in str(info.value) and f"process {other.pid}" in str(info.value)
        assert main(["demo", "--frames", "1", "--out", str(out), "--quiet"]) == EXIT_OUTPUT
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0] and f"process {other.pid}" in err[0], err
        assert contents(out) == before
        assert (out / LOCK_NAME).read_text().strip() == str(other.pid)


def test_the_lock_is_held_for_the_whole_run_and_released_after(tmp_path):
    """Pass: a second run started while the first is exporting frame 1 (same process, its own file
    descriptor, as a second process would) is refused with the first run's PID and removes nothing;
    the first run completes, lists exactly its files, and leaves no lock file."""
    scene, seen = tiny_scene(), {}
    export = scene.export_frame

    def export_and_intrude(out, frame, *items):
        if frame == 1:
            with pytest.raises(FolderBusyError) as info:
                run_scene(tiny_scene("other"), frames=1, out_dir=out, progress=False)
            seen.update(pid=info.value.pid, files=listing(out))
        return export(out, frame, *items)

    scene.export_frame = export_and_intrude
    run_scene(scene, frames=3, out_dir=tmp_path, progress=False)
    assert seen["pid"] == os.getpid()
    assert seen["files"] == sorted([LOCK_NAME, "run.json", "tiny_0000.ply"])
    assert_manifest_matches_folder(tmp_path, status="complete")
    assert LOCK_NAME not in listing(tmp_path)


def test_the_stale_lock_of_a_killed_run_is_taken_over(tmp_path):
    """Pass: the lock file of a run killed with SIGKILL (file and PID left behind, the lock released by
    the kernel) does not block the next run, which completes and removes the file."""
    out = tmp_path / "out"
    out.mkdir()
    with lock_held_by_another_process(out / LOCK_NAME) as dead:
        dead.send_signal(signal.SIGKILL)
        dead.wait()
    assert (out / LOCK_NAME).read_text().strip() == str(dead.pid)
    summary = run_scene(tiny_scene(), frames=1, out_dir=out, progress=False)
    assert summary["status"] == "complete" and LOCK_NAME not in listing(out)


# -------------------------------------------------------------------------------------------- signals


def interrupt_a_real_run(tmp_path, sig: int, *extra: str) -> tuple[subprocess.CompletedProcess, Path]:
    """Run the cloth demo (2000 frames, PLY + USD) in a fresh process with an empty Taichi offline cache,
    send `sig` once its first frame file is published, and return the finished process and its folder."""
    out = tmp_path / "out"
    env = {**ENV, "TI_OFFLINE_CACHE_FILE_PATH": str(tmp_path / "ticache")}
    argv = ["demo", "cloth", "--frames", "2000", "--format", "both", "--out", str(out), "--quiet", *extra]
    proc = subprocess.Popen(
        [sys.executable, "-m", "taichi_anim", *argv], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    try:
        deadline = time.monotonic() + 300
        while not (out / "cloth_0000.ply").exists():
            if proc.poll() is not None:
                pytest.fail(f"the run ended before its first frame: {proc.stderr.read().decode()}")
            assert time.monotonic() < deadline, "no frame within 300 s"
            time.sleep(0.02)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout.decode(), stderr.decode()), out


def assert_interrupted_cleanly(proc, out: Path, sig: int) -> dict:
    """Exit 128 + sig with one line on stderr; run.json "interrupted" with the signal, listing exactly
    the files there; one PLY per frame done; the stage complete and holding exactly those frames; no
    temporaries, no lock, no picture."""
    from pxr import Usd

    name = signal.Signals(sig).name
    assert proc.returncode == 128 + sig, proc.stderr
    err = [line for line in proc.stderr.splitlines() if line.startswith("taichi-anim:")]
    assert len(err) == 1 and f"interrupted by {name} after" in err[0], proc.stderr
    doc = assert_manifest_matches_folder(out, status="interrupted")
    assert doc["error"]["signal"] == name and doc["error"]["signal_number"] == sig
    assert doc["error"]["type"] == "RunInterrupted" and doc["error"]["forced"] is False
    done = doc["timings"]["frames_done"]
    assert 1 <= done < 2000 and f"after {done} of 2000 frames" in err[0]
    assert sorted(p.name for p in out.glob("cloth_[0-9]*.ply")) == [f"cloth_{k:04d}.ply" for k in range(done)]
    assert incomplete_reason(out / "cloth.usd") is None
    stage = Usd.Stage.Open(str(out / "cloth.usd"))
    assert stage.GetRootLayer().ListAllTimeSamples() == [float(k + 1) for k in range(done)]
    assert stage.GetEndTimeCode() == done
    assert not [n for n in listing(out) if TEMPORARY.fullmatch(n)]
    assert LOCK_NAME not in listing(out) and "cloth_last.png" not in listing(out)
    return doc


def test_sigterm_stops_a_real_run_between_frames_and_saves_what_it_has(tmp_path):
    """`timeout`, docker stop, Slurm and CI runners send SIGTERM. Pass: a real cloth run (fresh process,
    PLY + USD) sent SIGTERM after its first frame exits 143 (assert_interrupted_cleanly). Its first frame
    compiled from an empty offline cache, so run.json's compile_s is measured and > 0, no more than the
    first frame's time, with at least one kernel counted."""
    proc, out = interrupt_a_real_run(tmp_path, signal.SIGTERM)
    doc = assert_interrupted_cleanly(proc, out, signal.SIGTERM)
    timings = doc["timings"]
    assert 0 < timings["compile_s"] <= timings["first_frame_s"] and timings["compile_kernels"] >= 1


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT], ids=["SIGHUP", "SIGINT"])
def test_sighup_and_sigint_stop_a_real_run_and_keep_its_video(tmp_path, sig):
    """Slow (renders 960 x 720 frames). Pass: as for SIGTERM, with exit 129 or 130, and the MP4 published
    with exactly the frames run.json says were done."""
    from taichi_anim.render.video import video_frame_count

    proc, out = interrupt_a_real_run(tmp_path, sig, "--video")
    doc = assert_interrupted_cleanly(proc, out, sig)
    assert video_frame_count(out / "cloth.mp4") == doc["timings"]["frames_done"]
    assert doc["timings"]["video"]["frames"] == doc["timings"]["frames_done"]


def signal_during_export(scene, at: int, *signals: int, before: bool = False):
    """Make `scene` send itself `signals` while it exports frame `at` (after writing it, or before)."""
    export = scene.export_frame

    def export_and_signal(out, frame, *items):
        if frame == at and before:
            for sig in signals:
                os.kill(os.getpid(), sig)
        result = export(out, frame, *items)
        if frame == at and not before:
            for sig in signals:
                os.kill(os.getpid(), sig)
        return result

    scene.export_frame = export_and_signal
    return scene


def test_sighup_lets_the_frame_finish_and_the_library_raises_run_interrupted(tmp_path):
    """Pass: SIGHUP during frame 2 of 50 lets frame 2 finish; run_scene raises RunInterrupted (a
    KeyboardInterrupt: SIGHUP, exit code 129, 3 frames done, not forced) carrying the summary; run.json
    "interrupted" lists the 3 PLY frames and the stage, whose time samples are exactly codes 1..3; no
    picture; the previous SIGHUP handler is back."""
    from pxr import Sdf

    previous = signal.getsignal(signal.SIGHUP)
    scene = signal_during_export(tiny_scene(), 2, signal.SIGHUP)
    with pytest.raises(KeyboardInterrupt) as info:
        run_scene(scene, frames=50, out_dir=tmp_path, progress=False, export_format="both")
    e = info.value
    assert isinstance(e, RunInterrupted) and (e.signal, e.exit_code, e.frames_done, e.forced) == (
        "SIGHUP",
        129,
        3,
        False,
    )
    assert e.summary["status"] == "interrupted" and e.summary["frames_done"] == 3
    assert signal.getsignal(signal.SIGHUP) is previous
    doc = assert_manifest_matches_folder(tmp_path, status="interrupted")
    assert [f["path"] for f in doc["files"]] == [
        "tiny_0000.ply",
        "tiny_0001.ply",
        "tiny_0002.ply",
        "tiny.usd",
    ]
    assert Sdf.Layer.FindOrOpen(str(tmp_path / "tiny.usd")).ListAllTimeSamples() == [1.0, 2.0, 3.0]


def test_ctrl_c_through_the_cli_exits_130_with_one_line(tmp_path, monkeypatch, capsys):
    """Pass: SIGINT during frame 1 of 20 through the CLI exits 130 with one line on stderr naming the
    signal, the frames done (2 of 20) and the folder; run.json says "interrupted" (SIGINT)."""
    import taichi_anim.scenes as scenes

    monkeypatch.setattr(
        scenes, "make_scene", lambda name, **o: signal_during_export(tiny_scene(), 1, signal.SIGINT)
    )
    assert main(["demo", "--frames", "20", "--out", str(tmp_path), "--quiet"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"taichi-anim: interrupted by SIGINT after 2 of 20 frames; the frames so far are in {tmp_path}"
    ]
    doc = assert_manifest_matches_folder(tmp_path, status="interrupted")
    assert doc["error"]["signal"] == "SIGINT" and doc["timings"]["frames_done"] == 2


def test_a_second_signal_stops_at_once_and_still_records_the_run(tmp_path):
    """Pass: two SIGTERMs just before frame 2 is exported stop the run inside that frame: RunInterrupted
    (forced) with 2 frames done; run.json "interrupted" (forced) lists exactly frames 0 and 1; no
    temporary is left."""
    scene = signal_during_export(tiny_scene(), 2, signal.SIGTERM, signal.SIGTERM, before=True)
    with pytest.raises(RunInterrupted) as info:
        run_scene(scene, frames=50, out_dir=tmp_path, progress=False)
    assert info.value.forced and info.value.signal == "SIGTERM"
    doc = assert_manifest_matches_folder(tmp_path, status="interrupted")
    assert doc["error"]["forced"] is True and doc["timings"]["frames_done"] == 2
    assert [f["path"] for f in doc["files"]] == ["tiny_0000.ply", "tiny_0001.ply"]


def test_a_signal_after_the_last_look_reaches_the_previous_handler(tmp_path, monkeypatch):
    """Pass: a SIGHUP that arrives while the final run.json is written does not change the record
    ("complete") and is not lost: the handler installed before the run receives it once the run is over."""
    import taichi_anim.scenes.runner as runner

    write = runner.write_manifest

    def write_and_hang_up(out, *args, status, **kwargs):
        if status == "complete":
            os.kill(os.getpid(), signal.SIGHUP)
        return write(out, *args, status=status, **kwargs)

    monkeypatch.setattr(runner, "write_manifest", write_and_hang_up)
    got = []
    previous = signal.signal(signal.SIGHUP, lambda sig, frame: got.append(sig))
    try:
        summary = run_scene(tiny_scene(), frames=2, out_dir=tmp_path, progress=False)
    finally:
        signal.signal(signal.SIGHUP, previous)
    assert summary["status"] == "complete" and read_manifest(tmp_path)["status"] == "complete"
    assert got == [signal.SIGHUP]


# --------------------------------------------------------------------------- check before touching


@pytest.mark.parametrize(
    ("video", "code", "message"),
    [
        (".mp4", EXIT_PARAMETER, r"--video must name an \.mp4 or \.gif file, got '\.mp4' \(a suffix without"),
        ("clips/", EXIT_PARAMETER, r"--video must name an \.mp4 or \.gif file, got 'clips/'"),
        ("movie.avi", EXIT_PARAMETER, r"got 'movie.avi'"),
        (
            "{out}/folder.mp4",
            EXIT_OUTPUT,
            r"cannot write the video \S+folder.mp4: a folder of that name exists",
        ),
        (
            "{out}/user_notes.txt/x.mp4",
            EXIT_OUTPUT,
            r"cannot write to \S+user_notes.txt: the video's folder is a file",
        ),
    ],
)
def test_a_bad_video_option_is_refused_before_the_previous_run_is_touched(
    tmp_path, capsys, video, code, message
):
    """Pass: `--video` naming only a suffix, a folder (trailing slash or an existing folder), an unknown
    suffix, or a place that cannot be written (through a file) exits 2 (parameter) or 3 (output) with
    one line saying why, and the previous run's files, run.json and the user's file are unchanged."""
    out = tmp_path / "out"
    before = previous_run(out)
    (out / "folder.mp4").mkdir()
    argv = ["demo", "--frames", "1", "--out", str(out), "--quiet", "--video", video.format(out=out)]
    assert main(argv) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(message, err[0]), err
    assert contents(out) == before


def test_run_scene_checks_the_video_before_touching_the_folder(tmp_path):
    """Pass: run_scene(video=".mp4") is a ParameterError naming `video`, and nothing changed."""
    out = tmp_path / "out"
    before = previous_run(out)
    with pytest.raises(ParameterError, match=r"video must name .* got '\.mp4'"):
        run_scene(tiny_scene(), frames=1, out_dir=out, progress=False, video=".mp4")
    assert contents(out) == before


def small_video_frames(scene):
    """Skip the 960 x 720 renderer: every video frame is a small grey image."""
    scene.render_frame = lambda *args, **kwargs: np.full((48, 64, 3), 128, dtype=np.uint8)
    return scene


def test_stale_videos_and_video_temporaries_of_killed_runs_are_cleaned(tmp_path):
    """Pass: a killed run's default video (tiny.mp4, tiny.gif: run.json "running", listing nothing) is
    removed by the next run into the folder; a video written outside the folder removes the
    temporaries of its own name there (`.clip.tmp-*.mp4`) and nothing else (other names, other
    suffixes, the user's files); the video holds the run's 3 frames."""
    from taichi_anim.render.video import video_frame_count

    out, videos = tmp_path / "out", tmp_path / "videos"
    out.mkdir()
    videos.mkdir()
    for name in ("tiny.mp4", "tiny.gif", "user_clip.mp4"):
        (out / name).write_bytes(b"x")
    write_manifest(out, {"scene": "tiny"}, {}, status="running")
    stale = [".clip.tmp-0badf00d.mp4", ".clip.tmp-12345678.mp4"]
    kept = [".clip.tmp-0badf00d.gif", ".other.tmp-0badf00d.mp4", "clip.mp4.bak", "other.mp4"]
    for name in stale + kept:
        (videos / name).write_bytes(b"half")
    summary = run_scene(
        small_video_frames(tiny_scene()), frames=3, out_dir=out, progress=False, video=videos / "clip.mp4"
    )
    assert (
        "tiny.mp4" not in listing(out) and "tiny.gif" not in listing(out) and "user_clip.mp4" in listing(out)
    )
    assert listing(videos) == sorted([*kept, "clip.mp4"])
    assert video_frame_count(videos / "clip.mp4") == 3 and summary["files_removed"] == 4


def test_an_os_error_from_a_tool_is_one_line_without_its_command_line(monkeypatch, tmp_path, capsys):
    """Pass: an OSError that reaches the CLI with a tool's command line and log in its message (as
    imageio-ffmpeg's broken pipe does) exits 3 with one line: its first line, none of the command."""
    import taichi_anim.scenes.runner as runner

    def encoder_died(*args, **kwargs):
        raise OSError("[Errno 32] Broken pipe\n\nFFMPEG COMMAND:\nffmpeg -y -f rawvideo out.mp4\n")

    monkeypatch.setattr(runner, "run_scene", encoder_died)
    assert main(["demo", "--frames", "1", "--out", str(tmp_path), "--quiet"]) == EXIT_OUTPUT
    assert capsys.readouterr().err.strip().splitlines() == ["taichi-anim: error: [Errno 32] Broken pipe"]


# ---------------------------------------------------------------------------- run.json not a file


def test_run_json_that_is_a_fifo_or_a_link_to_dev_zero_is_refused_at_once(tmp_path):
    """Pass (in a subprocess with a timeout, so a hang fails): with run.json a FIFO, or a symbolic link to
    /dev/zero, the CLI exits 3 within seconds with one line naming run.json and what it is; the
    previous frames stay and so does the FIFO or link (something else made it)."""
    fifo, zero = tmp_path / "fifo", tmp_path / "zero"
    for out in (fifo, zero):
        out.mkdir()
        (out / "tiny_0000.ply").write_text("previous frame")
    os.mkfifo(fifo / "run.json")
    (zero / "run.json").symlink_to("/dev/zero")
    code = (
        "import sys\n"
        "from taichi_anim.cli import main\n"
        "for out in sys.argv[1:]:\n"
        "    print(main(['demo', '--frames', '1', '--quiet', '--out', out]), flush=True)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, str(fifo), str(zero)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=120,
    )
    codes = [line for line in proc.stdout.splitlines() if line.isdigit()]  # Taichi prints a banner too
    assert codes == [str(EXIT_OUTPUT)] * 2, proc.stderr
    err = [line for line in proc.stderr.splitlines() if line.startswith("taichi-anim:")]
    assert len(err) == 2
    assert str(fifo / "run.json") in err[0] and "FIFO" in err[0]
    assert str(zero / "run.json") in err[1] and "character device" in err[1]
    for out in (fifo, zero):
        assert (out / "tiny_0000.ply").read_text() == "previous frame"
    assert (fifo / "run.json").is_fifo() and (zero / "run.json").is_symlink()


@contextlib.contextmanager
def alarm(seconds: int):
    """Fail instead of hanging: SIGALRM interrupts a blocked open() or read() in this thread."""

    def hung(sig, frame):
        raise TimeoutError(f"still blocked after {seconds} s")

    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_read_manifest_refuses_what_is_not_a_bounded_regular_file(tmp_path):
    """Pass: read_manifest on a FIFO, a link to /dev/zero and a 65 MiB file raises ValueError saying why,
    each at once (an alarm fails the test after 10 s)."""
    os.mkfifo(tmp_path / "fifo.json")
    (tmp_path / "zero.json").symlink_to("/dev/zero")
    with open(tmp_path / "big.json", "wb") as f:
        f.truncate(65 << 20)  # sparse: no disk space used
    with alarm(10):
        with pytest.raises(ValueError, match="FIFO"):
            read_manifest(tmp_path / "fifo.json")
        with pytest.raises(ValueError, match="character device"):
            read_manifest(tmp_path / "zero.json")
        with pytest.raises(ValueError, match="larger than 64 MiB"):
            read_manifest(tmp_path / "big.json")


# ---------------------------------------------------------------------------------------- compile


def test_compile_time_is_measured_not_inferred(tmp_path):
    """Pass: a run whose first frame compiles the step kernels (a fresh Taichi runtime) reports
    compile_s > 0, no more than its first frame, with >= 1 kernel; a second run of the same scene, whose
    kernels are compiled, reports exactly 0 s and 0 kernels (the old estimate, first frame minus the
    median, was neither: noise around 0 or a slow first frame taken for compiling); Taichi's Kernel is
    left as it was."""
    from taichi.lang.kernel_impl import Kernel

    methods = (Kernel.materialize, Kernel.launch_kernel)
    scene = tiny_scene()
    first = run_scene(scene, frames=3, out_dir=tmp_path, progress=False)
    assert 0 < first["compile_s"] <= first["first_frame_s"] and first["compile_kernels"] >= 1
    again = run_scene(scene, frames=3, out_dir=tmp_path, progress=False)
    assert again["compile_s"] == 0.0 and again["compile_kernels"] == 0
    assert "compile 0.00 s" in summary_line(again)
    assert read_manifest(tmp_path)["timings"]["compile_kernels"] == 0
    assert (Kernel.materialize, Kernel.launch_kernel) == methods
