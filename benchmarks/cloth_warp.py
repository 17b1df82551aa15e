"""Mass-spring cloth: taichi_anim against NVIDIA Warp's cross-framework cloth benchmark
(warp/examples/benchmarks/benchmark_cloth.py) and its warp, taichi and numpy modes, same scene, same process.

Scene (Warp's `Cloth`, read from its source by peers/warp_cloth.py): dim x dim vertices 0.1 m apart,
0.1 kg each, two corners pinned; structural, shear and bend springs, k = 1000 N/m, damping 10; gravity;
60 frames of 1/60 s x 16 symplectic Euler substeps, positions read as NumPy every frame (ours: a copy,
`state.positions()`; Warp on the CPU: a view of its array), f32.
Ours: `add_particles` + `add_springs` + `add_force_gravity`, `symplectic_euler` with check_every = 16.
Reported: median ms per frame, speed-up (peer / ours), first frame apart, the engine's compile (cold and
warm offline cache), and our positions against warp's after the same frames.

    .venv/bin/python benchmarks/cloth_warp.py [--quick] [--arch cuda]
"""

import numpy as np
from harness import (
    Page,
    Run,
    clock,
    compile_times,
    fmt_s,
    host_clock,
    init,
    log,
    parse_args,
    peer,
    ratio,
    time_run,
    versions,
)

import taichi_anim as ta

SIZES, QUICK_SIZES = (32, 64, 128, 256), (32, 64)
OURS = "taichi_anim"


def build_ours(cloth):
    b = ta.Builder()
    b.add_particles(cloth.positions.astype(np.float64), mass=np.where(cloth.inv_masses > 0, 0.1, 0.0))
    b.add_springs(
        cloth.spring_indices.reshape(-1, 2), stiffness=cloth.spring_stiffness, damping=cloth.spring_damping
    )
    b.add_force_gravity((0.0, -9.81, 0.0))
    model = b.finalize()
    return model, model.state(), ta.make_integrator("symplectic_euler", check_every=16)


def ours(cloth, arch: str, dt: float, substeps: int, *, cpu_threads=None, mode=None):
    """A frame function of the engine on Warp's cloth; cpu_threads and a frame mode forced (`mode`, for
    cloth_bound.py's bound) optional."""
    init("f32", arch, cpu_threads=cpu_threads)  # after their taichi mode's own ti.init
    model, state, integ = build_ours(cloth)
    stepper = integ.stepper_for(model)
    if mode is not None:
        stepper._frame_mode = {"mode": mode, "reason": "forced by the benchmark"}

    def frame():
        stepper.advance(state, dt / substeps, substeps)
        # The engine's read of positions (a float64 copy; 79 against 140 us for Taichi's to_numpy at 32^2,
        # which starts a parallel loop); warp_cpu returns a view of its array.
        return state.positions()

    return frame


def theirs(wc, mode: str, cloth, dt: float, substeps: int):
    integ = wc.make_integrator(mode, wc.fresh(cloth))
    return lambda: integ.simulate(dt, substeps)


def main(argv=None) -> int:
    args = parse_args(
        __doc__, argv, lambda p: p.add_argument("--arch", choices=("cpu", "cuda"), default="cpu")
    )
    wc = peer("warp_cloth")
    if wc is None:
        return 1  # the scene itself is Warp's
    import warp as wp

    wp.config.quiet = True
    if args.arch == "cuda" and (why := wc.cuda_available())["taichi"]:
        log(f"no CUDA for Taichi here ({why['taichi']}): nothing measured")
        return 1
    modes = wc.MODES_CUDA if args.arch == "cuda" else wc.MODES_CPU
    sizes, frames = (QUICK_SIZES, 10) if args.quick else (SIZES, 60)
    sc = wc.scene(32)["constants"]
    dt, substeps = float(sc["sim_dt"]), int(sc["sim_substeps"])
    rows, data = [], []
    for dim in sizes:
        log(f"{dim}^2")
        cloth = wc.make_cloth(dim)
        runs = [Run(m, lambda m=m, c=cloth: theirs(wc, m, c, dt, substeps), sync=host_clock) for m in modes]
        runs.append(Run(OURS, lambda c=cloth: ours(wc.fresh(c), args.arch, dt, substeps)))
        res = {r.name: time_run(r, frames=frames, budget_s=20 if args.quick else 120) for r in runs}
        ref = runs[0]
        same = res[OURS]["frames"] == res[ref.name]["frames"]
        diff = float(np.abs(runs[-1].result - ref.result).max()) if same else None
        t = res[OURS]["median"]
        row = [f"{dim}²", f"{t * 1e3:.2f}"] + [
            f"{res[m]['median'] * 1e3:.2f} ({ratio(res[m]['median'], t)})" for m in modes
        ]
        rows.append(row + [fmt_s(res[OURS]["first"]), f"{diff:.1e} m" if diff is not None else "–"])
        data.append({"dim": dim, "runs": res, "max_abs_diff_vs_" + ref.name: diff})

    def first_and_steady():
        frame = ours(wc.make_cloth(QUICK_SIZES[-1]), args.arch, dt, substeps)
        a = clock()
        frame()
        b = clock()
        frame()
        return b - a, clock() - b

    comp = compile_times(first_and_steady) if args.arch == "cpu" else {}
    page = Page(
        "cloth_warp" + ("_cuda" if args.arch == "cuda" else ""),
        "Cloth against Warp's cloth benchmark",
        args,
        {
            "scene": f"Warp's benchmark_cloth.py Cloth: {wc.scene(32)['cloth_kwargs']}",
            "step": f"{substeps} symplectic Euler substeps per 1/{round(1 / dt)} s frame, f32, {args.arch}",
            "frames": f"{frames} timed after 2 warm-up frames (cut after the time budget)",
            "peers": ", ".join(f"{k} {v}" for k, v in versions("warp-lang", "usd-core").items()),
        },
    )
    page.table(
        "ms per frame (median; peer / ours in brackets)",
        ["grid", OURS, *modes, "our first frame", f"|x - x_{modes[0]}| max"],
        rows,
    )
    comp_rows = [[m, fmt_s(c["first"]), fmt_s(c["steady"]), fmt_s(c["compile"])] for m, c in comp.items()]
    if comp:
        page.table(
            f"Compile ({QUICK_SIZES[-1]}², fresh ta.init)",
            ["offline cache", "first frame", "steady", "compile"],
            comp_rows,
        )
    page.write({"sizes": data, "compile": comp})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
