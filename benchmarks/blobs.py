"""Blob meshing on the `blobs` demo's jet: field evaluation and isosurface time, triangle count and mesh
checks at 64^3 ... 256^3 for the three extractors (Open3D's marching cubes, scikit-image's, the engine's
Taichi marching tetrahedra), and one blob's mesh against the analytic sphere.

Cloud: the `blobs` scene from the catalogue (seed 0, 1500-particle jet) after 90 frames (45 with
--quick); sigma 0.04 m, iso 0.5, f32, on a cube around the demo's box. Timed after a warm-up call (its
compile reported apart), median of repeats: `BlobField.evaluate` (field) and `BlobField.isosurface`
(extraction + gradient normals + orientation). Checks by `spatial.mesh_report`: closed, manifold,
oriented, no self-intersection, outward. One blob: error = |vertex - centre| - R, R = sigma sqrt(ln 2).

    .venv/bin/python benchmarks/blobs.py [--quick]
"""

import importlib.util

import numpy as np
from harness import Page, clock, fmt_s, init, log, median_time, parse_args

import taichi_anim as ta
from taichi_anim.scenes import make_scene
from taichi_anim.spatial import mesh_report

SIGMA, ISO = 0.04, 0.5
METHODS = [
    m
    for m, lib in (("open3d", "open3d"), ("skimage", "skimage"), ("taichi", None))
    if lib is None or importlib.util.find_spec(lib)
]


def jet(frames: int):
    scene = make_scene("blobs")
    for _ in range(frames):
        scene.advance_frame()
    lo, hi = (np.asarray(b, float) for b in scene.bounds)
    c, half = 0.5 * (lo + hi), 0.5 * (hi - lo).max() + 0.1
    return scene.state.snapshot().x.astype(np.float64), (tuple(c - half), tuple(c + half))


def checks(v, f) -> str:
    r = mesh_report(v, f)
    ok = {
        "closed": r.closed,
        "manifold": r.edge_manifold and r.vertex_manifold,
        "oriented": r.oriented,
        "no self-intersection": not r.self_intersecting,
        "outward": r.volume > 0,
    }
    return "ok" if all(ok.values()) else "**" + ", ".join(k for k, v in ok.items() if not v) + " failed**"


def one_blob(cube, res: int, method: str) -> float:
    """Largest |vertex - centre| - R over a lone blob's mesh, in grid spacings (NaN: no surface)."""
    centre = 0.5 * (np.asarray(cube[0]) + np.asarray(cube[1])) + [0.0123, -0.0071, 0.0049]
    bf = ta.BlobField(capacity=1, sigma=SIGMA, bounds=cube, resolution=res)
    bf.evaluate(centre[None])
    v = bf.isosurface(ISO, method=method).vertices
    if not len(v):  # the blob is finer than the grid
        return float("nan")
    err = np.linalg.norm(v - centre, axis=1) - SIGMA * np.sqrt(np.log(1 / ISO))
    return float(np.abs(err).max() / bf.spacing)


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    resolutions, repeats, frames = ((32, 64), 3, 45) if args.quick else ((64, 96, 128, 192, 256), 5, 90)
    init("f32")
    x, cube = jet(frames)
    log(f"{len(x)} particles, extractors {METHODS}")
    rows, data = [], []
    for res in resolutions:
        bf = ta.BlobField(capacity=len(x), sigma=SIGMA, bounds=cube, resolution=res)
        a = clock()
        bf.evaluate(x)
        first = clock() - a
        field = median_time(lambda bf=bf: bf.evaluate(x), repeats=repeats, warmup=0)
        visited = bf.active_block_count * 8**3 / np.prod(bf.dims)
        for m in METHODS:
            a = clock()
            mesh = bf.isosurface(ISO, method=m)
            first_mesh = clock() - a
            t = median_time(lambda bf=bf, m=m: bf.isosurface(ISO, method=m), repeats=repeats, warmup=0)
            err = one_blob(cube, res, m)
            rows.append(
                [
                    f"{res}³",
                    m,
                    fmt_s(field),
                    fmt_s(t),
                    fmt_s(field + t),
                    mesh.triangle_count,
                    f"{visited:.1%}",
                    checks(mesh.vertices, mesh.triangles),
                    f"{err:.3f}",
                    f"{fmt_s(first)} + {fmt_s(first_mesh)}",
                ]
            )
            data.append(
                {
                    "resolution": res,
                    "method": m,
                    "field": field,
                    "isosurface": t,
                    "first": first_mesh,
                    "triangles": int(mesh.triangle_count),
                    "visited": float(visited),
                    "one_blob": err,
                }
            )
            log(" | ".join(map(str, rows[-1])))
    missing = [m for m in ("open3d", "skimage") if m not in METHODS]
    page = Page(
        "blobs",
        "Blob meshing: Open3D, scikit-image and Taichi extractors",
        args,
        {
            "cloud": f"`blobs` scene, seed 0, {len(x)} alive particles after {frames} frames",
            "field": f"sigma {SIGMA} m, iso {ISO}, cutoff 3 sigma, 8^3-node blocks near particles, f32",
            "repeats": f"median of {repeats} after the first (compile) call",
            "extractors left out (library missing)": ", ".join(missing) or "none",
        },
    )
    page.table(
        "Meshing the jet",
        [
            "grid",
            "extractor",
            "field",
            "isosurface",
            "total",
            "triangles",
            "nodes visited",
            "mesh checks",
            "one blob: max error [spacings]",
            "first calls",
        ],
        rows,
    )
    page.write(data)


if __name__ == "__main__":
    main()
