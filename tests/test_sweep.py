"""Parameter sweeps (taichi_anim.sweep): expansion, names refused up front, isolated runs, failures and
timeouts as rows, re-runs that keep complete runs, the error against a reference run, a Dask cluster
giving the local result, and the command line. The runs use a 5 x 5 cloth so that each is a second or two."""

import json
import time

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.cli import main
from taichi_anim.errors import ParameterError
from taichi_anim.scenes import Scene
from taichi_anim.sweep import expand, parse_param, parse_value, rms_distance, run_id, sweep

SUBSTEPS = [4, 8, 16]
FIXED = {"frames": 2, "export": False}


def tiny_cloth(*, substeps=4, seed=0, stiffness=50.0, fail="none", sleep=0.0):
    """A 0.3 m cloth of 5 x 5 vertices pinned at two corners, symplectic Euler (stable for substeps >= 2
    at this stiffness [N/m] and density); fail: "raise" in the build, "diverge" (a stiffness far past
    the step's stability limit); sleep [s] before building."""
    if sleep:
        time.sleep(sleep)
    if fail == "raise":
        raise ValueError("tiny_cloth was asked to fail")
    if fail == "diverge":
        stiffness, substeps = 1e6, 1
    b = ta.Builder()
    b.add_force_gravity()
    mat = ta.ClothMaterial(
        density=2.0,
        stretch_stiffness=stiffness,
        shear_stiffness=stiffness / 10,
        bend_stiffness=stiffness / 100,
    )
    b.add_cloth_grid(
        origin=(0, 1, 0), size=(0.3, 0.3), resolution=(5, 5), plane="xz", material=mat, pinned=[0, 4]
    )
    model = b.finalize(seed=seed)
    return Scene(
        name="tiny",
        description="a tiny cloth",
        model=model,
        state=model.state(),
        integrator=ta.make_integrator("symplectic_euler"),
        dt=1 / 60 / substeps,
        substeps=substeps,
        bounds=((-0.1, 0.6, -0.1), (0.4, 1.1, 0.4)),
        point_radius=0.01,
        frames=2,
    )


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """The cloth at 4, 8 and 16 substeps, compared with 16, with the warm-up run."""
    out = tmp_path_factory.mktemp("sweep")
    return sweep(
        tiny_cloth, {"substeps": SUBSTEPS}, out=out, reference={"substeps": 16}, progress=False, **FIXED
    )


def test_product_and_list_expansion():
    rows = expand({"a": [1, 2], "b": ["x", "y"]})
    assert rows == [{"a": 1, "b": "x"}, {"a": 1, "b": "y"}, {"a": 2, "b": "x"}, {"a": 2, "b": "y"}]
    assert expand({"a": [1, 2], "b": ["x", "y"]}, "list") == [{"a": 1, "b": "x"}, {"a": 2, "b": "y"}]
    with pytest.raises(ParameterError, match="one length, got a 2, b 3"):
        expand({"a": [1, 2], "b": [1, 2, 3]}, "list")
    with pytest.raises(ParameterError, match="repeats run 0"):
        expand({"a": [1, 1]})
    with pytest.raises(ParameterError, match="'a': give a list"):
        expand({"a": 3})


def test_run_ids_are_readable_and_safe():
    assert run_id({"substeps": 4, "seed": 1}) == "substeps=4_seed=1"
    assert run_id({"integrator": "rk4", "export": False, "wind": [6, 0, 1]}) == (
        "integrator=rk4_export=false_wind=6,0,1"
    )
    assert run_id({"path": "../a b/c"}) == "path=..-a-b-c"
    long = run_id({"name": "x" * 300})
    assert len(long) == 120 and long != run_id({"name": "x" * 299})


def test_unknown_parameter_is_refused_before_anything_runs(tmp_path):
    out = tmp_path / "never"
    with pytest.raises(ParameterError, match=r"unknown parameter 'stiffnes'.*bend_stiffness.*frames"):
        sweep("cloth", {"stiffnes": [1.0]}, out=out)
    with pytest.raises(ParameterError, match="unknown option 'substep'"):
        sweep(tiny_cloth, {"seed": [0]}, out=out, substep=3)
    with pytest.raises(ParameterError, match="both swept"):
        sweep(tiny_cloth, {"seed": [0]}, out=out, seed=1)
    with pytest.raises(ParameterError, match="cannot be imported by another process"):
        sweep(lambda **kw: None, {"seed": [0]}, out=out)
    with pytest.raises(ParameterError, match="unknown scene 'clothes'"):
        sweep("clothes", {"seed": [0]}, out=out)
    assert not out.exists()


def test_each_run_has_its_own_folder_and_run_json(base):
    assert [r["run_id"] for r in base.rows] == [f"substeps={n}" for n in SUBSTEPS]
    for row, n in zip(base.rows, SUBSTEPS, strict=True):
        doc = json.loads((base.out / row["run_id"] / "run.json").read_text())
        assert doc["status"] == row["status"] == "complete"
        assert doc["settings"]["sweep"]["params"] == {**FIXED, "substeps": n}
        assert doc["settings"]["substeps"] == row["substeps"] == row["param_substeps"] == n
        assert row["frames_done"] == 2 and row["steps"] == 2 * n and row["skipped"] is False
        assert row["wall_ms_per_frame"] > 0 and row["cpu_ms_per_frame"] > 0 and row["compile_s"] >= 0
    assert base.warmup["run_id"] == "substeps=4" and base.warmup["status"] == "complete"


def test_error_against_the_reference_run(base):
    errors = {r["param_substeps"]: r["error"] for r in base.rows}
    assert errors[16] == 0.0 and base.row("substeps=16")["is_reference"]
    assert errors[4] > errors[8] > 0.0
    # Symplectic Euler is first order: e(h) ~ C (h - h_ref), so e(1/4) / e(1/8) = (1/4 - 1/16) / (1/8 - 1/16).
    assert errors[4] / errors[8] == pytest.approx(3.0, rel=0.15)
    final = {k: np.load(base.out / f"substeps={k}" / "final_state.npz") for k in (4, 16)}
    d = final[4]["x"] - final[16]["x"]
    assert errors[4] == pytest.approx(np.sqrt(np.mean(np.sum(d * d, axis=1))), rel=1e-12)
    assert rms_distance(final[4], final[16]) == pytest.approx(errors[4], rel=1e-12)


def test_tables_and_manifest(base):
    text = base.csv.read_text().splitlines()
    header = text[0].split(",")
    for name in ("run_id", "status", "param_substeps", "wall_ms_per_frame", "cpu_ms_per_frame", "error"):
        assert name in header
    assert len(text) == 1 + len(SUBSTEPS)
    pq = pytest.importorskip("pyarrow.parquet")
    back = pq.read_table(base.parquet).to_pydict()
    assert back["param_substeps"] == SUBSTEPS and back["error"][2] == 0.0
    doc = json.loads(base.manifest.read_text())
    assert doc["settings"]["params"] == {"substeps": SUBSTEPS} and doc["settings"]["threads"] == 1
    assert doc["machine"]["cpu_count"] >= 1 and doc["counts"] == {"complete": 3}
    assert [r["run_id"] for r in doc["runs"]] == [r["run_id"] for r in base.rows]
    if base.plot is not None:
        assert base.plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_failures_and_divergence_are_rows(tmp_path):
    result = sweep(
        tiny_cloth,
        {"fail": ["none", "raise", "diverge"]},
        out=tmp_path,
        frames=3,
        export=False,
        progress=False,
    )
    rows = {r["param_fail"]: r for r in result.rows}
    assert rows["none"]["status"] == "complete" and rows["none"]["frames_done"] == 3
    assert rows["raise"]["status"] == "failed"
    assert rows["raise"]["message"] == "ValueError: tiny_cloth was asked to fail"
    assert rows["diverge"]["status"] == "diverged" and "diverged" in rows["diverge"]["message"]
    assert json.loads((tmp_path / "fail=diverge" / "run.json").read_text())["status"] == "diverged"


def test_a_run_past_its_timeout_is_stopped_and_recorded(tmp_path):
    result = sweep(tiny_cloth, {"sleep": [600.0]}, out=tmp_path, timeout=1.5, warmup=False, progress=False)
    (row,) = result.rows
    assert row["status"] == "timeout" and row["message"] == "stopped at the timeout of 1.5 s"


def test_dask_cluster_gives_the_local_rows_and_states(base, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as c:
        result = sweep(
            tiny_cloth,
            {"substeps": SUBSTEPS},
            out=tmp_path,
            cluster=c.scheduler_address,  # the sweep connects, runs on the cluster's executor, disconnects
            threads=1,  # as the local runs: the same kernels on as many threads give the same bits
            reference={"substeps": 16},
            warmup=False,
            progress=False,
            **FIXED,
        )
        with distributed.Client(c) as client:  # the sweep closed its connection, not the cluster
            assert len(client.scheduler_info()["workers"]) == 2
    keys = ("run_id", "status", "param_substeps", "param_frames", "frames_done", "steps")
    assert [{k: r[k] for k in keys} for r in result.rows] == [{k: r[k] for k in keys} for r in base.rows]
    for r in base.rows:
        ours, theirs = (np.load(o / r["run_id"] / "final_state.npz")["x"] for o in (base.out, tmp_path))
        np.testing.assert_array_equal(ours, theirs)


def test_command_line_values_and_params():
    assert parse_param("frames=2,3") == ("frames", [2, 3])
    assert parse_param("integrator=rk4,symplectic_euler") == ("integrator", ["rk4", "symplectic_euler"])
    assert parse_param("wind=[[6,0,1],[3,0,1]]") == ("wind", [[6, 0, 1], [3, 0, 1]])
    assert [parse_value(t) for t in ("4", "0.5", "1e-3", "true", "None", "auto")] == [
        4,
        0.5,
        1e-3,
        True,
        None,
        "auto",
    ]
    with pytest.raises(ParameterError, match="NAME=V1,V2"):
        parse_param("frames")


def test_command_line_refuses_unknown_names(capsys):
    assert main(["sweep", "cloth", "--param", "stiffnes=1,2", "--quiet"]) == 2
    assert "unknown parameter 'stiffnes'" in capsys.readouterr().err


def test_rerun_keeps_complete_runs_unless_asked(base, capsys):
    """Last: it runs the command line on the base sweep's folder (all kept), then reruns one run."""
    stamps = {r["run_id"]: (base.out / r["run_id"] / "run.json").stat().st_mtime_ns for r in base.rows}
    argv = ["sweep", f"{__name__}:tiny_cloth", "--param", "substeps=4,8,16", "--frames", "2", "--no-export"]
    argv += ["--out", str(base.out), "--reference", "substeps=16", "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.count("complete (kept)") == 3 and "sweep.csv" in printed
    again = sweep(tiny_cloth, {"substeps": SUBSTEPS}, out=base.out, progress=False, **FIXED)
    assert all(r["skipped"] for r in again.rows) and again.warmup is None
    assert {r: (base.out / r / "run.json").stat().st_mtime_ns for r in stamps} == stamps
    fresh = sweep(tiny_cloth, {"substeps": [4]}, out=base.out, rerun=True, progress=False, **FIXED)
    assert fresh.rows[0]["skipped"] is False and fresh.rows[0]["status"] == "complete"
    assert (base.out / "substeps=4" / "run.json").stat().st_mtime_ns > stamps["substeps=4"]
    assert (base.out / "substeps=8" / "run.json").stat().st_mtime_ns == stamps["substeps=8"]
