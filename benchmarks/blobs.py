"""Blobs: meshing time and triangle count against grid resolution, and one blob's mesh against the
analytic sphere, for the three isosurface extractors (Open3D's Flying Edges, scikit-image's marching
cubes, the engine's Taichi marching tetrahedra) and two field evaluations (the engine's gather by block
with the separable Gaussian, a gather per node from benchmarks/candidates/blob_node_gather.py).

Cloud: the `blobs` demo (taichi_anim/scenes/blobs.py, seed 0, its default 1500-particle jet) run for
FRAMES frames; its alive particles are meshed, at sigma = 0.04 m, iso = 0.5, cutoff 3 sigma, float32, on a
cube of side L around the demo's box (the box's longest side plus a margin) with resolution^3 nodes,
resolution = 64, 96, 128, 192, 256. Only the blocks of 8^3 nodes near particles are evaluated
(the "visited" column).

Measured after a warm-up call of every kernel (JIT excluded; compile time reported separately from fresh
`ta.init`s), with `ti.sync()` before each clock read, median of REPEATS calls:
- field: `BlobField.evaluate` (neighbour-structure build + one kernel) and the per-node candidate;
- extraction: `blobs.isosurface.extract_triangles` (for the libraries: copying the box of visited nodes
  to NumPy, the library call, vertices back to metres);
- normals: `BlobField.outward_normals` at the mesh's vertices (analytic gradient, Taichi kernel);
- total: `BlobField.isosurface` (extraction + normals + orientation) plus the field.
Checks per mesh, by `taichi_anim.spatial.mesh_report` (exact; not timed): closed (every edge shared by
two triangles), edge- and vertex-manifold, consistently oriented (every directed edge once with its
reverse), no self-intersection, no zero-area triangle, and the divergence-theorem volume > 0 (outward).

One blob: a single particle at an off-node point near the cube's centre on the same grids and sigma;
error = |vertex - centre| - R with R = sigma sqrt(ln(1/iso)) (exp(-R^2/sigma^2) = iso), max and RMS over the
vertices, and the enclosed volume against 4/3 pi R^3.

    .venv/bin/python benchmarks/blobs.py           # full run (~3 min on an idle 2-core machine)
    .venv/bin/python benchmarks/blobs.py --quick   # smoke run (~40 s): 32^3 ... 64^3, benchmarks/out/

An extractor whose library is not installed is left out (and named in the output).

Writes <out>/blobs.md (the RESULTS.md section), blobs.json (raw figures) and blobs.png.
"""

import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np
from common import (
    COMPILE_HEADERS,
    OtherLoad,
    clock,
    command_line,
    compile_rows,
    compile_times,
    engine_fingerprint,
    fmt_s,
    init,
    load_average,
    log,
    machine_info,
    machine_table,
    md_table,
    output_paths,
    parse_args,
)

import taichi_anim as ta
from taichi_anim.blobs.isosurface import extract_triangles
from taichi_anim.scenes import make_scene
from taichi_anim.spatial import mesh_report

sys.path.insert(0, str(Path(__file__).resolve().parent / "candidates"))
from blob_node_gather import BlobFieldNodeGather  # noqa: E402

SIGMA = 0.04  # [m], the demo's default
ISO = 0.5
FRAMES = 90  # 1.5 s of the demo: the jet has reached the floor
NEEDS = {"open3d": "open3d", "skimage": "skimage", "taichi": None}  # extractor -> library it imports
METHODS = tuple(m for m, lib in NEEDS.items() if lib is None or importlib.util.find_spec(lib) is not None)
MISSING = tuple(m for m in NEEDS if m not in METHODS)  # left out: library not installed
PRECISION = "f32"


def jet_cloud(frames: int) -> tuple[np.ndarray, tuple]:
    """Alive particle positions (N,3) [m] of the blobs demo after `frames` frames, and the cube around
    its box: (lo, hi) [m]."""
    scene = make_scene("blobs")
    for _ in range(frames):
        scene.advance_frame()
    lo, hi = (np.asarray(b, dtype=float) for b in scene.bounds)
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo).max() + 0.1  # room for a blob radius plus the zero outer layer
    cube = (tuple(float(c) for c in centre - half), tuple(float(c) for c in centre + half))
    return scene.state.snapshot().x.astype(np.float64), cube


def timed(fn, repeats: int) -> tuple[float, object]:
    """(median seconds, last result) of `repeats` calls, each between synchronised clock reads."""
    times, out = [], None
    for _ in range(repeats):
        t0 = clock()
        out = fn()
        times.append(clock() - t0)
    return float(np.median(times)), out


def mesh_checks(v: np.ndarray, f: np.ndarray) -> dict:
    r = mesh_report(v, f)
    checks = {
        "closed": r.closed,
        "manifold": r.edge_manifold and r.vertex_manifold,
        "oriented": r.oriented,
        "no_self_intersection": not r.self_intersecting,
        "no_zero_area": not len(r.degenerate_triangles),
        "outward": r.volume > 0,
    }
    checks["all"] = all(checks.values())
    return checks


def resolution_row(x: np.ndarray, cube, res: int, repeats: int, node_gather: bool) -> dict:
    bf = ta.BlobField(capacity=len(x), sigma=SIGMA, bounds=cube, resolution=res)
    bf.evaluate(x)  # warm-up: compiles
    t_eval, _ = timed(lambda: bf.evaluate(x), repeats)
    visited = bf.active_block_count * 8**3 / np.prod(bf.dims)
    row = {
        "resolution": res,
        "dims": bf.dims,
        "spacing": bf.spacing,
        "particles": len(x),
        "neighbors": bf.neighbors.describe(),
        "active_blocks": bf.active_block_count,
        "visited_fraction": float(visited),
        "field_block": t_eval,
        "methods": {},
    }
    if node_gather:
        cand = BlobFieldNodeGather(capacity=len(x), sigma=SIGMA, bounds=cube, resolution=res)
        cand.evaluate(x)
        row["field_node"], _ = timed(lambda: cand.evaluate(x), max(2, repeats // 2))
        row["field_node_max_diff"] = float(np.abs(cand.values() - bf.values()).max())
        row["psi_max"] = float(bf.values().max())
        del cand
    for method in METHODS:
        mesh = bf.isosurface(ISO, method=method)  # warm-up
        t_total, mesh = timed(lambda m=method: bf.isosurface(ISO, method=m), repeats)
        t_extract, _ = timed(lambda m=method: extract_triangles(bf, ISO, m), repeats)
        t_normals, _ = timed(lambda v=mesh.vertices: bf.outward_normals(v), repeats)
        row["methods"][method] = {
            "total": t_total,
            "normals": t_normals,
            "extraction": t_extract,
            "triangles": int(mesh.triangle_count),
            "vertices": len(mesh.vertices),
            "checks": mesh_checks(mesh.vertices, mesh.triangles),
        }
        m = row["methods"][method]
        log(
            f"{res}^3 {method}: field {fmt_s(t_eval)}, extraction {fmt_s(m['extraction'])}, normals "
            f"{fmt_s(t_normals)}, {mesh.triangle_count} triangles, checks {'ok' if m['checks']['all'] else m}"
        )
    return row


def one_blob_row(cube, res: int) -> dict:
    lo, hi = (np.asarray(c) for c in cube)
    centre = 0.5 * (lo + hi) + np.array([0.0123, -0.0071, 0.0049])  # off the nodes
    bf = ta.BlobField(capacity=1, sigma=SIGMA, bounds=cube, resolution=res)
    bf.evaluate(centre[None])
    radius = SIGMA * np.sqrt(np.log(1.0 / ISO))
    out = {"resolution": res, "spacing": bf.spacing, "radius": radius, "methods": {}}
    for method in METHODS:
        mesh = bf.isosurface(ISO, method=method)
        v, f = mesh.vertices, mesh.triangles
        err = np.linalg.norm(v - centre, axis=1) - radius
        volume = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
        out["methods"][method] = {
            "triangles": int(len(f)),
            "max_error": float(np.abs(err).max()) if len(v) else float("nan"),
            "rms_error": float(np.sqrt(np.mean(err**2))) if len(v) else float("nan"),
            "volume_error": float(volume / (4 / 3 * np.pi * radius**3) - 1),
        }
    return out


def compile_measurement(x, cube, modes) -> dict:
    out = {}
    for method in ("open3d", "taichi"):

        def first_and_steady(method=method):
            bf = ta.BlobField(capacity=len(x), sigma=SIGMA, bounds=cube, resolution=64)
            a = clock()
            bf.evaluate(x)
            bf.isosurface(ISO, method=method)
            b = clock()
            bf.evaluate(x)
            bf.isosurface(ISO, method=method)
            return b - a, clock() - b

        out[method] = compile_times(first_and_steady, precision=PRECISION, modes=modes)
        log(
            f"compile ({method}): " + ", ".join(f"{m}: {fmt_s(r['compile'])}" for m, r in out[method].items())
        )
    return out


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    _, out_dir = output_paths(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.quick:
        resolutions, repeats, frames = (32, 48, 64), 3, 45
        modes = ("offline cache off",)
    else:
        resolutions, repeats, frames = (64, 96, 128, 192, 256), 5, FRAMES
        modes = ("offline cache off", "offline cache on, cold", "offline cache on, warm")
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()

    init(PRECISION)
    x, cube = jet_cloud(frames)
    log(f"jet cloud: {len(x)} particles after {frames} frames; cube {cube}")
    comp = compile_measurement(x, cube, modes)
    init(PRECISION)
    rows = [resolution_row(x, cube, r, repeats, node_gather=True) for r in resolutions]
    blobs = [one_blob_row(cube, r) for r in resolutions]
    total = time.perf_counter() - started
    load_end = load_average()

    text = report(
        args,
        rows,
        blobs,
        comp,
        x,
        cube,
        frames,
        repeats,
        machine_info(),
        load_start,
        load_end,
        date,
        engine,
        other,
    )
    (out_dir / "blobs.md").write_text(text)
    (out_dir / "blobs.json").write_text(
        json.dumps({"rows": rows, "one_blob": blobs, "compile": comp}, indent=1, default=str)
    )
    plot(rows, blobs, out_dir / "blobs.png")
    log(f"wrote {out_dir}/blobs.md, blobs.json and blobs.png in {total / 60:.1f} min")


def report(
    args, rows, blobs, comp, x, cube, frames, repeats, info, load_start, load_end, date, engine, other
) -> str:
    side = cube[1][0] - cube[0][0]
    time_rows = []
    for r in rows:
        for method in METHODS:
            m = r["methods"][method]
            time_rows.append(
                [
                    f"{r['resolution']}^3",
                    f"{r['spacing'] * 1e3:.1f} mm = {r['spacing'] / SIGMA:.2f} sigma",
                    f"{r['visited_fraction']:.1%}",
                    fmt_s(r["field_block"]),
                    fmt_s(r["field_node"]) if "field_node" in r else "-",
                    method,
                    fmt_s(m["extraction"]),
                    fmt_s(m["normals"]),
                    f"**{fmt_s(r['field_block'] + m['total'])}**",
                    f"{m['triangles']:,}",
                    "yes"
                    if m["checks"]["all"]
                    else "**no**: " + ", ".join(k for k, ok in m["checks"].items() if not ok),
                ]
            )
    blob_rows = []
    for b in blobs:
        for method in METHODS:
            m = b["methods"][method]
            blob_rows.append(
                [
                    f"{b['resolution']}^3",
                    f"{b['spacing'] / SIGMA:.2f}",
                    method,
                    m["triangles"],
                    f"{m['max_error'] * 1e3:.3f} mm = {m['max_error'] / b['spacing']:.3f} h",
                    f"{m['rms_error'] * 1e3:.3f} mm = {m['rms_error'] / b['spacing']:.3f} h",
                    f"{m['volume_error']:+.2%}",
                ]
            )
    diff = max(r.get("field_node_max_diff", 0.0) for r in rows)
    psi_max = max(r.get("psi_max", 0.0) for r in rows)
    return (
        "## Blobs: meshing time, triangle count and one-blob accuracy against grid resolution\n\n"
        f"`{command_line(args, 'blobs.py')}` ({date}). Cloud: the `blobs` demo after {frames} frames, "
        f"{len(x)} alive particles; sigma = {SIGMA} m, iso = {ISO}, cutoff 3 sigma, {PRECISION}; cube of "
        f"side {side:.2f} m, resolution^3 nodes; median of {repeats} calls after a warm-up. Field: the "
        "engine's gather by block (one neighbour query per block of 8^3 nodes, separable Gaussian) and the "
        "per-node candidate (benchmarks/candidates/blob_node_gather.py; largest difference "
        f"{diff:.1e} where psi reaches {psi_max:.3g}: {PRECISION} rounding). "
        "Total = field + `isosurface()` (extraction, normals, orientation). Checks (`mesh_report`, exact): "
        "closed, edge- and vertex-manifold, consistently oriented, no self-intersection, no zero-area "
        "triangle, outward (see the script's docstring)."
        + (f" Left out (library not installed): {', '.join(MISSING)}." if MISSING else "")
        + "\n\n"
        + md_table(
            [
                "grid",
                "spacing h",
                "nodes visited",
                "field (engine)",
                "field (per node)",
                "extractor",
                "extraction",
                "normals",
                "total",
                "triangles",
                "checks pass",
            ],
            time_rows,
        )
        + "\n\n### One blob against the analytic sphere R = sigma sqrt(ln(1/iso))\n\n"
        f"R = {blobs[0]['radius'] * 1e3:.2f} mm; error = |vertex - centre| - R over all vertices; volume "
        "from the divergence theorem against 4/3 pi R^3.\n\n"
        + md_table(
            ["grid", "h / sigma", "extractor", "triangles", "max error", "RMS error", "volume"], blob_rows
        )
        + "\n\n### JIT compile time (64^3, evaluate + isosurface, first call minus second)\n\n"
        + md_table(
            COMPILE_HEADERS,
            compile_rows("blobs, open3d extractor", comp["open3d"])
            + compile_rows("blobs, taichi extractor", comp["taichi"]),
        )
        + "\n\n### Machine\n\n"
        + machine_table(info, load_start=load_start, load_end=load_end, date=date, engine=engine, other=other)
        + "\n"
    )


def plot(rows, blobs, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = [r["resolution"] for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    ax = axes[0]
    ax.plot(res, [r["field_block"] for r in rows], "k-o", label="field, engine (block gather)")
    if all("field_node" in r for r in rows):
        ax.plot(res, [r["field_node"] for r in rows], "k:o", label="field, per-node gather")
    for i, method in enumerate(METHODS):
        ax.plot(
            res,
            [r["methods"][method]["extraction"] for r in rows],
            "-s",
            color=f"C{i}",
            label=f"extraction, {method}",
        )
        ax.plot(
            res,
            [r["methods"][method]["normals"] for r in rows],
            "--^",
            color=f"C{i}",
            label=f"normals, {method} vertices",
        )
    ax.set_ylabel("seconds per frame")
    ax.set_title("meshing time (jet cloud)", fontsize=10)
    ax = axes[1]
    for i, method in enumerate(METHODS):
        ax.plot(res, [r["methods"][method]["triangles"] for r in rows], "-s", color=f"C{i}", label=method)
    ax.set_ylabel("triangles")
    ax.set_title("triangle count (jet cloud)", fontsize=10)
    ax = axes[2]
    for i, method in enumerate(METHODS):
        ax.plot(
            res,
            [b["methods"][method]["max_error"] for b in blobs],
            "-s",
            color=f"C{i}",
            label=f"max error, {method}",
        )
        ax.plot(
            res,
            [b["methods"][method]["rms_error"] for b in blobs],
            ":s",
            color=f"C{i}",
            label=f"RMS error, {method}",
        )
    ax.plot(res, [b["spacing"] for b in blobs], "k-", lw=0.8, label="grid spacing h")
    ax.set_ylabel("|vertex - centre| - R  [m]")
    ax.set_title(f"one blob vs analytic sphere (sigma = {SIGMA} m)", fontsize=10)
    for ax in axes:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(res)
        ax.set_xticklabels([f"{r}^3" for r in res])
        ax.minorticks_off()
        ax.set_xlabel("grid resolution")
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize=6.5)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
