"""Surfacing a liquid: the engine's blobs (the particles' Gaussian field at its half level, evaluated
in Taichi, Open3D's marching cubes, normals from the field's gradient) against splashsurf (pysplashsurf:
an SPH colour field, marching cubes, in Rust) on the same particles, in the same run.

Clouds: the `dam_break` demo's column (per_width particles across a, 2a high) at rest and after 0.4 s
of collapse (a splashing surge), f32. Both on a grid of half a spacing (the particle radius, r = d/2):
ours with sigma = d and iso = the field's half level inside the lattice; splashsurf with its
documented defaults relative to the radius, smoothing length 2r (SPH support 4r = 2d, as the solver)
and iso 0.6. Each is timed twice: the surface alone (ours with normals=False; splashsurf's
`reconstruct_surface`), and with vertex normals from the field's gradient (ours: the analytic gradient of
the blobs; splashsurf: its colour field's SPH gradient, `reconstruction_pipeline(compute_normals=True,
sph_normals=True)`). Timed after a first call (its compile reported apart), in alternating rounds (each
engine once a round), median, all on every core. Quality, by `spatial.mesh_report`: closed, manifold,
oriented, no self-intersection; the enclosed volume against the particles' volume N d^3; triangles.

    .venv/bin/python benchmarks/fluid_surfacing.py [--quick]
"""

import os

import numpy as np
from harness import Page, clock, fmt_s, init, log, parse_args

import taichi_anim as ta
from taichi_anim.scenes import make_scene
from taichi_anim.scenes.dam_break import LIQUID_CUTOFF, half_level
from taichi_anim.spatial import mesh_report


def clouds(per_width: int, seconds: float) -> list[tuple[str, np.ndarray, float]]:
    """(name, positions, spacing) of the dam break at rest and after `seconds`."""
    scene = make_scene("dam_break", per_width=per_width)
    d = scene.options["width"] / per_width
    idx = scene.model.fluid_particles
    out = [("column at rest", scene.state.positions()[idx].astype(np.float64), d)]
    for _ in range(round(seconds * 60)):
        scene.advance_frame()
    out.append((f"surge at {seconds} s", scene.state.positions()[idx].astype(np.float64), d))
    return out


def quality(v, f, n: int, d: float) -> dict:
    r = mesh_report(v, f)
    ok = r.closed and r.edge_manifold and r.vertex_manifold and r.oriented and not r.self_intersecting
    return dict(ok=bool(ok), volume=float(abs(r.volume) / (n * d**3)), triangles=int(len(f)))


def ours(x: np.ndarray, d: float, normals: bool):
    """(surface(), its mesh's vertices and triangles) for the engine's blobs."""
    lo, hi = x.min(axis=0) - LIQUID_CUTOFF * d, x.max(axis=0) + LIQUID_CUTOFF * d
    resolution = int(np.ceil((hi - lo).max() / (0.5 * d))) + 1  # grid spacing d/2
    bf = ta.BlobField(capacity=len(x), sigma=d, bounds=(lo, hi), resolution=resolution, cutoff=LIQUID_CUTOFF)
    iso = half_level(d, d, LIQUID_CUTOFF)

    def surface():
        bf.evaluate(x)
        return bf.isosurface(iso, normals=normals)

    return surface, lambda m: (m.vertices, m.triangles)


def splashsurf(x: np.ndarray, d: float, normals: bool):
    """(surface(), its mesh's vertices and triangles) for splashsurf."""
    import pysplashsurf

    # pysplashsurf 0.14 takes smoothing_length and cube_size in particle radii, although its docstring
    # says absolute units: absolute values (0.02 m, 0.01 m) gave one tiny sphere per particle.
    settings = dict(particle_radius=0.5 * d, rest_density=1000.0, smoothing_length=2.0, cube_size=1.0,
                    iso_surface_threshold=0.6, multi_threading=True)  # fmt: skip
    x32 = x.astype(np.float32)

    def surface():
        if normals:
            pipeline = pysplashsurf.reconstruction_pipeline
            mesh, _ = pipeline(x32, compute_normals=True, sph_normals=True, **settings)
            assert "normals" in mesh.point_attributes
            return mesh.mesh
        return pysplashsurf.reconstruct_surface(x32, **settings).mesh

    return surface, lambda m: (
        np.asarray(m.vertices, dtype=np.float64),
        np.asarray(m.triangles, dtype=np.int64),
    )


def alternating(engines: dict, x: np.ndarray, d: float, rounds: int) -> dict:
    """Per engine: the first call (compile included), then `rounds` rounds that time every engine once in
    turn (so a slow phase of the machine falls on all of them), the median, and the mesh's quality."""
    out = {}
    for name, (surface, arrays) in engines.items():
        a = clock()
        mesh = surface()
        out[name] = dict(first=clock() - a, times=[], **quality(*arrays(mesh), len(x), d))
    for _ in range(rounds):
        for name, (surface, _) in engines.items():
            a = clock()
            surface()
            out[name]["times"].append(clock() - a)
    for r in out.values():
        r["seconds"] = float(np.median(r.pop("times")))
    return out


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    sizes, rounds = ((10,), 3) if args.quick else ((10, 20, 30), 9)
    init("f32")
    rows, data = [], []
    for per_width in sizes:
        for name, x, d in clouds(per_width, 0.4):
            log(f"{name}: {len(x)} particles")
            engines = {
                "taichi_anim blobs, surface only": ours(x, d, False),
                "splashsurf 0.14, surface only": splashsurf(x, d, False),
                "taichi_anim blobs, normals": ours(x, d, True),
                "splashsurf 0.14, SPH normals": splashsurf(x, d, True),
            }
            res = alternating(engines, x, d, rounds)
            for engine, r in res.items():
                rows.append([name, len(x), engine, fmt_s(r["seconds"]), f"{len(x) / r['seconds']:.3g}",
                             r["triangles"], "ok" if r["ok"] else "**failed**", f"{r['volume']:.3f}",
                             fmt_s(r["first"])])  # fmt: skip
                log(" | ".join(map(str, rows[-1])))
            a, b, an, bn = res.values()
            data.append(dict(cloud=name, particles=len(x), spacing=d, ours=a, splashsurf=b, ours_normals=an,
                             splashsurf_normals=bn, speed_ratio=b["seconds"] / a["seconds"],
                             speed_ratio_normals=bn["seconds"] / an["seconds"]))  # fmt: skip
    page = Page(
        "fluid_surfacing",
        "Surfacing a liquid: blobs against splashsurf",
        args,
        {"clouds": "dam_break demo columns (per_width 10/20/30 across a), at rest and after 0.4 s",
         "grid": "half a spacing (the particle radius) for both",
         "ours": f"Gaussian blobs sigma = d, iso = half the interior value, cutoff {LIQUID_CUTOFF} sigma, "
                 "Open3D marching cubes",
         "splashsurf": "smoothing length 2r (support 2d), cube r, iso 0.6, rest density 1000, "
                       "multi-threaded; surface only: reconstruct_surface; SPH normals: "
                       "reconstruction_pipeline(compute_normals, sph_normals)",
         "threads": os.cpu_count(),
         "repeats": f"median of {rounds} alternating rounds (each engine once a round) after the first call"},
    )  # fmt: skip
    page.table(
        "Per surface",
        ["cloud", "particles", "engine", "time", "particles/s", "triangles", "closed manifold",
         "volume / N d^3", "first call"],
        rows,
        "Time ratios splashsurf / ours (surface only; with SPH normals): "
        + ", ".join(f"{r['cloud']} ({r['particles']}): {r['speed_ratio']:.2f}x; "
                    f"{r['speed_ratio_normals']:.2f}x" for r in data),  # fmt: skip
    )  # fmt: skip
    page.write(data)


if __name__ == "__main__":
    main()
