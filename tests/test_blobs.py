"""Blobs (Blinn 1982 field, marching cubes / tetrahedra isosurfaces): the truncated field against the
brute-force sum, one blob against the analytic sphere, closed consistently oriented meshes, merging of
two blobs at the analytic distance, the demo's exported meshes, and bad input."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim.io.export import read_triangle_mesh
from taichi_anim.scenes import make_scene
from taichi_anim.spatial import mesh_report

pytest.importorskip("open3d")  # the default extractor

METHODS = [m.value for m in ta.IsosurfaceMethod]
# The default run checks the Taichi extractor's mesh topology (the cloud test); its other cases are slow
# only because each test compiles its kernels afresh.
METHODS_FAST = [m if m != "taichi" else pytest.param(m, marks=pytest.mark.slow) for m in METHODS]


def needs(method: str) -> None:
    if method == "skimage":
        pytest.importorskip("skimage")


def brute_force(nodes: np.ndarray, centers: np.ndarray, sigma: float, cutoff_radius: float | None = None):
    """psi at nodes (..., 3) from every center (sum over all, or only those closer than cutoff_radius)."""
    d2 = ((nodes[..., None, :] - centers) ** 2).sum(-1)
    w = np.exp(-d2 / sigma**2)
    if cutoff_radius is not None:
        w = np.where(d2 < cutoff_radius**2, w, 0.0)
    return w.sum(-1)


def interior(a: np.ndarray) -> np.ndarray:
    return a[1:-1, 1:-1, 1:-1]


# ------------------------------------------------------------------------------------------- the field


@pytest.mark.parametrize("cutoff, neighbor_method", [(1.5, "brute"), (3.0, "grid")])
def test_truncated_field_matches_brute_force_within_the_stated_bound(cutoff, neighbor_method):
    rng = np.random.default_rng(7)
    sigma = 0.05
    n = 40
    x = rng.uniform(-0.2, 0.2, (n, 3))
    x[:4] += 0.3  # some just outside the grid: they still reach nodes within r_c
    alive = rng.uniform(size=n) < 0.75
    bf = ta.BlobField(
        capacity=n,
        sigma=sigma,
        bounds=((-0.3, -0.25, -0.25), (0.3, 0.25, 0.25)),
        resolution=25,
        cutoff=cutoff,
        neighbor_method=neighbor_method,
    )
    bf.evaluate(rng.uniform(-0.3, 0.3, (n, 3)))  # an earlier cloud: its blocks must be cleared, not kept
    xf = ti.Vector.field(3, float, n)
    death = ti.field(float, n)
    xf.from_numpy(x)
    death.from_numpy(np.where(alive, 1.0, -1.0))
    bf.evaluate(xf, count=n, death=death, t=0.0)
    psi = bf.values()
    nodes = bf.node_positions()
    exact = brute_force(nodes, x[alive], sigma)
    truncated = brute_force(nodes, x[alive], sigma, bf.cutoff_radius)
    err = interior(exact - psi)
    # 0 <= psi_exact - psi < N exp(-cutoff^2): every omitted particle is >= r_c away.
    bound = alive.sum() * np.exp(-(cutoff**2))
    assert err.min() > -1e-12 and err.max() < bound
    # Exactly the particles beyond r_c are omitted, nothing else (up to summation order).
    np.testing.assert_allclose(interior(psi), interior(truncated), rtol=1e-12, atol=1e-14)
    if cutoff < 2:  # the truncation is real and measured, not vacuous
        assert err.max() > 0.05 * bound
    # The outer layer is the zero pad that closes the isosurface.
    inner = np.zeros(psi.shape, bool)
    inner[1:-1, 1:-1, 1:-1] = True
    assert np.all(psi[~inner] == 0.0)


@pytest.mark.parametrize("precision", ["f32", "f64"])
def test_blocks_shared_out_by_workers_give_the_plain_loops_bits(precision):
    """The gather's blocks claimed one by one by the CPU's workers (blobs/field.py) against a loop over
    them: the same bits, on 1 and 2 threads, and the truncated sum at 600 sampled nodes."""
    import taichi_anim.blobs.field as field_module

    rng = np.random.default_rng(11)
    n, sigma = 6000, 0.04
    x = rng.uniform((-0.6, -0.15, -0.6), (0.6, 0.15, 0.6), (n, 3))
    runs = {}
    for threads, workers in ((2, True), (2, False), (1, True)):
        ta.init("cpu", precision=precision, cpu_threads=threads)
        field_module.WORKER_GATHER = workers
        try:
            bf = ta.BlobField(capacity=n, sigma=sigma, bounds=((-0.8,) * 3, (0.8,) * 3), resolution=80)
        finally:
            field_module.WORKER_GATHER = None
        bf.evaluate(x[::-1])  # an earlier cloud to clear
        bf.evaluate(x)
        assert bf.active_block_count > 300  # many blocks to share out
        runs[threads, workers] = bf.values()
    assert np.array_equal(runs[2, True], runs[2, False])
    assert np.array_equal(runs[2, True], runs[1, True])
    # 600 of the nodes the blobs reach (brute force holds 600 x 6000 x 3 floats)
    pick = rng.choice(np.flatnonzero(runs[2, True]), 600, replace=False)
    nodes = bf.node_positions().reshape(-1, 3)[pick]
    inner = np.zeros(bf.dims, bool)
    inner[1:-1, 1:-1, 1:-1] = True
    keep = inner.ravel()[pick]
    truncated = brute_force(nodes[keep], x, sigma, bf.cutoff_radius)
    # f32: the positions' rounding, and a particle at the cutoff counted or not (1.2e-4 of ~5).
    rtol = 1e-12 if precision == "f64" else 1e-4
    np.testing.assert_allclose(runs[2, True].reshape(-1)[pick][keep], truncated, rtol=rtol, atol=rtol)


def test_normals_are_the_analytic_gradient_whatever_the_neighbour_search():
    """The surface's normals come from the particles within the cutoff, found by the grid's scan of
    half-cutoff cells (for_each_near) or by the other searches' queries: all equal to the brute-force
    gradient of the truncated sum."""
    rng = np.random.default_rng(5)
    n, sigma = 300, 0.05
    x = rng.uniform(-0.2, 0.2, (n, 3))
    points = rng.uniform(-0.25, 0.25, (500, 3))
    d = points[:, None, :] - x[None, :, :]
    r2 = (d**2).sum(-1)
    w = np.where(r2 < (3.0 * sigma) ** 2, np.exp(-r2 / sigma**2), 0.0)
    g = (d * w[..., None]).sum(1)
    expected = g / np.linalg.norm(g, axis=1, keepdims=True)
    for method in ("grid", "hash_grid", "brute"):
        bf = ta.BlobField(capacity=n, sigma=sigma, bounds=((-0.3,) * 3, (0.3,) * 3), resolution=32,
                          neighbor_method=method)  # fmt: skip
        bf.evaluate(x)
        np.testing.assert_allclose(bf.outward_normals(points), expected, atol=1e-9, err_msg=method)


# ------------------------------------------------------------------------------------------ one blob


@pytest.mark.parametrize("method", METHODS_FAST)
def test_one_blob_is_the_analytic_sphere(method):
    needs(method)
    sigma, iso = 0.1, 0.4
    c = np.array([0.0123, -0.0071, 0.0049])  # off the nodes, so no vertex sits on a node
    # A box of unequal sides: a swapped axis (Open3D reads the volume as [z, y, x]) would show.
    bf = ta.BlobField(capacity=1, sigma=sigma, bounds=((-0.3, -0.25, -0.2), (0.35, 0.25, 0.2)), resolution=24)
    bf.evaluate(c[None])
    mesh = bf.isosurface(iso, method=method)
    v, f, nrm = mesh.vertices, mesh.triangles, mesh.normals
    h = bf.spacing
    radius = sigma * np.sqrt(np.log(1.0 / iso))  # exp(-R^2 / sigma^2) = iso
    r = np.linalg.norm(v - c, axis=1)
    assert len(f) > 100
    assert np.abs(r - radius).max() < h  # the criterion
    # Linear interpolation of psi along an edge of length L misplaces the root by about
    # L^2 |psi''| / (8 |psi'|) = L^2 (4R^2/s^2 - 2) / (16 R) radially: ~0.03 h for the cubes' edges,
    # 3x that on the tetrahedra's main diagonals (L = sqrt(3) h). Asserted with a 2x margin.
    longest = np.sqrt(3) * h if method == "taichi" else h
    estimate = longest**2 * (4 * radius**2 / sigma**2 - 2) / (16 * radius)
    assert np.abs(r - radius).max() < 2 * estimate
    # Normals: the analytic outward normal of a sphere is radial.
    assert np.min(np.einsum("ij,ij->i", nrm, (v - c) / r[:, None])) > 1 - 1e-9
    # Outward winding: the divergence-theorem volume is positive and close to 4/3 pi R^3 (inscribed).
    vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    assert -0.06 < vol / (4 / 3 * np.pi * radius**3) - 1 < 0


# --------------------------------------------------------------------------------------- mesh quality


def check_closed_and_oriented(v, f, normals, field=None) -> None:
    # Closed (every edge in exactly two triangles), edge- and vertex-manifold, consistently oriented (each
    # directed edge once), no two triangles meeting where they should not: decided exactly, so slivers
    # merely touching near a grid node are not taken for intersections (Open3D's is_watertight does).
    report = mesh_report(v, f)
    assert report.ok, report.describe()
    # Outward: triangle normals agree with the field's outward normals, volume > 0. Counted by area:
    # where the grid under-resolves a thin neck a sliver's normal may turn away. Caps that the grid's
    # zero outer layer cuts (vertices within a spacing of the grid's edge) follow the cut, not the field.
    face = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area = np.linalg.norm(face, axis=1)
    keep = np.ones(len(f), bool)
    if field is not None:
        h = field.spacing
        inner = (v > np.asarray(field.lo) + h) & (v < np.asarray(field.hi) - h)
        keep = inner.all(axis=1)[f].all(axis=1)
    agree = np.einsum("ij,ij->i", face, normals[f].sum(axis=1)) > 0
    assert area[keep & agree].sum() > 0.999 * area[keep].sum()
    assert report.volume > 0
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


@pytest.mark.parametrize("method", METHODS)
def test_blob_cloud_mesh_is_closed_manifold_and_consistently_oriented(method, tmp_path):
    needs(method)
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal((-0.1, 0, 0), 0.05, (12, 3)), rng.normal((0.12, 0.02, 0), 0.04, (8, 3))])
    x[0] = (0.29, 0.0, 0.0)  # a blob cut by the grid's edge: the zero outer layer must cap it
    bf = ta.BlobField(
        capacity=len(x), sigma=0.04, bounds=((-0.3, -0.2, -0.2), (0.3, 0.2, 0.2)), resolution=32
    )
    bf.evaluate(x)
    mesh = bf.isosurface(0.3, method=method)
    assert mesh.triangle_count > 500
    check_closed_and_oriented(mesh.vertices, mesh.triangles, mesh.normals, bf)
    # Without normals: the same surface, wound the same way (its winding decided by a sample's normals).
    bare = bf.isosurface(0.3, method=method, normals=False)
    assert bare.normals is None
    assert np.array_equal(bare.vertices, mesh.vertices) and np.array_equal(bare.triangles, mesh.triangles)
    assert "vertex_normals" not in read_triangle_mesh(bare.write(tmp_path / "bare.ply"))


@pytest.mark.parametrize("method", METHODS_FAST)
def test_two_blobs_merge_exactly_when_the_midpoint_exceeds_iso(method):
    needs(method)
    sigma, iso = 0.1, 0.5
    # On the axis between two blobs the field is lowest at the midpoint: 2 exp(-(D/2)^2 / s^2) = iso
    # at D* = 2 s sqrt(ln(2 / iso)) = 2.35 s, while each alone has radius s sqrt(ln(1/iso)) = 0.83 s:
    # the blobs join well before their spheres would touch (1.67 s).
    d_star = 2 * sigma * np.sqrt(np.log(2 / iso))
    bf = ta.BlobField(capacity=2, sigma=sigma, bounds=((-0.4, -0.2, -0.2), (0.4, 0.2, 0.2)), resolution=64)
    components = {}
    for factor in (0.9, 1.1):
        d = factor * d_star
        bf.evaluate(np.array([[-d / 2, 0.003, 0.001], [d / 2, 0.003, 0.001]]))
        mesh = bf.isosurface(iso, method=method)
        components[factor] = mesh_report(mesh.vertices, mesh.triangles).component_count
    assert components == {0.9: 1, 1.1: 2}


@pytest.mark.slow
def test_extractors_agree_on_the_same_field():
    """Same grid values, same linear interpolation on the cube edges: Open3D and the tetrahedra enclose
    the same volume to within the interpolation error."""
    rng = np.random.default_rng(11)
    x = rng.normal(0.0, 0.08, (30, 3))
    bf = ta.BlobField(capacity=30, sigma=0.05, bounds=((-0.3, -0.3, -0.3), (0.3, 0.3, 0.3)), resolution=40)
    bf.evaluate(x)
    vols = {}
    for method in ("open3d", "taichi"):
        mesh = bf.isosurface(0.4, method=method)
        v, f = mesh.vertices, mesh.triangles
        vols[method] = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    assert abs(vols["taichi"] / vols["open3d"] - 1) < 0.01


@pytest.mark.slow  # two fresh runtimes, each compiling every kernel (~4 s)
def test_field_and_tetrahedra_mesh_do_not_depend_on_the_thread_count():
    """Each block's nodes are summed by one thread in the neighbour structure's order, and the mesh is
    written block by block at scanned offsets: bitwise the same on 1 and 2 threads."""
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 0.08, (200, 3))
    results = []
    for threads in (1, 2):
        ta.init("cpu", precision="f64", cpu_threads=threads)
        bf = ta.BlobField(
            capacity=200, sigma=0.03, bounds=((-0.3, -0.3, -0.3), (0.3, 0.3, 0.3)), resolution=40
        )
        bf.evaluate(x)
        mesh = bf.isosurface(0.5, method="taichi")
        results.append((bf.values(), mesh.vertices, mesh.triangles))
    for a, b in zip(*results, strict=True):
        assert np.array_equal(a, b)


def test_empty_field_gives_an_empty_mesh(tmp_path):
    bf = ta.BlobField(capacity=2, sigma=0.05, bounds=((0, 0, 0), (1, 1, 1)), resolution=16)
    bf.evaluate(np.array([[5.0, 5.0, 5.0]]))  # far outside: touches no node
    assert bf.active_block_count == 0
    mesh = bf.isosurface(0.5)
    assert mesh.triangle_count == 0
    path = mesh.write(tmp_path / "empty.ply")
    assert len(read_triangle_mesh(path)["vertices"]) == 0


# ---------------------------------------------------------------------------------------------- demo


def test_blobs_demo_exports_closed_meshes_with_normals(tmp_path):
    scene = make_scene("blobs", particles=400, resolution=48, seed=1)
    for _ in range(24):  # 0.4 s: the jet is in the air
        scene.advance_frame()
    paths = scene.export_frame(tmp_path, 7)
    assert [p.name for p in paths] == ["blobs_0007.ply", "blobs_mesh_0007.ply"]
    mesh = read_triangle_mesh(paths[1])
    v, f, n = mesh["vertices"], mesh["triangles"], mesh["vertex_normals"]
    assert len(f) > 200
    check_closed_and_oriented(v, f, n)
    # The surface is where the particles are: psi > 0 needs a particle within r_c, and a vertex lies on
    # a grid edge with a corner where psi > iso.
    x = scene.state.snapshot().x
    nearest = np.sqrt(((v[:, None, :] - x[None]) ** 2).sum(-1).min(axis=1))
    assert nearest.max() < scene.blobs.cutoff_radius + np.sqrt(3) * scene.blobs.spacing
    png = scene.render(tmp_path / "blobs.png")
    assert png.stat().st_size > 1000


# ---------------------------------------------------------------------------------------------- errors


def test_bad_input_names_the_parameter():
    box = ((0, 0, 0), (1, 1, 1))
    with pytest.raises(ta.ParameterError, match="sigma"):
        ta.BlobField(capacity=4, sigma=0.0, bounds=box)
    with pytest.raises(ta.ParameterError, match="resolution"):
        ta.BlobField(capacity=4, sigma=0.1, bounds=box, resolution=2)
    with pytest.raises(ta.ParameterError, match="bounds"):
        ta.BlobField(capacity=4, sigma=0.1, bounds=((0, 0, 0), (1, -1, 1)))
    with pytest.raises(ta.ParameterError, match="cutoff"):
        ta.BlobField(capacity=4, sigma=0.1, bounds=box, cutoff=-1)
    bf = ta.BlobField(capacity=2, sigma=0.1, bounds=box, resolution=8)
    with pytest.raises(ta.ParameterError, match="x contains 1 non-finite"):
        bf.evaluate(np.array([[0.5, np.nan, 0.5]]))
    with pytest.raises(ta.ParameterError, match="capacity=2"):
        bf.evaluate(np.zeros((3, 3)))
    bf.evaluate(np.array([[0.5, 0.5, 0.5]]))
    with pytest.raises(ta.ParameterError, match="iso"):
        bf.isosurface(0.0)
    with pytest.raises(ta.ParameterError, match="unknown isosurface method 'marching'"):
        bf.isosurface(0.5, method="marching")
    with pytest.raises(ta.ParameterError, match="iso must lie strictly between 0 and 1"):
        make_scene("blobs", iso=1.5)
