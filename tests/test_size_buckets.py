"""Capacity buckets (capacity.py): a scene of another size in the same bucket compiles no kernel, in the
same process and in the next one (counted through Taichi's own offline cache: one file per compiled
kernel), and runs the same physics as with exactly sized arrays."""

import gc
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim import capacity
from taichi_anim.errors import ParameterError
from taichi_anim.scenes import cloth, fountain, layers, spheres

from .helpers import fluid_tank, mesh_drop, ulp_tolerance

ROOT = Path(__file__).resolve().parents[1]

# Two sizes in one bucket, and one in the next, per scene kind: an emitter's pool (particles, emitters,
# trails, a box collider, symplectic Euler), a mass-spring cloth stepped by implicit Euler with PCG
# (springs, drag, pins, the linear solver) and hard spheres (contacts, the neighbour grid). Cloth 14 and
# 15: 196 and 225 vertices (bucket 256), 1038 and 1202 springs (bucket 2048); 17: 289 vertices.
SIZES = {
    "fountain": ({"particles": 700}, {"particles": 1000}, {"particles": 1500}),
    "cloth": ({"resolution": 14}, {"resolution": 15}, {"resolution": 17}),
    # 3000 and 3500 spheres: the demo's column is then 25 layers high either way, so its box (a collider's
    # shape is a compile-time constant) is the same; 5000 fill the next bucket.
    "spheres": ({"particles": 3000}, {"particles": 3500}, {"particles": 5000}),
    # Two sheets with self-contact (its pair lists, guard and BVHs over triangles and edges) on a ball: 392
    # and 450 vertices, 676 and 784 triangles, 1066 and 1232 edges, 2076 and 2404 springs; 17: 578 vertices.
    "layers": ({"resolution": 14}, {"resolution": 15}, {"resolution": 17}),
    # Particles on a static mesh collider (its BVH, adjacency and normals): 114 and 107 vertices, 224 and
    # 210 faces (buckets 128 and 256); 12 rings: 178 vertices, 352 faces.
    "mesh": ({"rings": 8, "segments": 16}, {"rings": 8, "segments": 15}, {"rings": 12, "segments": 16}),
    # A liquid collapsing in one tank (its walls' samples, neighbour grid, DFSPH's solves): 90 and 120
    # particles (bucket 128); 10 layers: 150.
    "fluid": ({"rows": 6}, {"rows": 8}, {"rows": 10}),
}
BUILD = {
    "fountain": {},
    "cloth": {"integrator": "implicit_euler"},
    "spheres": {"steps_per_frame": 2},
    "layers": {"layers": 2},
    "mesh": {},
    "fluid": {},
}
# What builds each kind: a demo's build(), or a test scene ("module:function", importable in the runner).
BUILDERS = {name: f"taichi_anim.scenes.{name}:build" for name in ("fountain", "cloth", "spheres", "layers")}
BUILDERS["mesh"] = "tests.helpers:mesh_drop"
BUILDERS["fluid"] = "tests.helpers:fluid_tank"
SCENES = {"fountain": fountain.build, "cloth": cloth.build, "spheres": spheres.build, "layers": layers.build}
SCENES["mesh"] = mesh_drop
SCENES["fluid"] = fluid_tank

_RUNNER = """
import gc, json, sys
import taichi_anim as ta
from importlib import import_module
ta.init("cpu", size_buckets=True)
for builder, options in json.loads(sys.argv[1]):
    module, function = builder.split(":")
    scene = getattr(import_module(module), function)(**options)
    stepper = ta.Stepper(scene.model, scene.integrator)
    for _ in range(2):
        stepper.step(scene.state, scene.dt, scene.substeps)
    scene.state.snapshot()
    del scene, stepper
    gc.collect()
"""


def _run(plan: list, cache: Path) -> int:
    """Run the scenes of `plan` ([builder, build options] in order) in one new process with the offline
    cache in `cache`; return how many compiled kernels the cache holds afterwards."""
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=str(cache), PYTHONPATH=str(ROOT))
    env.pop("TAICHI_ANIM_SIZE_BUCKETS", None)
    done = subprocess.run([sys.executable, "-c", _RUNNER, json.dumps(plan)], env=env, capture_output=True)
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    return len(list(cache.rglob("*.tic")))


def _plan(which: int) -> list:
    return [[BUILDERS[name], {**BUILD[name], **SIZES[name][which]}] for name in SIZES]


def test_another_size_in_the_bucket_compiles_no_kernel(tmp_path):
    first = _run(_plan(0), tmp_path / "first")
    assert first > 10  # the scenes' kernels were compiled into the cache
    # The later run starts from a copy of that cache: the first size's scenes load their kernels (not
    # compiled again), and any kernel a later scene does not find adds a file all the same.
    shutil.copytree(tmp_path / "first", tmp_path / "both")
    # In one process: the second size's scenes get the first's fields back and find every kernel.
    assert _run(_plan(0) + _plan(1), tmp_path / "both") == first


@pytest.mark.slow
def test_the_next_process_finds_another_sizes_kernels_in_the_cache(tmp_path):
    first = _run(_plan(0), tmp_path / "first")
    shutil.copytree(tmp_path / "first", tmp_path / "next")
    assert _run(_plan(1), tmp_path / "next") == first  # the cache the first size filled serves the second


@pytest.mark.slow
def test_a_size_in_the_next_bucket_compiles_its_own_kernels(tmp_path):
    # The check above is sensitive: counting the cache's files sees kernels compiled for a new size.
    first = _run(_plan(0), tmp_path / "first")
    shutil.copytree(tmp_path / "first", tmp_path / "three")
    assert _run(_plan(0) + _plan(1) + _plan(2), tmp_path / "three") > first


def _final(name: str, buckets: bool, frames: int):
    ta.init("cpu", precision="f64", size_buckets=buckets)
    scene = SCENES[name](**BUILD[name], **SIZES[name][1])
    stepper = ta.Stepper(scene.model, scene.integrator)
    for _ in range(frames):
        stepper.step(scene.state, scene.dt, scene.substeps)
    return scene, stepper


@pytest.fixture
def buckets_reset():
    yield
    capacity.set_enabled(None)


@pytest.mark.parametrize(
    "name, frames",
    [
        pytest.param("fountain", 30, marks=pytest.mark.slow),  # 16 s; emitters' buckets: the no-kernel test
        ("cloth", 10),
        pytest.param("spheres", 10, marks=pytest.mark.slow),  # 10 s; the cloth and mesh cases run by default
        # the sheets need 130 frames to reach the ball (34 s, loaded 2 cores): self-contact under buckets
        pytest.param("layers", 130, marks=pytest.mark.slow),
        ("mesh", 200),
        ("fluid", 20),
    ],
)
def test_buckets_run_the_same_physics(buckets_reset, name, frames):
    """The live count read at run time instead of a constant: the same arithmetic, compiled apart, so equal
    within round-off (the cloth's PCG also stops after the same iterations)."""
    exact, exact_stepper = _final(name, False, frames)
    x0, alive0 = exact.state.positions(), exact.state.alive_mask()
    # What the liquid reports, read now: the next ti.init drops this run's fields.
    liquid0 = totals0 = None
    if exact.model.fluid_count:
        liquid0 = (exact.state.fluid_densities(), exact.state.fluid_pressures())
        totals0 = dict(exact_stepper.solver("fluid").totals)
    n = exact.model.particle_count
    assert exact.state.particle_x.shape == (n,)
    bucketed, stepper = _final(name, True, frames)
    model = bucketed.model
    assert model.particle_count == n and model.particle_capacity == capacity.bucket(n) > n
    assert bucketed.state.particle_x.shape == (model.particle_capacity,)
    x1 = bucketed.state.positions()
    assert x1.shape == (n, 3)
    np.testing.assert_array_equal(bucketed.state.alive_mask(), alive0)
    assert alive0.sum() > 0
    tol = ulp_tolerance(float(np.abs(x0[alive0]).max()), ulps=1024)  # f64, frames of rounding
    np.testing.assert_allclose(x1[alive0], x0[alive0], rtol=0, atol=tol)
    # Rows past the live count are never touched: still the zeros the start wrote.
    assert not np.any(bucketed.state.particle_x.to_numpy()[n:])
    if name == "mesh":  # the particles reached the ball: the nearest rests on its faces (inside the sphere)
        gap = np.linalg.norm(x1 - (0.0, 0.2, 0.0), axis=1) - 0.2
        assert -0.01 < gap.min() < 1e-4
        ball = model.colliders[0]
        assert ball.buckets and ball.mesh.face_capacity == capacity.bucket(ball.face_count) > ball.face_count
    liquid = stepper.solver("fluid")
    if liquid is not None:  # the solves ran to the same iterations; the column collapsed along the floor
        assert model.fluid_capacity == capacity.bucket(model.fluid_count) > model.fluid_count
        assert model.settings["size_buckets"]["fluid_capacity"] == model.fluid_capacity  # run.json's record
        assert liquid.boundary.capacity == capacity.bucket(liquid.boundary_count) > liquid.boundary_count
        assert x1[:, 0].max() > 0.13  # the block's front started at 0.09 m
        rho0, p0 = liquid0
        # A density sums kernels of its neighbours' distances, which carry the positions' round-off: it
        # moves by at most ~10 times that over a spacing, relatively (the cubic spline's sum of
        # m |grad W| spacing over a full neighbourhood is a few rho0).
        rel = 10.0 * tol / liquid.spacing
        counts = ("steps", "density_iterations", "divergence_iterations", "unconverged_steps")
        assert {k: liquid.totals[k] for k in counts} == {k: totals0[k] for k in counts}
        # the largest density error, rho / rho0 - 1: the densities' relative round-off
        assert liquid.totals["max_error_max"] == pytest.approx(totals0["max_error_max"], rel=0, abs=rel)
        np.testing.assert_allclose(bucketed.state.fluid_densities(), rho0, rtol=0, atol=rel * rho0.max())
        # A pressure sums the solves' density errors rho - rho0 (about the tolerance times rho0), each
        # carrying the round-off of rho: its own round-off is 1 / tolerance times larger.
        p_tol = rel * float(np.abs(p0).max()) / liquid.tolerance
        np.testing.assert_allclose(bucketed.state.fluid_pressures(), p0, rtol=0, atol=p_tol)
    contact = stepper.solver("self-contact")
    if contact is not None:  # the sheets lie on the ball and on each other: pairs found and guarded
        assert contact.buckets and contact.tri_boxes.capacity > contact.triangle_count
        assert contact.read_stats()["guard_pairs"] > 0


def test_bucket_sizes_and_switch(buckets_reset):
    assert [capacity.bucket(n) for n in (1, 64, 65, 1000, 1024, 1025)] == [64, 64, 128, 1024, 1024, 2048]
    capacity.set_enabled(True)
    assert capacity.enabled()
    capacity.set_enabled(False)
    assert not capacity.enabled()
    with pytest.raises(ParameterError, match="size_buckets must be True, False or None, got 'yes'"):
        capacity.set_enabled("yes")


def test_pool_returns_a_dropped_owners_fields_oldest_first():
    class Owner:
        pass

    a, b = Owner(), Owner()
    fa = capacity.take(a, "test_role", ti.f32, 8, (3,))
    fb = capacity.take(b, "test_role", ti.f32, 8, (3,))
    assert fa is not fb
    del b, a  # collected in the other order than made
    gc.collect()
    c, d = Owner(), Owner()
    assert capacity.take(c, "test_role", ti.f32, 8, (3,)) is fa
    assert capacity.take(d, "test_role", ti.f32, 8, (3,)) is fb
    # Another role, shape or dtype never shares a field.
    assert capacity.take(c, "other_role", ti.f32, 8, (3,)) is not fa
    assert capacity.take(d, "test_role", ti.f32, 16, (3,)) is not fb
    # A new Taichi program invalidates every field: the pool starts empty.
    del c, d
    gc.collect()
    assert capacity.pooled_count() >= 2
    ta.init("cpu", precision="f64")
    assert capacity.pooled_count() == 0


def test_demo_option_buckets_the_run_and_says_so(tmp_path, buckets_reset):
    from taichi_anim.cli import main

    argv = ["demo", "cloth", "--frames", "2", "--no-export", "--quiet", "--integrator", "symplectic_euler"]
    assert main([*argv, "--size-buckets", "on", "--out", str(tmp_path / "on")]) == 0
    on = json.loads((tmp_path / "on" / "run.json").read_text())
    assert on["settings"]["model"]["size_buckets"] == {"particle_capacity": 4096}  # 48^2 = 2304 vertices
    assert main([*argv, "--size-buckets", "off", "--out", str(tmp_path / "off")]) == 0
    off = json.loads((tmp_path / "off" / "run.json").read_text())
    assert "size_buckets" not in off["settings"]["model"]
    assert on["status"] == off["status"] == "complete"


def test_a_blob_field_from_the_pool_starts_empty():
    """A blob field made of a dropped one's fields (capacity.take, as under buckets) is the empty field
    Blinn's sum starts from: psi 0 and no block listed, whatever the last owner evaluated."""
    box = ((-0.3,) * 3, (0.3,) * 3)
    first = ta.BlobField(capacity=8, sigma=0.05, bounds=box, resolution=24, make=capacity.take)
    first.evaluate(np.zeros((1, 3)))
    psi = first.psi
    assert psi.to_numpy().max() > 0.5  # nodes near a lone blob's centre (psi = 1 at it)
    del first
    gc.collect()
    second = ta.BlobField(capacity=8, sigma=0.05, bounds=box, resolution=24, make=capacity.take)
    assert second.psi is psi  # the same field, handed back by the pool
    assert not np.any(second.psi.to_numpy())
    assert int(second.active_count[None]) == 0
