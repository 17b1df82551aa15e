"""Hard cases for output: a full disk, a read-only folder, `--out` on a file, temporaries of killed runs,
re-runs into the same folder, divergence with a lazy watch, interrupts. Each test's docstring states
its pass criterion. Full disks are simulated without root by a file size limit (RLIMIT_FSIZE with
SIGXFSZ ignored, so writes past it fail with EFBIG as they fail with ENOSPC on a full disk)."""

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.cli import EXIT_OUTPUT, EXIT_SIMULATION, main
from taichi_anim.errors import DivergenceError, OutputError
from taichi_anim.io import (
    frame_path,
    read_line_set,
    read_manifest,
    read_point_cloud,
    write_line_set,
    write_manifest,
    write_point_cloud,
    write_triangle_mesh,
)
from taichi_anim.io.atomic import check_complete, file_record
from taichi_anim.scenes import Scene
from taichi_anim.scenes.runner import run_scene, summary_line

resource = pytest.importorskip("resource")  # POSIX only
ROOT = Path(__file__).resolve().parents[2]
TEMPORARY = re.compile(r"\..*\.tmp-[0-9a-f]{8}")


@contextlib.contextmanager
def file_size_limit(nbytes: int):
    """Writes beyond `nbytes` in any one file fail with EFBIG (instead of killing the process)."""
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, handler)


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def tiny_scene(name="tiny", *, velocity=(0.0, 0.0, 0.0), dt=1 / 60, check_every=1) -> Scene:
    """Three falling particles: the cheapest scene that goes through the whole runner."""
    b = ta.Builder()
    b.add_force_gravity((0.0, -9.81, 0.0))
    b.add_particles(np.array([[0.0, 1.0, 0.0], [0.1, 1.0, 0.0], [0.2, 1.0, 0.0]]), np.tile(velocity, (3, 1)))
    model = b.finalize()
    return Scene(
        name=name,
        description="three falling particles",
        model=model,
        state=model.state(),
        integrator=ta.make_integrator("symplectic_euler", check_every=check_every),
        dt=dt,
        substeps=1,
        bounds=((-1.0, 0.0, -1.0), (1.0, 2.0, 1.0)),
        point_radius=0.01,
    )


def assert_manifest_matches_folder(out: Path, *, status: str) -> dict:
    """run.json has `status` and lists exactly the files in the folder (besides itself and files named in
    `keep`), each with its true size and SHA-256; every listed PLY is complete."""
    doc = read_manifest(out)
    assert doc["status"] == status
    listed = {f["path"]: f for f in doc["files"]}
    present = {p.name for p in out.iterdir() if p.name != "run.json" and not p.name.startswith("user_")}
    assert set(listed) == present
    for name, entry in listed.items():
        assert file_record(out / name, out) == entry
        if name.endswith(".ply"):
            check_complete(out / name, "frame")
    assert not [n for n in listing(out) if TEMPORARY.fullmatch(n)]
    return doc


# ------------------------------------------------------------------------------------------ full disk


@pytest.mark.slow
def test_full_disk_fountain_cli_fails_cleanly(tmp_path):
    """The issue's reproduction (slow: a fresh process compiles the fountain, ~10 s on an idle 2-core CPU).
    Pass: the fountain demo with a 60 kB file size limit exits with code 3 and one line on stderr naming
    the file; no truncated file is left under a final name, no temporary is left, and run.json says
    "failed" (OutputError) and lists exactly the complete files that are there, sizes and SHA-256 true."""
    out = tmp_path / "out"
    code = (
        "import resource, signal, sys\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (60000, resource.RLIM_INFINITY))\n"
        "from taichi_anim.cli import main\n"
        f"sys.exit(main(['demo', 'fountain', '--frames', '8', '--out', {str(out)!r}, '--quiet']))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == EXIT_OUTPUT, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("taichi-anim:")]
    assert len(errors) == 1 and "cannot write" in errors[0] and str(out) in errors[0]
    assert "RPly" not in proc.stderr  # Open3D's per-value complaints are not shown
    doc = assert_manifest_matches_folder(out, status="failed")
    assert doc["error"]["type"] == "OutputError" and doc["files"]  # some frames were written before
    failed = re.search(r"cannot write (\S+):", errors[0]).group(1)
    assert not Path(failed).exists()
    for f in doc["files"]:
        reader = read_line_set if "trails" in f["path"] else read_point_cloud
        assert len(reader(out / f["path"])["points"]) > 0


def test_full_disk_through_the_cli_exits_3_with_run_json_failed(tmp_path, monkeypatch, capsys):
    """Pass: when the disk fills while the last picture is written (a 6 kB file size limit around the
    render; frames are 0.5 kB, the picture ~16 kB), the CLI exits 3 with one line on stderr naming the
    picture, the picture is absent (not truncated), and run.json says "failed" and lists exactly the
    frames, which are complete."""
    import taichi_anim.scenes as scenes

    def make_scene(name, **options):
        scene = tiny_scene()
        render = scene.render

        def render_on_a_full_disk(path, *args, **kwargs):
            with file_size_limit(6_000):
                return render(path, *args, **kwargs)

        scene.render = render_on_a_full_disk
        return scene

    monkeypatch.setattr(scenes, "make_scene", make_scene)
    assert main(["demo", "--frames", "3", "--out", str(tmp_path), "--quiet"]) == EXIT_OUTPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("taichi-anim: error: cannot write")
    assert "tiny_last.png" in err[0]
    doc = assert_manifest_matches_folder(tmp_path, status="failed")
    assert [f["path"] for f in doc["files"]] == ["tiny_0000.ply", "tiny_0001.ply", "tiny_0002.ply"]
    assert doc["error"]["type"] == "OutputError" and "tiny_last.png" not in listing(tmp_path)


@pytest.mark.parametrize("kind", ["ply", "pcd", "xyz", "mesh_ply", "mesh_obj", "lines", "json"])
def test_each_writer_at_a_file_size_limit_raises_and_keeps_the_previous_version(tmp_path, kind):
    """Pass: for every format we write, a write cut off by a 20 kB file size limit raises OutputError
    naming the file, leaves no temporary, and the complete previous version stays under the name."""
    rng = np.random.default_rng(5)
    big = rng.random((3000, 3))
    tri = rng.integers(0, 3000, (3000, 3))
    writers = {
        "ply": ("p.ply", lambda p, x: write_point_cloud(p, x, attributes={"v": x})),
        "pcd": ("p.pcd", lambda p, x: write_point_cloud(p, x, attributes={"a": x[:, 0]})),
        "xyz": ("p.xyz", write_point_cloud),
        "mesh_ply": ("m.ply", lambda p, x: write_triangle_mesh(p, x, tri[tri.max(1) < len(x)])),
        "mesh_obj": ("m.obj", lambda p, x: write_triangle_mesh(p, x, tri[tri.max(1) < len(x)])),
        "lines": ("l.ply", lambda p, x: write_line_set(p, x, np.arange(len(x) - 1)[:, None] + [0, 1])),
        "json": ("run.json", lambda p, x: write_manifest(p.parent, {"x": x}, {})),
    }
    name, write = writers[kind]
    path = tmp_path / name
    write(path, big[:10])  # a small, complete previous version
    before = path.read_bytes()
    with file_size_limit(20_000), pytest.raises(OutputError, match=re.escape(str(path))) as info:
        write(path, big)
    assert re.search("incomplete|file size|could not write", str(info.value))
    assert listing(tmp_path) == [name] and path.read_bytes() == before


def test_disk_full_at_flush_is_an_output_error(tmp_path, monkeypatch):
    """Pass: ENOSPC reported only when the file is flushed (delayed allocation) is an OutputError saying
    the device is full; the previous version and no temporary remain."""
    write_point_cloud(tmp_path / "p.ply", np.zeros((2, 3)))
    before = (tmp_path / "p.ply").read_bytes()

    def full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError, match="no space left"):
        write_point_cloud(tmp_path / "p.ply", np.ones((5, 3)))
    assert listing(tmp_path) == ["p.ply"] and (tmp_path / "p.ply").read_bytes() == before


# -------------------------------------------------------------------------------- folders and --out


def test_out_is_a_file_is_a_one_line_error(tmp_path, capsys):
    """Pass: `--out` naming a file (or a path through a file) exits 3 with one line on stderr saying it is
    a file; the file is untouched."""
    f = tmp_path / "notes.txt"
    f.write_text("mine")
    for out in (f, f / "sub"):
        assert main(["demo", "--frames", "1", "--out", str(out), "--quiet"]) == EXIT_OUTPUT
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "is a file" in err[0] and str(f) in err[0]
    assert f.read_text() == "mine"


def test_read_only_folder_is_a_one_line_error(tmp_path, capsys):
    """Pass: a read-only `--out` folder exits 3 with one line on stderr saying writing is not permitted,
    and nothing is written. Root ignores permission bits, so as root the folder is made immutable
    (chattr +i) instead; the test is skipped where neither is possible."""
    out = tmp_path / "ro"
    out.mkdir()
    if os.geteuid() != 0:
        out.chmod(0o555)
        undo = ["chmod", "755", str(out)]
    elif shutil.which("chattr") and subprocess.run(["chattr", "+i", str(out)], check=False).returncode == 0:
        undo = ["chattr", "-i", str(out)]
    else:
        pytest.skip("running as root without chattr: a read-only folder cannot be made")
    try:
        assert main(["demo", "--frames", "1", "--out", str(out), "--quiet"]) == EXIT_OUTPUT
        assert listing(out) == []
    finally:
        subprocess.run(undo, check=True)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out) in err[0]
    assert re.search("permission denied|not permitted", err[0])


def test_stale_temporaries_of_killed_runs_are_removed_when_a_run_starts(tmp_path):
    """Pass: hidden `.NAME.tmp-XXXXXXXX.ext` files in the output folder are gone after a run starts
    there; a user's files, even with similar names, stay."""
    stale = [".tiny_0003.tmp-0badf00d.ply", ".run.tmp-12345678.json", ".tiny_last.tmp-abcdef01.png"]
    mine = ["user_notes.txt", "user_tiny.tmp-0badf00d.ply", ".user_hidden"]
    for n in stale + mine:
        (tmp_path / n).write_bytes(b"ply\nhalf")
    run_scene(tiny_scene(), frames=2, out_dir=tmp_path, progress=False)
    names = listing(tmp_path)
    assert not set(stale) & set(names) and set(mine) <= set(names)


def test_rerun_with_fewer_frames_replaces_the_previous_run(tmp_path):
    """Pass: a 12-frame run names its frames tiny_0000..tiny_0011; a 5-frame run into the same folder
    leaves only its own 5 frames and picture beside the user's file, and run.json ("complete") lists
    exactly those files with true sizes and SHA-256."""
    (tmp_path / "user_scene.blend").write_text("keep me")
    run_scene(tiny_scene(), frames=12, out_dir=tmp_path, progress=False)
    assert [n for n in listing(tmp_path) if n.endswith(".ply")] == [f"tiny_{i:04d}.ply" for i in range(12)]
    summary = run_scene(tiny_scene(), frames=5, out_dir=tmp_path, progress=False)
    assert listing(tmp_path) == sorted(
        [f"tiny_{i:04d}.ply" for i in range(5)] + ["tiny_last.png", "run.json", "user_scene.blend"]
    )
    doc = assert_manifest_matches_folder(tmp_path, status="complete")
    assert summary["files_removed"] == 13 and summary["files_written"] == 6 == len(doc["files"])
    assert doc["timings"]["frames_done"] == 5 and doc["settings"]["frames"] == 5


def test_a_killed_run_of_another_scene_is_cleared(tmp_path):
    """Pass: after a run of scene "other" was killed (run.json still "running", no file list), a run of
    "tiny" in the same folder removes other's frames; files of neither scene stay."""
    for n in ("other_0000.ply", "other_trails_0000.ply", "other_0001.ply", "otherwise_0000.ply"):
        (tmp_path / n).write_bytes(b"x")
    write_manifest(tmp_path, {"scene": "other"}, {}, status="running")
    run_scene(tiny_scene(), frames=1, out_dir=tmp_path, progress=False)
    assert listing(tmp_path) == ["otherwise_0000.ply", "run.json", "tiny_0000.ply", "tiny_last.png"]


def test_run_json_says_running_while_the_run_goes_on(tmp_path):
    """Pass: during the run (seen from inside its export), run.json exists with status "running"."""
    scene = tiny_scene()
    seen = []
    export = scene.export_frame
    scene.export_frame = lambda out, frame, *items: (
        seen.append(read_manifest(out)["status"]) or export(out, frame, *items)
    )
    run_scene(scene, frames=2, out_dir=tmp_path, progress=False)
    assert seen == ["running", "running"] and read_manifest(tmp_path)["status"] == "complete"


# ---------------------------------------------------------------------------------- failed runs


def test_divergence_with_a_lazy_watch_exports_nothing_after_the_bad_step(tmp_path):
    """Pass: particles launched at 1e38 m/s (dt = 1 s) overflow float32 to inf within 4 steps; with the
    watch read only every 4 steps, the run still raises DivergenceError, exports exactly the frames
    before the bad step (frame k holds step k+1; so none after it, although the watch saw it late), no
    picture, and run.json says "diverged" with the step."""
    ta.init("cpu")  # float32, so the overflow happens within a few steps
    scene = tiny_scene(velocity=(1e38, 0.0, 0.0), dt=1.0, check_every=4)
    with pytest.raises(DivergenceError) as info:
        run_scene(scene, frames=8, out_dir=tmp_path, progress=False)
    e = info.value
    bad = e.step if e.step is not None else int(re.search(r"step (\d+)", str(e)).group(1))
    assert 1 <= bad <= 4 and bad % 4 != 0  # the integrator's own watch would only see it at step 4
    frames = sorted(int(n[5:9]) for n in listing(tmp_path) if n.endswith(".ply"))
    assert frames == list(range(bad - 1))
    for k in frames:
        assert np.all(np.isfinite(read_point_cloud(frame_path(tmp_path, "tiny", k))["points"]))
    doc = assert_manifest_matches_folder(tmp_path, status="diverged")
    assert doc["error"]["type"] == "DivergenceError"
    assert set(doc["error"]) >= {"message", "step", "particle", "quantity", "value"}
    assert "tiny_last.png" not in listing(tmp_path)


def test_interrupt_marks_the_run_failed_and_lists_what_was_written(tmp_path):
    """Pass: Ctrl-C during frame 2's export propagates, and run.json says "failed" (KeyboardInterrupt)
    and lists frames 0 and 1, which are complete."""
    scene = tiny_scene()
    export = scene.export_frame

    def interrupted(out, frame, *items):
        if frame == 2:
            raise KeyboardInterrupt
        return export(out, frame, *items)

    scene.export_frame = interrupted
    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, frames=5, out_dir=tmp_path, progress=False)
    doc = assert_manifest_matches_folder(tmp_path, status="failed")
    assert doc["error"]["type"] == "KeyboardInterrupt"
    assert [f["path"] for f in doc["files"]] == ["tiny_0000.ply", "tiny_0001.ply"]


def test_health_counts_reach_the_summary_line_and_run_json(tmp_path):
    """Pass: counts in the stepper's Health appear in the summary, run.json's "health", and briefly in
    the summary line; a run with no counts says nothing about health."""
    scene = tiny_scene()
    clean = run_scene(scene, frames=1, out_dir=tmp_path, progress=False)
    assert "health:" not in summary_line(clean) and clean["health"]["counts"] == {}
    scene = tiny_scene()
    scene.integrator.stepper_for(scene.model).health.count("linear_unconverged", 3)
    s = run_scene(scene, frames=1, out_dir=tmp_path, progress=False)
    assert s["health"]["counts"] == {"linear_unconverged": 3}
    assert read_manifest(tmp_path)["health"]["counts"] == {"linear_unconverged": 3}
    assert "health: linear_unconverged 3" in summary_line(s)


def test_cli_exit_code_for_a_diverged_run(monkeypatch, tmp_path, capsys):
    """Pass: a DivergenceError from the run exits with code 4 and one line on stderr."""
    import taichi_anim.scenes.runner as runner

    def diverge(*args, **kwargs):
        raise DivergenceError("simulation diverged at step 7", step=7)

    monkeypatch.setattr(runner, "run_scene", diverge)
    assert main(["demo", "--frames", "1", "--out", str(tmp_path), "--quiet"]) == EXIT_SIMULATION
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["taichi-anim: error: simulation diverged at step 7"]
