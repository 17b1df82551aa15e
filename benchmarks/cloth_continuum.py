"""Continuum cloth statics: does the static shape of a cloth depend on its mesh? The StVK membrane with
dihedral bending (FabricMaterial) against mass-spring cloth (ClothMaterial), the dihedral bending against
the Euler-Bernoulli cantilever, and `solve_static` before and after its line search.

Scenes (f64, static equilibria by `ta.solve_static(tol=1e-6)`):

1. Hanging sheet. A 1 m square, 0.2 kg/m², hanging in its own plane (xy, top edge at y = 0) under
   gravity from two clips: the top-edge vertices within 1/8 m of either top corner are pinned. Membrane:
   E = 1e3 N/m (areal), nu = 0.3, D = 1e-4 N m. Springs: ClothMaterial(stretch 1e3 N/m, shear 1e2,
   bend 10; damping irrelevant at rest). Meshes: grids of 8, 16, 32, 64 cells per side (add_cloth_grid,
   Provot's springs for the spring cloth; the same triangles for the membrane) and irregular meshes of the
   same vertex count at 32 and 64 cells (every interior grid vertex moved by up to 0.3 cells in x and y,
   uniform, seed 1, then Delaunay; add_cloth_mesh, whose springs are every edge as a stretch spring plus
   shear/bend springs across edges). Shapes are compared by the displacement u = x - X at 20 material
   points (x in {0, 1/4, 1/2, 3/4, 1}, y in {-1/4, -1/2, -3/4, -1}), interpolated linearly on each mesh's
   rest triangles: "diff" is the largest |u_A - u_B| over those points.
2. The same sheet pinned at the two corner vertices only (point pins), all grids of one material in one
   model: a point force on an elastic sheet has a logarithmically divergent displacement, so this shape
   has no mesh limit (membrane or springs).
3. Cantilever: a strip L = 0.3 m (clamp to tip) x 0.03 m, flat, its first two grid columns (x = -a, 0)
   pinned, checkerboard diagonals, membrane E = 1e4 N/m, nu = 0.3, D = 0.3 N m, 0.2 kg/m²: linear theory
   w_tip = q L^4 / (8 D) = 6.622 mm (w/L = 2.2 %). Three cell aspects (across / along = 1/4, 1/2, 1),
   two or three resolutions each, one model per aspect (one compile, one joint solve, tol = 1e-5:
   the finest strip's forces stop at ~2e-6 of a vertex weight, f64 round-off); against the exact value,
   the clamp-offset prediction (1 + a / 2L)^4 and the 1D discrete beam of the same hinges (NumPy).
4. Solver: the previous method (full regularised Newton steps at h = 100 s, PCG to 1e-8:
   `line_search=False, anderson=False, linear_tol=1e-8`), the line search with inexact Newton alone
   (`anderson=False`) and the default (with Anderson acceleration), on a 17 x 17 spring cloth and a
   17 x 17 fabric falling from flat, pinned at two corners of one edge (ClothMaterial / FabricMaterial
   defaults, add_cloth_grid(plane="xz")), on the 32-cell clipped sheet of scene 1 started flat
   (horizontal) instead of hanging, and on the 30-cell cantilever. Up to 200 iterations each.

Timing: each model's kernels compile in a first `solve_static(max_iterations=1)` (reported as "compile +
1 iteration"); solves then start from a fresh rest state on the compiled model. `ti.sync()` before every
clock read. Other processes share the 2 cores: timings are indicative.

    .venv/bin/python benchmarks/cloth_continuum.py           # full run (~5 min), benchmarks/results/
    .venv/bin/python benchmarks/cloth_continuum.py --quick   # smoke run (~2 min), benchmarks/out/
"""

import json
import time

import numpy as np
from common import (
    OtherLoad,
    clock,
    command_line,
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

G = 9.81
DENSITY = 0.2
SHEET = dict(youngs_modulus=1e3, poisson_ratio=0.3, bending_stiffness=1e-4)
SPRING_K = 1e3
CLIP = 0.125
JITTER, SEED = 0.3, 1
TOL = 1e-6
MAX_ITERATIONS = 200
CANT_L, CANT_W, CANT_D, CANT_E = 0.3, 0.03, 0.3, 1e4
# The 60 x 24 strip's forces stop at ~2e-6 of a vertex weight (f64 round-off of its stiff, fine cells);
# 1e-5 moves its tip by < 1e-8 m.
CANT_TOL = 1e-5
SAMPLES = np.array([(x, y) for y in (-0.25, -0.5, -0.75, -1.0) for x in (0.0, 0.25, 0.5, 0.75, 1.0)])
CENTRE, CORNER = 7, 15  # (0.5, -0.5) and the bottom-left corner (0, -1) in SAMPLES
# The buckled sheet folds at the top edge between the clips: its points there are compared too.
SAMPLES_TOP = np.array([(0.25, 0.0), (0.5, 0.0), (0.75, 0.0)])
SAMPLES_BUCKLED = np.concatenate([SAMPLES_TOP, SAMPLES])
FOLD = 1  # (0.5, 0): the middle of the top edge


# ---------------------------------------------------------------------------------------------------------
# meshes (as in tests/test_continuum_statics.py)


def grid_mesh(x0, x1, y0, y1, nx, ny, *, alternate=False):
    """nx x ny cells over [x0, x1] x [y0, y1] in the xy plane, row by row; triangles counter-clockwise from
    +z, split along (i,j)-(i+1,j+1) like add_cloth_grid(plane="xy"), or in a checkerboard (`alternate`)."""
    X, Y = np.meshgrid(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1))
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    idx = np.arange(len(v)).reshape(ny + 1, nx + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    split = np.stack([np.stack([a, b, d], 1), np.stack([a, d, c], 1)], 1)
    other = np.stack([np.stack([a, b, c], 1), np.stack([b, d, c], 1)], 1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    flip = ((i + j) % 2 == 1).ravel() if alternate else np.zeros(i.size, dtype=bool)
    return v, np.where(flip[:, None, None], other, split).reshape(-1, 3)


def square(cells):
    return grid_mesh(0.0, 1.0, -1.0, 0.0, cells, cells)


def jittered_square(cells):
    from scipy.spatial import Delaunay

    v, _ = square(cells)
    i, j = np.meshgrid(np.arange(cells + 1), np.arange(cells + 1))
    inner = ((i > 0) & (i < cells) & (j > 0) & (j < cells)).ravel()
    rng = np.random.default_rng(SEED)
    v[inner, :2] += rng.uniform(-JITTER, JITTER, (int(inner.sum()), 2)) / cells
    t = Delaunay(v[:, :2]).simplices.astype(np.int64)
    p = v[t]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    t[cw] = t[cw][:, [0, 2, 1]]
    return v, t


def pins(v, clip):
    top = np.abs(v[:, 1]) < 1e-9
    return np.flatnonzero(top & ((v[:, 0] <= clip + 1e-9) | (v[:, 0] >= 1.0 - clip - 1e-9)))


def interpolate(v, t, u, points):
    p = v[t][:, :, :2]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    out = np.empty((len(points), 3))
    for k, q in enumerate(points):
        r = q - p[:, 0]
        l1 = (r[:, 0] * e2[:, 1] - r[:, 1] * e2[:, 0]) / det
        l2 = (e1[:, 0] * r[:, 1] - e1[:, 1] * r[:, 0]) / det
        e = int(np.flatnonzero(np.minimum(np.minimum(l1, l2), 1.0 - l1 - l2) > -1e-9)[0])
        out[k] = (1.0 - l1[e] - l2[e]) * u[t[e, 0]] + l1[e] * u[t[e, 1]] + l2[e] * u[t[e, 2]]
    return out


def mean_uy(v, t, u):
    """Area-weighted mean of u_y (the exact integral of the linear interpolant)."""
    p = v[t]
    area = 0.5 * np.abs(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2])
    return float(np.sum(area * u[t][:, :, 1].mean(1)) / area.sum())


def material(kind):
    if kind == "membrane":
        return ta.FabricMaterial(density=DENSITY, **SHEET)
    return ta.ClothMaterial(density=DENSITY, stretch_stiffness=SPRING_K)


def add_sheet(b, kind, mesh_name, v, t, shift, clip):
    """Add one sheet (rest vertices v + shift in x) to builder b."""
    if mesh_name.startswith("grid"):
        cells = int(mesh_name[4:])
        b.add_cloth_grid(
            origin=(shift, -1.0, 0.0),
            size=(1.0, 1.0),
            resolution=(cells + 1, cells + 1),
            plane="xy",
            material=material(kind),
            pinned=pins(v, clip),
        )
    else:
        b.add_cloth_mesh((v + (shift, 0.0, 0.0), t), material=material(kind), pinned=pins(v, clip))


def mesh_of(name):
    cells = int(name.split("grid")[-1].split("irregular")[-1])
    return square(cells) if name.startswith("grid") else jittered_square(cells)


# ---------------------------------------------------------------------------------------------------------
# solving


def compiled(model):
    """Compile the model's kernels (a one-iteration solve); returns its wall time."""
    t0 = clock()
    ta.solve_static(model, model.state(), max_iterations=1)
    return clock() - t0


def timed_solve(model, x0=None, **options):
    state = model.state()
    if x0 is not None:
        state.particle_x.from_numpy(np.asarray(x0, dtype=np.float64))
    opts = dict(tol=TOL, max_iterations=MAX_ITERATIONS)
    opts.update(options)
    t0 = clock()
    r = ta.solve_static(model, state, **opts)
    r["wall"] = clock() - t0
    x = state.particle_x.to_numpy().astype(np.float64)
    m = model.particle_masses()
    r["total_energy"] = sum(model.energy(x).values()) + float(np.sum(m * G * x[:, 1]))
    return r, x


def bump(v):
    """A start 1 mm out of the plane towards -z at the middle of the top edge, fading to 0 at the bottom
    (picks the same one of the two mirror-image folds on every mesh)."""
    x0 = v.copy()
    x0[:, 2] = -1e-3 * np.sin(np.pi * v[:, 0]) * (1.0 + v[:, 1])
    return x0


def sheet_row(kind, name, buckled_iterations):
    v, t = mesh_of(name)
    b = ta.Builder()
    add_sheet(b, kind, name, v, t, 0.0, CLIP)
    b.add_force_gravity()
    model = b.finalize()
    first = compiled(model)
    r, x = timed_solve(model)
    u = x - v
    us = interpolate(v, t, u, SAMPLES)
    rb, xb = timed_solve(model, bump(v), max_iterations=buckled_iterations)
    ub = interpolate(v, t, xb - v, SAMPLES_BUCKLED)
    log(
        f"{kind:8s} {name:12s}: {r['iterations']} iterations, residual {r['residual']:.1e}, "
        f"{r['linear_iterations']} PCG, {fmt_s(r['wall'])} (compile + 1 iteration {fmt_s(first)}); "
        f"centre u_y {us[CENTRE, 1] * 1e3:.4f} mm; buckled: {rb['iterations']} iterations, residual "
        f"{rb['residual']:.1e}, {fmt_s(rb['wall'])}, fold {ub[FOLD, 2] * 1e3:.3f} mm"
    )
    keys = ("iterations", "converged", "residual", "linear_iterations", "wall", "total_energy")
    return dict(
        kind=kind,
        mesh=name,
        vertices=len(v),
        samples=us.tolist(),
        centre=us[CENTRE].tolist(),
        corner=us[CORNER].tolist(),
        mean_uy=mean_uy(v, t, u),
        max_u=float(np.max(np.linalg.norm(us, axis=1))),
        first=first,
        **{k: r[k] for k in keys},
        buckled=dict(
            samples=ub.tolist(),
            fold=ub[FOLD].tolist(),
            centre=ub[len(SAMPLES_TOP) + CENTRE].tolist(),
            max_u=float(np.max(np.linalg.norm(ub, axis=1))),
            **{k: rb[k] for k in keys},
        ),
        _model=model,
        _x=x,
        _xb=xb,
        _v=v,
    )


def diff(a, b):
    """Largest distance between the displacements of the same material points of two results."""
    return float(np.max(np.linalg.norm(np.asarray(a["samples"]) - np.asarray(b["samples"]), axis=1)))


def point_pins(kind, grids):
    """All grids of one material side by side in one model, pinned at the two top corners only (the
    membrane's as one mesh through add_cloth_mesh: one membrane and one bending term, one compile)."""
    b = ta.Builder()
    meshes, shift, vs, ts, pinned, start = [], 0.0, [], [], [], 0
    for c in grids:
        v, t = square(c)
        if kind == "springs":
            add_sheet(b, kind, f"grid{c}", v, t, shift, 0.0)
        else:
            vs.append(v + (shift, 0.0, 0.0))
            ts.append(t + start)
            pinned.append(pins(v, 0.0) + start)
            start += len(v)
        meshes.append((c, v, t, shift))
        shift += 1.5
    if kind != "springs":
        mesh = (np.concatenate(vs), np.concatenate(ts))
        b.add_cloth_mesh(mesh, material=material(kind), pinned=np.concatenate(pinned))
    b.add_force_gravity()
    model = b.finalize()
    first = compiled(model)
    r, x = timed_solve(model)
    rows, start = [], 0
    for c, v, t, shift in meshes:
        u = x[start : start + len(v)] - (v + (shift, 0.0, 0.0))
        start += len(v)
        us = interpolate(v, t, u, SAMPLES)
        rows.append(
            dict(
                kind=kind, cells=c, samples=us.tolist(), centre=us[CENTRE].tolist(), mean_uy=mean_uy(v, t, u)
            )
        )
    log(
        f"point pins {kind}: {r['iterations']} iterations (joint), {fmt_s(r['wall'])}, compile {fmt_s(first)}"
    )
    return dict(
        kind=kind, rows=rows, iterations=r["iterations"], residual=r["residual"], wall=r["wall"], first=first
    )


# ---------------------------------------------------------------------------------------------------------
# cantilever


def beam_1d_tip(cells):
    """Tip deflection of the 1D discrete beam the strip's hinges form: nodes at x = -a, 0, ..., L (the first
    two fixed), hinge angles (w[i+1] - 2 w[i] + w[i-1]) / a with energy D / (2 a) theta^2 per unit width,
    lumped loads q a (q a / 2 at the tip)."""
    a = CANT_L / cells
    q = DENSITY * G
    n = cells + 2
    B = np.zeros((cells, n))
    for k in range(cells):
        B[k, k : k + 3] = np.array([1.0, -2.0, 1.0]) / a
    K = (CANT_D / a) * B.T @ B
    load = np.full(n, q * a)
    load[-1] = q * a / 2.0
    free = np.arange(2, n)
    return float(np.linalg.solve(K[np.ix_(free, free)], load[free])[-1])


def cantilever(families):
    """The strips (cells along, cells across) of `families` side by side in one mesh, one model (one
    compile, one joint solve); tip deflections per strip, grouped by family. main() makes one model per
    family: all eight strips in one solve took 44 Newton and 670,000 PCG iterations (11 minutes) where
    each family alone takes 5."""
    strips = [(name, along, across) for name, group in families.items() for along, across in group]
    vs, ts, tips, pinned, start = [], [], [], [], 0
    for k, (_, along, across) in enumerate(strips):
        a = CANT_L / along
        v, t = grid_mesh(-a, CANT_L, 0.0, CANT_W, along + 1, across, alternate=True)
        v = v[:, [0, 2, 1]] + (0.0, 0.0, 2.0 * CANT_W * k)
        vs.append(v)
        ts.append(t[:, [0, 2, 1]] + start)
        pinned.append(start + np.flatnonzero(v[:, 0] <= 1e-9))
        tips.append(start + np.flatnonzero(v[:, 0] >= CANT_L - 1e-9))
        start += len(v)
    mat = ta.FabricMaterial(
        density=DENSITY, youngs_modulus=CANT_E, poisson_ratio=0.3, bending_stiffness=CANT_D
    )
    b = ta.Builder()
    b.add_cloth_mesh((np.concatenate(vs), np.concatenate(ts)), material=mat, pinned=np.concatenate(pinned))
    b.add_force_gravity()
    model = b.finalize()
    first = compiled(model)
    r, x = timed_solve(model, tol=CANT_TOL)
    exact = DENSITY * G * CANT_L**4 / (8.0 * CANT_D)
    rows = []
    for (aspect_name, along, across), tip in zip(strips, tips, strict=True):
        a = CANT_L / along
        w = float(-x[tip, 1].mean())
        beam = beam_1d_tip(along)
        rows.append(
            dict(
                aspect=aspect_name,
                along=along,
                across=across,
                a=a,
                c=CANT_W / across,
                tip=w,
                error=w / exact - 1.0,
                clamp_offset=(1.0 + a / (2.0 * CANT_L)) ** 4 - 1.0,
                beam_1d=beam,
                over_beam=w / beam - 1.0,
                twist=float(np.ptp(-x[tip, 1])),
            )
        )
    log(
        f"cantilever: {r['iterations']} iterations, residual {r['residual']:.1e}, {r['linear_iterations']} "
        f"PCG, {fmt_s(r['wall'])}, compile {fmt_s(first)}; errors "
        + ", ".join(f"{row['aspect']} {row['along']}: {row['error'] * 100:+.2f} %" for row in rows)
    )
    return dict(
        rows=rows,
        families={name: [row for row in rows if row["aspect"] == name] for name in families},
        exact=exact,
        iterations=r["iterations"],
        converged=r["converged"],
        residual=r["residual"],
        linear=r["linear_iterations"],
        wall=r["wall"],
        first=first,
        _model=model,
    )


# ---------------------------------------------------------------------------------------------------------
# solver comparison

METHODS = {
    "before: full steps, h = 100 s, PCG 1e-8": dict(line_search=False, anderson=False, linear_tol=1e-8),
    "line search + adaptive h + inexact Newton": dict(anderson=False),
    "default (+ Anderson acceleration)": dict(),
}


def corner_cloth(kind, n):
    b = ta.Builder()
    mat = ta.ClothMaterial() if kind == "springs" else ta.FabricMaterial()
    b.add_cloth_grid(resolution=(n, n), size=(1.0, 1.0), plane="xz", material=mat, pinned=[0, n - 1])
    b.add_force_gravity()
    return b.finalize()


def solver_case(name, model, x0=None, references=None):
    first = compiled(model)
    out = []
    for method, options in METHODS.items():
        r, x = timed_solve(model, x0, **options)
        row = dict(
            case=name,
            method=method,
            first=first,
            **{
                k: r[k]
                for k in (
                    "iterations",
                    "converged",
                    "residual",
                    "linear_iterations",
                    "backtracks",
                    "accelerated",
                    "wall",
                    "total_energy",
                    "history",
                )
            },
        )
        for key, ref in (references or {}).items():
            row[key] = float(np.max(np.linalg.norm(x - ref, axis=1)))
        log(
            f"solver {name} / {method}: {r['iterations']} iterations, residual {r['residual']:.1e}, "
            f"{r['linear_iterations']} PCG, {fmt_s(r['wall'])}"
        )
        out.append(row)
    return out


# ---------------------------------------------------------------------------------------------------------
# output


def fmt_mm(x):
    return f"{x * 1e3:.4f}"


def plot(sheets, points, cant, solver, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
    for kind, color in (("membrane", "C0"), ("springs", "C3")):
        grid = [s for s in sheets if s["kind"] == kind and s["mesh"].startswith("grid")]
        h = [1.0 / int(s["mesh"][4:]) for s in grid[:-1]]
        d = [diff(a, b) * 1e3 for a, b in zip(grid, grid[1:], strict=False)]
        ax[0].loglog(h, d, "o-", color=color, label=f"{kind}, planar, grid: diff to the next finer grid")
        db = [diff(a["buckled"], b["buckled"]) * 1e3 for a, b in zip(grid, grid[1:], strict=False)]
        ax[0].loglog(h, db, "^:", color=color, label=f"{kind}, buckled, grid: diff to the next finer grid")
        irr = [s for s in sheets if s["kind"] == kind and s["mesh"].startswith("irregular")]
        hi, di = [], []
        for s in irr:
            cells = int(s["mesh"][9:])
            same = next((g for g in grid if g["mesh"] == f"grid{cells}"), None)
            if same:
                hi.append(1.0 / cells)
                di.append(diff(s, same) * 1e3)
        ax[0].loglog(
            hi, di, "s", color=color, ms=9, mfc="none", label=f"{kind}: irregular vs grid, same size"
        )
        pr = next(p for p in points if p["kind"] == kind)["rows"]
        hp = [1.0 / r["cells"] for r in pr[:-1]]
        dp = [abs(a["mean_uy"] - b["mean_uy"]) * 1e3 for a, b in zip(pr, pr[1:], strict=False)]
        ax[0].loglog(hp, dp, "x--", color=color, label=f"{kind}, point pins: change of mean u_y")
    ax[0].set_xlabel("cell size [m] (finer mesh to the left)")
    ax[0].set_ylabel("difference [mm]")
    ax[0].set_title("hanging sheet: shape differences between meshes")
    ax[0].legend(fontsize=6)
    ax[0].grid(True, which="both", alpha=0.3)
    for rows, marker in zip(cant["families"].values(), "os^", strict=False):
        ax[1].loglog(
            [r["a"] for r in rows],
            [abs(r["error"]) * 100 for r in rows],
            marker + "-",
            label=f"cells across/along = {rows[0]['aspect']}",
        )
    a = np.geomspace(0.002, 0.03, 20)
    ax[1].loglog(
        a, ((1 + a / (2 * CANT_L)) ** 4 - 1) * 100, "k--", label="clamp at x = -a/2: (1 + a/2L)^4 - 1"
    )
    ax[1].set_xlabel("cell length along the strip a [m]")
    ax[1].set_ylabel("|tip / (q L^4 / 8D) - 1| [%]")
    ax[1].set_title("cantilever: tip deflection error")
    ax[1].legend(fontsize=7)
    ax[1].grid(True, which="both", alpha=0.3)
    styles = dict(zip(METHODS, ("-", "--", "-"), strict=True))
    for case, color in zip(dict.fromkeys(r["case"] for r in solver), ("C0", "C3", "C2", "C1"), strict=False):
        for r in (r for r in solver if r["case"] == case):
            if r["method"].startswith("line search"):
                continue
            ax[2].semilogy(
                r["history"],
                styles[r["method"]],
                color=color,
                lw=1 if r["method"].startswith("before") else 2,
                label=f"{case}: {r['method'].split(':')[0]}",
            )
    ax[2].axhline(TOL, color="k", lw=0.5)
    ax[2].set_xlabel("Newton iteration")
    ax[2].set_ylabel("largest free force / weight")
    ax[2].set_title("solve_static: thin = before, thick = now")
    ax[2].legend(fontsize=6)
    ax[2].grid(True, which="both", alpha=0.3)
    from matplotlib.ticker import NullFormatter

    for a in ax[:2]:
        a.xaxis.set_minor_formatter(NullFormatter())
        a.yaxis.set_minor_formatter(NullFormatter())
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    _, out_dir = output_paths(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.quick:
        grids, irregular, point_grids = (4, 8, 16), (8,), (4, 8)
        families = {"1/4": [(15, 6), (30, 12)], "1": [(30, 3), (60, 6)]}  # also the solver case
        corner_n = 9
    else:
        grids, irregular, point_grids = (8, 16, 32, 64), (32,), (8, 16, 32, 64)
        families = {
            "1/4": [(15, 6), (30, 12), (60, 24)],
            "1/2": [(15, 3), (30, 6), (60, 12)],
            "1": [(30, 3), (60, 6)],
        }
        corner_n = 17
    init("f64", offline_cache=True)
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()

    sheets = []
    for kind in ("membrane", "springs"):
        for name in [f"grid{c}" for c in grids] + [f"irregular{c}" for c in irregular]:
            sheets.append(sheet_row(kind, name, MAX_ITERATIONS))
    points = [point_pins(kind, point_grids) for kind in ("membrane", "springs")]
    parts = {name: cantilever({name: strips}) for name, strips in families.items()}
    cant = dict(
        rows=[r for p in parts.values() for r in p["rows"]],
        families={name: p["rows"] for name, p in parts.items()},
        exact=next(iter(parts.values()))["exact"],
        solves={
            name: {k: v for k, v in p.items() if k not in ("rows", "families") and not k.startswith("_")}
            for name, p in parts.items()
        },
    )

    solver = []
    solver += solver_case(f"{corner_n}² springs, 2 corners, from flat", corner_cloth("springs", corner_n))
    solver += solver_case(f"{corner_n}² fabric, 2 corners, from flat", corner_cloth("fabric", corner_n))
    mid = next(s for s in sheets if s["kind"] == "membrane" and s["mesh"] == f"grid{grids[2]}")
    flat = mid["_v"][:, [0, 2, 1]] * (1.0, 1.0, -1.0)  # rotated about the top edge into the xz plane
    solver += solver_case(
        f"{mid['mesh']} membrane sheet, clips, from flat",
        mid["_model"],
        flat,
        references={"to_planar": mid["_x"], "to_buckled": mid["_xb"]},
    )
    # The cantilever of tests/test_continuum_statics.py (15 and 30 cells, aspect 1/4), its own model.
    small = parts["1/4"] if args.quick else cantilever({"1/4": [(15, 6), (30, 12)]})
    solver += solver_case(f"cantilever, {len(small['rows'])} strips", small["_model"])
    total = time.perf_counter() - started
    load_end = load_average()
    write_outputs(
        args, out_dir, sheets, points, cant, solver, grids, total, load_start, load_end, date, engine, other
    )


def write_outputs(
    args, out_dir, sheets, points, cant, solver, grids, total, load_start, load_end, date, engine, other
):
    plot(sheets, points, cant, solver, out_dir / "cloth_continuum.png")
    by = {(s["kind"], s["mesh"]): s for s in sheets}
    sheet_rows = []
    for s in sheets:
        kind, name = s["kind"], s["mesh"]
        prefix = "grid" if name.startswith("grid") else "irregular"
        cells = int(name[len(prefix) :])
        finer = by.get((kind, f"{prefix}{2 * cells}"))
        same = by.get((kind, f"grid{cells}")) if prefix == "irregular" else None
        sheet_rows.append(
            [
                kind,
                name,
                s["vertices"],
                fmt_mm(s["centre"][1]),
                fmt_mm(s["centre"][0]),
                f"{fmt_mm(s['corner'][0])}, {fmt_mm(s['corner'][1])}",
                fmt_mm(s["mean_uy"]),
                fmt_mm(s["max_u"]),
                f"**{fmt_mm(diff(s, finer))}**" if finer else "–",
                f"**{fmt_mm(diff(s, same))}**" if same else "–",
                s["iterations"],
                s["linear_iterations"],
                f"{s['residual']:.1e}",
                fmt_s(s["wall"]),
                fmt_s(s["first"]),
            ]
        )
    buckled_rows = []
    for s in sheets:
        kind, name, bk = s["kind"], s["mesh"], s["buckled"]
        prefix = "grid" if name.startswith("grid") else "irregular"
        cells = int(name[len(prefix) :])
        finer = by.get((kind, f"{prefix}{2 * cells}"))
        same = by.get((kind, f"grid{cells}")) if prefix == "irregular" else None
        buckled_rows.append(
            [
                kind,
                name,
                fmt_mm(bk["fold"][2]),
                ", ".join(fmt_mm(c) for c in bk["centre"]),
                fmt_mm(bk["max_u"]),
                f"{(bk['total_energy'] - s['total_energy']) * 1e6:+.2f}",
                f"**{fmt_mm(diff(bk, finer['buckled']))}**" if finer else "–",
                f"**{fmt_mm(diff(bk, same['buckled']))}**" if same else "–",
                bk["iterations"],
                "yes" if bk["converged"] else "**no**",
                f"{bk['residual']:.1e}",
                bk["linear_iterations"],
                fmt_s(bk["wall"]),
            ]
        )
    point_rows = []
    for p in points:
        rows = p["rows"]
        for k, r in enumerate(rows):
            nxt = rows[k + 1] if k + 1 < len(rows) else None
            point_rows.append(
                [
                    r["kind"],
                    f"grid{r['cells']}",
                    fmt_mm(r["centre"][1]),
                    fmt_mm(r["centre"][0]),
                    fmt_mm(r["mean_uy"]),
                    fmt_mm(nxt["mean_uy"] - r["mean_uy"]) if nxt else "–",
                    f"**{fmt_mm(diff(r, nxt))}**" if nxt else "–",
                ]
            )
    cant_rows = []
    for rows in cant["families"].values():
        for r in rows:
            cant_rows.append(
                [
                    r["aspect"],
                    f"{r['along']} x {r['across']}",
                    f"{r['a'] * 1e3:.2f} x {r['c'] * 1e3:.2f}",
                    f"{r['tip'] * 1e3:.5f}",
                    f"**{r['error'] * 100:+.2f} %**",
                    f"{r['clamp_offset'] * 100:+.2f} %",
                    f"{((1 + r['error']) / (1 + r['clamp_offset']) - 1) * 100:+.2f} %",
                    f"{r['over_beam'] * 100:+.2f} %",
                    f"{r['twist'] / r['tip']:.1e}",
                ]
            )
    solver_rows = [
        [
            r["case"],
            r["method"],
            r["iterations"],
            "yes" if r["converged"] else "**no**",
            f"{r['residual']:.1e}",
            r["linear_iterations"],
            r["backtracks"],
            r["accelerated"],
            f"{r['total_energy']:.9f}",
            f"{fmt_mm(r['to_planar'])} / {fmt_mm(r['to_buckled'])}" if "to_planar" in r else "–",
            fmt_s(r["wall"]),
            fmt_s(r["first"]),
        ]
        for r in solver
    ]
    fine = grids[-1]
    text = (
        "# Continuum cloth statics: mesh (in)dependence, cantilever, solver\n\n"
        f"Regenerate: `{command_line(args, 'cloth_continuum.py')}` (took {total / 60:.1f} min). "
        "Scenes, metrics and settings: the script's docstring; in short: f64, `ta.solve_static(tol=1e-6, "
        f"max_iterations={MAX_ITERATIONS})` (cantilever tol {CANT_TOL:g}), 1 m square sheet at 0.2 kg/m² "
        f"hanging in its plane from two {CLIP} m clips (membrane E = {SHEET['youngs_modulus']:g} N/m, "
        f"nu = {SHEET['poisson_ratio']}, "
        f"D = {SHEET['bending_stiffness']:g} N m; springs k = {SPRING_K:g} N/m stretch, ClothMaterial's "
        f"shear 1e2 and bend 10), irregular meshes jittered by {JITTER} cells (seed {SEED}) and Delaunay "
        "re-triangulated. u = displacement from the rest shape at 20 material points below the top edge "
        "(centre = (0.5, -0.5), corner = bottom-left (0, -1)); diff = largest |u_A - u_B| over those points. "
        "Timings are indicative: other processes were running on this 2-core machine (row below).\n\n"
        + machine_table(
            machine_info(), load_start=load_start, load_end=load_end, date=date, engine=engine, other=other
        )
        + "\n\n![cloth_continuum](cloth_continuum.png)\n\n"
        "## 1. Hanging sheet, clips: mesh dependence\n\n"
        + md_table(
            [
                "model",
                "mesh",
                "vertices",
                "centre u_y [mm]",
                "centre u_x [mm]",
                "corner u_x, u_y [mm]",
                "mean u_y [mm]",
                "max |u| [mm]",
                "diff to the next finer mesh of its kind [mm]",
                "diff to the grid of the same size [mm]",
                "Newton iterations",
                "PCG iterations",
                "residual",
                "solve",
                "compile + 1 iteration",
            ],
            sheet_rows,
        )
        + "\n\n"
        + sheet_findings(by, grids)
        + "\n\n## 1b. The same sheets buckled: the stable equilibrium\n\n"
        "The planar solution above is a saddle of the energy: between the clips the top edge is compressed "
        "and folds out of the plane as soon as anything breaks the symmetry (a solve from flat ends folded "
        "too, section 4). Here every sheet starts 1 mm out of plane at the middle of its top edge (`bump`: "
        "-1 mm sin(pi x) (1 + y)) and is solved on the same model. fold = u_z at the middle of the top "
        "edge; dE = energy of the buckled minus the planar solution; diffs over the 20 points of section 1 "
        "and three points of the top edge (x = 1/4, 1/2, 3/4).\n\n"
        + md_table(
            [
                "model",
                "mesh",
                "fold u_z [mm]",
                "centre u [mm]",
                "max |u| [mm]",
                "dE [µJ]",
                "diff to the next finer mesh of its kind [mm]",
                "diff to the grid of the same size [mm]",
                "Newton iterations",
                "converged",
                "residual",
                "PCG iterations",
                "solve",
            ],
            buckled_rows,
        )
        + "\n\n"
        + sheet_findings(by, grids, buckled=True)
        + "\n\n## 2. Hanging sheet, corner vertices pinned (no mesh limit)\n\n"
        "All grids of one material in one model (one joint solve: "
        + ", ".join(
            f"{p['rows'][0]['kind']} {p['iterations']} iterations, residual {p['residual']:.1e}"
            for p in points
        )
        + "). A point force on a 2D elastic sheet has a displacement that grows like log(1/r) towards it; a "
        "mesh cuts that off at r ~ a, so the sheet keeps sliding down by about the same amount at every "
        "halving of the cells (F / (pi E) ln 2 ~ 2e-4 m for F = half the weight, times a corner factor).\n\n"
        + md_table(
            [
                "model",
                "mesh",
                "centre u_y [mm]",
                "centre u_x [mm]",
                "mean u_y [mm]",
                "change of mean u_y to the next grid [mm]",
                "diff to the next grid [mm]",
            ],
            point_rows,
        )
        + "\n\n## 3. Cantilever against Euler-Bernoulli\n\n"
        f"Exact (linear): w_tip = q L^4 / (8 D) = {cant['exact'] * 1e3:.4f} mm. One model per cell "
        "aspect, its strips in one joint solve ("
        + "; ".join(
            f"{name}: {p['iterations']} Newton iterations, {p['linear']} PCG iterations, residual "
            f"{p['residual']:.1e}, {fmt_s(p['wall'])}, compile + 1 iteration {fmt_s(p['first'])}"
            for name, p in cant["solves"].items()
        )
        + "). 'clamp offset' = (1 + a/2L)^4 - 1, "
        "the first-order error of the hinge on the clamped column (it lumps the curvature of [-a/2, a/2], "
        "so the clamp acts at x = -a/2); '1D beam' = the discrete beam those hinges form (NumPy), i.e. "
        "what the mesh would give if every cross-section stayed straight.\n\n"
        + md_table(
            [
                "cells across / along",
                "cells (along x across)",
                "cell a x c [mm]",
                "tip [mm]",
                "error vs exact",
                "clamp offset",
                "error vs clamp-offset prediction",
                "tip / 1D discrete beam - 1",
                "twist (spread / tip)",
            ],
            cant_rows,
        )
        + "\n\n"
        + cantilever_findings(cant)
        + "\n\n## 4. solve_static before and after the line search\n\n"
        "Each case's model compiled once ('compile + 1 iteration'); every method then starts from the same "
        "state. Energy = elastic + gravity potential [J] at the end. 'to the planar / buckled solution' = "
        "the largest vertex distance from the sheet solved from its hanging rest shape (section 1) and "
        "from the bump (section 1b).\n\n"
        + md_table(
            [
                "case",
                "method",
                "Newton iterations",
                "converged",
                "residual",
                "PCG iterations",
                "line-search cuts",
                "Anderson steps",
                "energy [J]",
                "to the planar / buckled solution [mm]",
                "solve",
                "compile + 1 iteration",
            ],
            solver_rows,
        )
        + "\n"
    )
    (out_dir / "cloth_continuum.md").write_text(text)
    strip = lambda d: {k: v for k, v in d.items() if not k.startswith("_")}  # noqa: E731
    (out_dir / "cloth_continuum.json").write_text(
        json.dumps(
            {
                "settings": {
                    "density": DENSITY,
                    "sheet": SHEET,
                    "spring_stiffness": SPRING_K,
                    "clip": CLIP,
                    "jitter": JITTER,
                    "seed": SEED,
                    "tol": TOL,
                    "max_iterations": MAX_ITERATIONS,
                    "samples": SAMPLES.tolist(),
                    "cantilever": dict(L=CANT_L, W=CANT_W, D=CANT_D, E=CANT_E),
                    "finest_grid": fine,
                },
                "machine": machine_info(),
                "load": [load_start, load_end],
                "other_processes_cores": other.cores(),
                "date": date,
                "engine": engine,
                "total_seconds": total,
                "sheets": [strip(s) for s in sheets],
                "point_pins": points,
                "cantilever": strip(cant),
                "solver": solver,
            },
            indent=1,
        )
    )
    log(f"wrote {out_dir / 'cloth_continuum.md'} ({total / 60:.1f} min)")


def sheet_findings(by, grids, buckled=False):
    lines = []
    for kind in ("membrane", "springs"):
        pick = (lambda s: s["buckled"]) if buckled else (lambda s: s)  # noqa: E731
        g = [pick(by[(kind, f"grid{c}")]) for c in grids]
        d = [diff(a, b) for a, b in zip(g, g[1:], strict=False)]
        seq = ", ".join(f"{x * 1e3:.3f}" for x in d)
        ratios = ", ".join(f"{b / a:.2f}" for a, b in zip(d, d[1:], strict=False))
        irr = [(c, pick(by[(kind, f"irregular{c}")])) for c in grids if (kind, f"irregular{c}") in by]
        irr_txt = "; ".join(
            f"irregular vs grid at {c} cells {diff(s, pick(by[(kind, f'grid{c}')])) * 1e3:.3f} mm "
            f"({diff(s, pick(by[(kind, f'grid{c}')])) / pick(by[(kind, f'grid{c}')])['max_u'] * 100:.1f} % "
            "of the grid's max |u|)"
            for c, s in irr
        )
        lines.append(f"- **{kind}**: diffs between successive grids {seq} mm (ratios {ratios}); {irr_txt}.")
    return "\n".join(lines)


def cantilever_findings(cant):
    lines = []
    for rows in cant["families"].values():
        rel = ", ".join(f"{r['over_beam'] * 100:+.2f} %" for r in rows)
        rich = 2 * rows[-1]["error"] - rows[-2]["error"]
        lines.append(
            f"- cells across/along = {rows[0]['aspect']}: errors "
            + ", ".join(f"{r['error'] * 100:+.2f} %" for r in rows)
            + f"; Richardson 2 e(a) - e(2a) at the two finest = {rich * 100:+.2f} %; against the 1D discrete "
            f"beam {rel}."
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
