"""USD export (taichi_anim/io/usd.py): the stage a run writes with `--format usd|both`, read back with
pxr. Each test's docstring states its pass criterion."""

import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.cli import EXIT_OUTPUT, main
from taichi_anim.content import Mesh, Points
from taichi_anim.errors import DivergenceError, OutputError, ParameterError
from taichi_anim.io import UsdStageWriter, frame_path, read_manifest, read_point_cloud, read_triangle_mesh
from taichi_anim.io.atomic import file_record, incomplete_reason
from taichi_anim.scenes import Scene, make_scene
from taichi_anim.scenes.runner import run_scene

from .hard_cases.test_output import file_size_limit, tiny_scene

Usd = pytest.importorskip("pxr.Usd")  # usd-core is a core dependency; pxr is imported lazily (ruff)
UsdGeom = pytest.importorskip("pxr.UsdGeom")

TEMPORARY = re.compile(r"\..*\.tmp-[0-9a-f]{8}\..*")


def open_stage(path: Path) -> Usd.Stage:
    stage = Usd.Stage.Open(str(path))
    assert stage is not None
    return stage


def validation_errors(stage: Usd.Stage) -> list[str]:
    """usdchecker's findings of type Error: its engine is UsdValidation in OpenUSD >= 25.08 and
    UsdUtils.ComplianceChecker before."""
    try:
        from pxr import UsdValidation
    except ImportError:
        from pxr.UsdUtils.complianceChecker import ComplianceChecker

        checker = ComplianceChecker()
        checker.CheckCompliance(stage.GetRootLayer().identifier)
        return list(checker.GetErrors())
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    found = UsdValidation.ValidationContext(validators).Validate(stage)
    return [e.GetMessage() for e in found if e.GetType() == UsdValidation.ValidationErrorType.Error]


def run(name: str, tmp_path: Path, fmt: str, frames: int, **options) -> tuple[Scene, dict]:
    scene = make_scene(name, **options)
    summary = run_scene(scene, frames=frames, out_dir=tmp_path, progress=False, export_format=fmt)
    return scene, summary


def world(stage: Usd.Stage, path: str, code: float) -> np.ndarray:
    """The points of the prim at `path` in world space at time `code`."""
    prim = stage.GetPrimAtPath(path)
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(code))
    p = np.array(UsdGeom.PointBased(prim).GetPointsAttr().Get(code), dtype=np.float64)
    return p @ m[:3, :3] + m[3, :3]  # Gf matrices act on row vectors


# ------------------------------------------------------------------------------------------ content


def test_fountain_stage_metadata_and_points_equal_the_ply_frames(tmp_path):
    """Pass: `--format both` on the fountain writes fountain.usd beside the PLY frames; the stage declares
    Y up, 1 m per unit, time codes and frames per second = 1 / frame_dt, codes 1..3, default prim /World;
    at code k + 1 its points, colours, velocities and ids equal PLY frame k (float32), widths are
    2 * point_radius; the trails are time-sampled curves; run.json records export_format and lists the
    stage with its true size and SHA-256; usdchecker's engine finds no error."""
    assert (
        main(["demo", "fountain", "--frames", "3", "--out", str(tmp_path), "--quiet", "--format", "both"])
        == 0
    )
    doc = read_manifest(tmp_path)
    assert doc["settings"]["export_format"] == "both"
    listed = {f["path"]: f for f in doc["files"]}
    assert listed["fountain.usd"] == file_record(tmp_path / "fountain.usd", tmp_path)
    stage = open_stage(tmp_path / "fountain.usd")
    fps = 1.0 / doc["settings"]["frame_dt"]
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == pytest.approx(
        fps
    ) and stage.GetFramesPerSecond() == pytest.approx(fps)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1.0, 3.0)
    assert stage.GetDefaultPrim().GetPath() == "/World"
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/fountain"))
    assert points.GetPointsAttr().GetTimeSamples() == [1.0, 2.0, 3.0]
    for k in range(3):
        ply = read_point_cloud(frame_path(tmp_path, "fountain", k))
        code = k + 1.0
        x = np.array(points.GetPointsAttr().Get(code))
        assert len(x) == len(ply["points"]) > 0
        assert np.array_equal(x, ply["points"].astype(np.float32))
        color = np.array(points.GetDisplayColorPrimvar().Get(code))
        assert np.allclose(color, ply["colors"], atol=0.5 / 255 + 1e-6)  # PLY keeps 8-bit colours
        v = np.array(points.GetVelocitiesAttr().Get(code))
        assert np.array_equal(v, ply["velocity"].astype(np.float32))
        ids = np.array(points.GetIdsAttr().Get(code))
        assert len(np.unique(ids)) == len(ids) == len(x)
        age = np.array(UsdGeom.PrimvarsAPI(points).GetPrimvar("age").Get(code))
        assert np.array_equal(age, ply["age"].astype(np.float32).reshape(-1))
    assert list(points.GetWidthsAttr().Get()) == pytest.approx([0.02])  # constant, 2 x point_radius
    trails = UsdGeom.BasisCurves(stage.GetPrimAtPath("/World/fountain_trails"))
    assert trails.GetTypeAttr().Get() == UsdGeom.Tokens.linear
    assert trails.GetPointsAttr().GetNumTimeSamples() == 3
    box = stage.GetPrimAtPath("/World/colliders/container0")
    assert (
        box.GetTypeName() == "BasisCurves"
        and box.GetCustomDataByKey("taichi_anim:collider")["kind"] == "container"
    )
    assert validation_errors(stage) == []


def test_cloth_topology_is_authored_once_and_points_follow_the_frames(tmp_path):
    """Pass: the cloth demo's mesh has faceVertexIndices / counts without time samples, equal to the PLY's
    triangles; points and unit vertex normals are time-sampled and equal the PLY frames (float32);
    doubleSided, subdivisionScheme none and a displayColor are authored; the pins' bar is a guide."""
    scene, _ = run("cloth", tmp_path, "both", 2, resolution=8, integrator="implicit_euler")
    stage = open_stage(tmp_path / "cloth.usd")
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/cloth"))
    assert mesh.GetFaceVertexIndicesAttr().GetNumTimeSamples() == 0
    assert mesh.GetFaceVertexCountsAttr().GetNumTimeSamples() == 0
    assert mesh.GetPointsAttr().GetTimeSamples() == [1.0, 2.0]
    for k in range(2):
        ply = read_triangle_mesh(frame_path(tmp_path, "cloth", k))
        assert np.array_equal(
            np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), ply["triangles"]
        )
        assert np.array_equal(np.array(mesh.GetPointsAttr().Get(k + 1.0)), ply["vertices"].astype(np.float32))
        n = np.array(mesh.GetNormalsAttr().Get(k + 1.0))
        assert np.allclose(n, ply["vertex_normals"], atol=1e-6)
        assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert set(np.array(mesh.GetFaceVertexCountsAttr().Get())) == {3}
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    assert mesh.GetDoubleSidedAttr().Get() is True
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert len(mesh.GetDisplayColorPrimvar().Get()) == 1
    guide = UsdGeom.Imageable(stage.GetPrimAtPath("/World/cloth_guides"))
    assert guide.GetPurposeAttr().Get() == UsdGeom.Tokens.guide
    assert validation_errors(stage) == []


def test_blob_surface_topology_is_time_sampled(tmp_path):
    """Pass: the blobs demo's surface mesh has time-sampled topology (its triangles change every frame),
    and at each code it equals the PLY frame's mesh; the particles beside it are Points."""
    ta.init("cpu")
    run("blobs", tmp_path, "both", 3, particles=400, resolution=40)
    stage = open_stage(tmp_path / "blobs.usd")
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/blobs_mesh"))
    assert mesh.GetFaceVertexIndicesAttr().GetTimeSamples() == [1.0, 2.0, 3.0]
    assert mesh.GetFaceVertexCountsAttr().GetNumTimeSamples() == 3
    sizes = set()
    for k in range(3):
        ply = read_triangle_mesh(frame_path(tmp_path, "blobs_mesh", k))
        tri = np.array(mesh.GetFaceVertexIndicesAttr().Get(k + 1.0)).reshape(-1, 3)
        assert np.array_equal(tri, ply["triangles"]) and len(tri) > 0
        assert np.array_equal(np.array(mesh.GetPointsAttr().Get(k + 1.0)), ply["vertices"].astype(np.float32))
        assert len(mesh.GetNormalsAttr().Get(k + 1.0)) == len(ply["vertices"])
        sizes.add(len(tri))
    assert len(sizes) > 1  # the topology did change
    assert stage.GetPrimAtPath("/World/blobs").GetTypeName() == "Points"
    assert validation_errors(stage) == []


def test_spheres_widths_are_twice_the_radii(tmp_path):
    """Pass: in the spheres demo's stage, each sphere's width is twice its model radius (by id), and
    usd-only export writes no PLY."""
    ta.init("cpu")
    scene, _ = run("spheres", tmp_path, "usd", 1, particles=300, steps_per_frame=20)
    stage = open_stage(tmp_path / "spheres.usd")
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/spheres"))
    ids = np.array(points.GetIdsAttr().Get(1.0))
    widths = np.array(points.GetWidthsAttr().Get(1.0))
    assert len(widths) == len(ids) == 300
    assert np.allclose(widths, 2.0 * scene.model.particle_radii(ids), rtol=1e-6)
    assert points.GetWidthsInterpolation() == UsdGeom.Tokens.vertex
    assert not list(tmp_path.glob("*.ply"))


def test_colliders_static_once_and_moving_with_their_rigid_motion(tmp_path):
    """Pass: from a model's colliders, a static plane and solid box are meshes without time samples or
    xform ops (the box spans lo..hi); a sphere moved by a RigidMotion (turning and rising) has
    time-sampled translate + orient ops whose world points at each code c equal RigidMotion.apply(local
    points, c / fps) to 1e-9 m, and lie on the sphere; a moving container is 12 edges carried the same
    way; usdchecker's engine finds no error."""
    turn = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, np.sin(0.6), 0.0, np.cos(0.6)], [0.3, 0.0, 0.0, 0.954]])
    motion = ta.RigidMotion([0.0, 0.05, 0.1], [[0.0, 0.0, 0.0], [0.1, 0.2, 0.0], [0.1, 0.3, 0.2]], turn)
    b = ta.Builder()
    b.add_particles(np.array([[0.0, 1.0, 0.0], [0.1, 1.2, 0.0]]))
    b.add_collider_plane((0.0, 1.0, 0.0), 0.0)
    b.add_collider_box((0.5, 0.0, 0.5), (0.7, 0.1, 0.7), solid=True)
    b.add_collider_sphere((0.2, 0.3, 0.0), 0.15, motion=motion)
    b.add_collider_box((-1.0, -1.0, -1.0), (1.0, 2.0, 1.0), motion=motion)
    model = b.finalize()
    path = tmp_path / "movers.usd"
    fps = 60.0
    with UsdStageWriter(path, fps=fps, colliders=model.colliders, bounds=((-1, 0, -1), (1, 2, 1))) as w:
        for k in range(8):  # the pose is sampled at each frame's time, moving and held after 0.1 s
            w.add_frame([Points("", np.zeros((1, 3)), np.zeros((1, 3)), np.array([0]))], time=k / fps)
    stage = open_stage(path)
    kinds = [p.GetName() for p in stage.GetPrimAtPath("/World/colliders").GetChildren()]
    assert kinds == ["plane0", "box1", "sphere2", "container3"]
    for name in ("plane0", "box1"):
        prim = stage.GetPrimAtPath(f"/World/colliders/{name}")
        assert not UsdGeom.Xformable(prim).GetOrderedXformOps()
        assert UsdGeom.Mesh(prim).GetPointsAttr().GetNumTimeSamples() == 0
    plane = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/World/colliders/plane0")).GetPointsAttr().Get())
    assert np.allclose(plane[:, 1], 0.0)
    box = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/World/colliders/box1")).GetPointsAttr().Get())
    assert np.allclose(box.min(axis=0), [0.5, 0.0, 0.5]) and np.allclose(box.max(axis=0), [0.7, 0.1, 0.7])
    for name in ("sphere2", "container3"):
        prim_path = f"/World/colliders/{name}"
        prim = stage.GetPrimAtPath(prim_path)
        ops = UsdGeom.Xformable(prim).GetOrderedXformOps()
        assert [op.GetOpType() for op in ops] == [UsdGeom.XformOp.TypeTranslate, UsdGeom.XformOp.TypeOrient]
        local = np.array(UsdGeom.PointBased(prim).GetPointsAttr().Get(), dtype=np.float64)
        for code in range(8):
            expected = motion.apply(local, code / fps)
            assert np.abs(world(stage, prim_path, code) - expected).max() < 1e-9
    sphere = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/World/colliders/sphere2")).GetPointsAttr().Get())
    assert np.allclose(np.linalg.norm(sphere - [0.2, 0.3, 0.0], axis=1), 0.15, atol=1e-6)
    edges = np.array(
        UsdGeom.BasisCurves(stage.GetPrimAtPath("/World/colliders/container3")).GetPointsAttr().Get()
    )
    assert (
        len(edges) == 24 and np.allclose(edges.min(axis=0), -1) and np.allclose(edges.max(axis=0), [1, 2, 1])
    )
    assert validation_errors(stage) == []


def test_moving_mesh_ball_follows_its_motion(tmp_path):
    """Pass: the moving_mesh demo's ball is written once from the model's mesh collider (its content item
    is not duplicated) and placed by xform ops equal to the scene's RigidMotion at each frame's time,
    while it rises and turns (0.5 to 2.5 s)."""
    scene = make_scene("moving_mesh", resolution=6)
    times = [0.4, 0.9, 1.5, 2.0]
    path = tmp_path / "moving_mesh.usd"
    with UsdStageWriter(path, fps=30, name=scene.name, colliders=scene.model.colliders) as w:
        for t in times:
            w.add_frame(scene.frame_content(), time=t)
    stage = open_stage(path)
    assert not stage.GetPrimAtPath("/World/moving_mesh_ball")
    prim_path = "/World/colliders/mesh0"
    local = scene.ball[0]
    written = np.array(UsdGeom.Mesh(stage.GetPrimAtPath(prim_path)).GetPointsAttr().Get())
    assert np.allclose(written, local, atol=1e-6)
    for t in times:
        expected = scene.motion.apply(local, t)
        assert np.abs(world(stage, prim_path, 30 * t) - expected).max() < 1e-6
    assert np.abs(world(stage, prim_path, 60.0) - world(stage, prim_path, 12.0)).max() > 0.1  # it moved


def test_items_come_and_go_and_point_counts_vary(tmp_path):
    """Pass: with the writer used directly, points whose count changes per frame keep their own count and
    ids at each code; an item absent from a frame is invisible there and visible again after; a static
    mesh is written once (no time samples)."""
    path = tmp_path / "s.usda"
    ground = Mesh("ground", np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1]]), np.array([[0, 2, 1]]),
                  role="collider", animated=False)  # fmt: skip
    with UsdStageWriter(path, fps=24, name="t") as w:
        for k, n in enumerate([3, 5, 2]):
            x = np.full((n, 3), float(k))
            items = [Points("", x, np.zeros((n, 3)), np.arange(n) + k), ground]
            if k != 1:
                items.append(Points("extra", x[:1], np.ones((1, 3)), np.array([7])))
            w.add_frame(items, time=(k + 1) / 24)
    stage = open_stage(path)
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/t"))
    for k, n in enumerate([3, 5, 2]):
        assert len(points.GetPointsAttr().Get(k + 1)) == n
        assert list(points.GetIdsAttr().Get(k + 1)) == list(range(k, k + n))
    extra = UsdGeom.Imageable(stage.GetPrimAtPath("/World/t_extra"))
    assert [extra.ComputeVisibility(c) for c in (1, 2, 3)] == ["inherited", "invisible", "inherited"]
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/World/t_ground")).GetPointsAttr().GetNumTimeSamples() == 0
    assert incomplete_reason(path) is None


# ----------------------------------------------------------------------------------- failures, CLI


def test_truncated_stages_are_incomplete(tmp_path):
    """Pass: a stage cut short (binary crate or text) is reported incomplete by atomic.incomplete_reason;
    a text stage that lost its last prim (a static mesh) but still parses is caught by the prim count
    it records."""
    ground = Mesh("ground", np.eye(3), np.array([[0, 1, 2]]), role="collider", animated=False)
    for suffix in (".usd", ".usda"):
        path = tmp_path / f"s{suffix}"
        with UsdStageWriter(path, fps=30) as w:
            for k in range(4):
                x = np.random.default_rng(k).random((200, 3))
                w.add_frame([Points("", x, x, np.arange(200)), ground], time=(k + 1) / 30)
        assert incomplete_reason(path) is None
        cut = tmp_path / f"cut{suffix}"
        cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
        assert incomplete_reason(cut) is not None
    text = (tmp_path / "s.usda").read_text()
    last = text.rindex('    def Mesh "s_ground"')
    dropped = tmp_path / "dropped.usda"
    dropped.write_text(text[:last] + "}\n")
    assert "3 prims announced, 2 written" in (incomplete_reason(dropped) or "")


def test_full_disk_leaves_no_stage_and_exits_3(tmp_path, monkeypatch, capfd):
    """Pass: when the stage's save meets a 20 kB file size limit, the CLI exits 3 with one line naming the
    stage and the reason, no file of that name nor any temporary is left, and run.json says "failed"."""
    import taichi_anim.scenes as scenes

    def make_scene(name, **options):
        b = ta.Builder()
        b.add_particles(np.random.default_rng(0).random((3000, 3)) + [0.0, 1.0, 0.0])
        m = b.finalize()
        integ = ta.make_integrator("symplectic_euler")
        return Scene("tiny", "", m, m.state(), integ, 1 / 60, 1, ((-1.0, 0.0, -1.0), (1.0, 2.0, 1.0)), 0.01)

    save = UsdStageWriter.save

    def save_on_a_full_disk(self):
        with file_size_limit(20_000):
            return save(self)

    monkeypatch.setattr(scenes, "make_scene", make_scene)
    monkeypatch.setattr(UsdStageWriter, "save", save_on_a_full_disk)
    assert (
        main(["demo", "--frames", "4", "--out", str(tmp_path), "--quiet", "--format", "usd"]) == EXIT_OUTPUT
    )
    err = capfd.readouterr().err.strip().splitlines()
    err = [line for line in err if not line.startswith("[Taichi]")]
    assert len(err) == 1 and "cannot write" in err[0] and str(tmp_path / "tiny.usd") in err[0]
    assert "file size" in err[0]
    assert not (tmp_path / "tiny.usd").exists()
    assert not [p for p in tmp_path.iterdir() if TEMPORARY.fullmatch(p.name)]
    doc = read_manifest(tmp_path)
    assert doc["status"] == "failed" and doc["error"]["type"] == "OutputError" and doc["files"] == []


def test_writer_at_a_file_size_limit_raises_and_keeps_the_previous_stage(tmp_path):
    """Pass: UsdStageWriter.save past a 20 kB limit raises OutputError naming the path; the previous,
    complete stage stays under the name and no temporary is left."""
    path = tmp_path / "s.usd"
    x = np.random.default_rng(1).random((3000, 3))
    with UsdStageWriter(path, fps=30) as w:
        w.add_frame([Points("", x[:5], x[:5], np.arange(5))], time=0.0)
    before = path.read_bytes()
    w = UsdStageWriter(path, fps=30)
    for k in range(4):
        w.add_frame([Points("", x, x, np.arange(3000))], time=k / 30)
    with file_size_limit(20_000), pytest.raises(OutputError, match=re.escape(str(path))):
        w.save()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.usd"] and path.read_bytes() == before


def unstable_scene() -> Scene:
    """Two particles on a stiff spring stepped by explicit Euler beyond its stability limit (omega dt =
    0.7): the energy grows 1.5x per step until the watchdog stops the run a few frames in."""
    b = ta.Builder()
    b.add_particles(np.array([[0.0, 1.0, 0.0], [0.0, 1.1, 0.0]]))
    b.add_springs([[0, 1]], stiffness=1e4, rest_length=0.05)
    m = b.finalize()
    integ = ta.make_integrator("explicit_euler")
    return Scene("unstable", "", m, m.state(), integ, 0.005, 1, ((-1.0, 0.0, -1.0), (1.0, 2.0, 1.0)), 0.01)


def test_a_diverged_run_saves_the_frames_before_the_divergence(tmp_path):
    """Pass: a run that diverges after a few frames raises DivergenceError, and its stage holds exactly
    the frames the PLY export wrote (codes 1..K for PLY frames 0..K-1, all finite), is listed in run.json
    ("diverged") and is complete."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(DivergenceError):
            run_scene(unstable_scene(), frames=40, out_dir=tmp_path, progress=False, export_format="both")
    plys = sorted(tmp_path.glob("unstable_*.ply"))
    assert len(plys) >= 2
    stage = open_stage(tmp_path / "unstable.usd")
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/unstable")).GetPointsAttr()
    assert points.GetTimeSamples() == [float(k + 1) for k in range(len(plys))]
    assert stage.GetEndTimeCode() == len(plys)
    for k in range(len(plys)):
        x = np.array(points.Get(k + 1))
        assert np.all(np.isfinite(x))
        assert np.array_equal(
            x, read_point_cloud(frame_path(tmp_path, "unstable", k))["points"].astype(np.float32)
        )
    doc = read_manifest(tmp_path)
    assert doc["status"] == "diverged" and "unstable.usd" in [f["path"] for f in doc["files"]]
    assert incomplete_reason(tmp_path / "unstable.usd") is None


def test_bad_format_no_export_and_stale_stage(tmp_path, capsys):
    """Pass: `--format obj` exits 2 naming the value; run_scene(export_format="obj") is a ParameterError
    naming it; `--format usd --no-export` writes no stage; a run of the same scene in PLY removes a stale
    tiny.usd from an earlier run (and a user's file stays)."""
    with pytest.raises(SystemExit) as info:
        main(["demo", "--format", "obj", "--out", str(tmp_path)])
    assert info.value.code == 2 and "'obj'" in capsys.readouterr().err
    with pytest.raises(ParameterError, match="export_format 'obj'"):
        run_scene(tiny_scene(), frames=1, out_dir=tmp_path, export_format="obj")
    run_scene(tiny_scene(), frames=2, out_dir=tmp_path, progress=False, export=False, export_format="usd")
    assert not (tmp_path / "tiny.usd").exists()
    run_scene(tiny_scene(), frames=2, out_dir=tmp_path, progress=False, export_format="usd")
    assert (tmp_path / "tiny.usd").exists()
    shutil.copy(tmp_path / "tiny.usd", tmp_path / "user_tiny.usd")
    run_scene(tiny_scene(), frames=2, out_dir=tmp_path, progress=False, export_format="ply")
    names = sorted(p.name for p in tmp_path.iterdir())
    assert "tiny.usd" not in names and "user_tiny.usd" in names and "tiny_0001.ply" in names
