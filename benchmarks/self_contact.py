"""Cloth self-contact: what it costs as a share of a step, and the stacked-sheets scene against Newton's
VBD solver with self-contact in the same run.

Part 1, the share of the step (`share`): the `layers` scene (taichi_anim/scenes/layers.py: two 1 m
sheets of n x n vertices, 0.2 kg/m^2 springs, 3 cm apart, the lower at 0.6 m, over a 0.25 m ball on the
floor; self-contact thickness 5 mm, friction 0.3, 4 Gauss-Seidel sweeps) for n = 64 and 128. It is run by
implicit Euler (PCG, tol 1e-4) at dt = 1/600 s to t = RUN_UP s, when the sheets lie on the ball and on
each other; from that state, STEPS steps are timed for implicit Euler at 1/600 s and for symplectic Euler
at its stable step 0.4 sqrt(m / k) (m the vertex mass, k = 1e3 N/m). Per step: the whole step, and the
self-contact solver's part (its calls wrapped by a synchronised clock), median over the steps.

Part 2, against Newton (`newton`): the same scene at 33 x 33 vertices per sheet (32 x 32 cells), 1/60 s
frames of 10 steps, implicit Euler, FRAMES frames; Newton's SolverVBD with self-contact (its settings in
benchmarks/peers/newton_vbd.py, extra `newton`) on the same sheets, ball and floor in the same process,
with and without self-contact. Per frame: wall time (JIT compile reported apart: the first frame) and
the crossing triangle pairs (non-adjacent triangles that intersect, counted by the exact test of
taichi_anim.spatial on every frame, outside the timed region).

    .venv/bin/python benchmarks/self_contact.py [--quick] [--part share|newton]
"""

import statistics
import time

import numpy as np
from harness import Page, clock, init, log, parse_args, peer

import taichi_anim as ta
from taichi_anim.scenes.layers import build_model
from taichi_anim.spatial import intersecting_triangle_pairs

FRAME_DT = 1.0 / 60.0
SUBSTEPS = 10
RUN_UP = 0.3  # [s]: the sheets lie on the ball and on each other
STEPS = 20
FRAMES = 90


def implicit():
    return ta.make_integrator("implicit_euler", linear_solver="pcg", tol=1e-4, max_iterations=200)


def timed_contact(stepper) -> list:
    """Wrap the stepper's self-contact calls with a synchronised clock; returns the accumulator."""
    sc = stepper.self_contact
    spent = [0.0]
    begin, solve = sc.begin, sc.solve

    def timed(fn):
        def call(*args):
            t0 = clock()
            fn(*args)
            spent[0] += clock() - t0

        return call

    sc.begin, sc.solve = timed(begin), timed(solve)
    return spent


def measure_steps(model, state, integrator, dt: float, steps: int) -> dict:
    stepper = integrator.stepper_for(model)
    spent = timed_contact(stepper)
    for _ in range(3):  # compile: the first call builds the hierarchies, later ones refit them
        integrator.step(model, state, dt)
    totals, parts = [], []
    for _ in range(steps):
        spent[0] = 0.0
        t0 = clock()
        integrator.step(model, state, dt)
        totals.append(clock() - t0)
        parts.append(spent[0])
    stats = stepper.self_contact.read_stats()
    total, part = statistics.median(totals), statistics.median(parts)
    return {
        "dt": dt,
        "ms_step": 1e3 * total,
        "ms_contact": 1e3 * part,
        "share": part / total,
        "pairs": stats["vertex_triangle_pairs"] + stats["edge_edge_pairs"],
    }


def share(n: int, quick: bool, broad_phase: str = "auto", explicit: bool = True) -> dict:
    log(f"share: n = {n}, broad phase {broad_phase}")
    # Finer sheets put more primitives within a thickness of a vertex: larger pair lists.
    model = build_model(
        layers=2, resolution=n, broad_phase=broad_phase, pairs_per_vertex=256 if n > 64 else 128
    )
    state = model.state()
    run_up = implicit()
    t0 = time.perf_counter()
    for _ in range(round((0.05 if quick else RUN_UP) * 600)):
        run_up.step(model, state, FRAME_DT / SUBSTEPS)
    run_up_s = time.perf_counter() - t0
    snap = state.particle_x.to_numpy(), state.particle_v.to_numpy()
    mass = 0.2 * (1.0 / (n - 1)) ** 2
    out = {"n": n, "vertices": model.particle_count, "run_up_s": run_up_s, "broad_phase": broad_phase}
    methods = [("implicit Euler", implicit(), FRAME_DT / SUBSTEPS)]
    if explicit:
        stable = 0.4 * np.sqrt(mass / 1e3)
        methods.append(("symplectic Euler", ta.make_integrator("symplectic_euler", check_every=10), stable))
    for name, integ, dt in methods:
        state.particle_x.from_numpy(snap[0])
        state.particle_v.from_numpy(snap[1])
        out[name] = measure_steps(model, state, integ, dt, 4 if quick else STEPS)
        log(f"  {name}: {out[name]}")
    return out


def ours_frames(frames: int, **options) -> dict:
    """The layers scene at 33^2 per sheet: ms per frame and crossing pairs per frame."""
    model = build_model(layers=2, resolution=33, **options)
    state = model.state()
    integ = implicit()
    times, cpu, crossings = [], [], []
    for _ in range(frames + 1):
        t0, c0 = clock(), time.process_time()
        for _ in range(SUBSTEPS):
            integ.step(model, state, FRAME_DT / SUBSTEPS)
        times.append(clock() - t0)
        cpu.append(time.process_time() - c0)
        x = state.particle_x.to_numpy().astype(np.float64)
        crossings.append(len(intersecting_triangle_pairs(x, model.triangles)))
    return {
        "first_frame_s": times[0],  # JIT compile included
        "ms_frame": [1e3 * t for t in times[1:]],
        "cpu_ms_frame": [1e3 * t for t in cpu[1:]],
        "crossings": crossings[1:],
    }


def newton_part(frames: int) -> dict:
    """Ours and Newton's VBD (with and without self-contact), one after the other in this process."""
    results = {"taichi_anim": ours_frames(frames)}
    log("taichi_anim: proximity only, and without self-contact")
    results["taichi_anim_proximity_only"] = ours_frames(frames, guard=False)
    results["taichi_anim_no_self_contact"] = ours_frames(frames, self_contact=False)
    newton_vbd = peer("newton_vbd", extra="newton")
    for contact in (True, False) if newton_vbd else ():
        key = f"newton_vbd{'' if contact else '_no_self_contact'}"
        log(f"newton: self_contact={contact}")
        r = newton_vbd.run(frames, contact)
        results[key] = {
            "first_frame_s": r["warmup_s"],  # a first instance run for one frame: Warp's compile
            "ms_frame": (1e3 * r["frame_s"]).tolist(),
            "cpu_ms_frame": (1e3 * r["frame_cpu_s"]).tolist(),
            "crossings": newton_vbd.crossings_per_frame(r)[1:].tolist(),
            "settings": r["settings"],
        }
    return results


def summary(frames: dict) -> dict:
    ms = frames["ms_frame"]
    return {
        "median_ms": statistics.median(ms),
        "mean_ms": float(np.mean(ms)),
        "cpu_ms": float(np.mean(frames["cpu_ms_frame"])),
        "max_crossings": int(max(frames["crossings"])),
        "frames_with_crossings": int(sum(c > 0 for c in frames["crossings"])),
    }


def main(argv=None) -> None:
    def options(p):
        p.add_argument("--part", choices=["all", "share", "newton"], default="all")

    args = parse_args(__doc__, argv, options)
    init("f32")
    shares = (
        [share(n, args.quick) for n in ((16, 24) if args.quick else (64, 128))]
        if args.part != "newton"
        else []
    )
    frames, run_up, steps = (3, 0.05, 4) if args.quick else (FRAMES, RUN_UP, STEPS)
    newton = newton_part(frames) if args.part != "share" else {}
    page = Page(
        "self_contact" + ("" if args.part == "all" else f"_{args.part}"),
        "Cloth self-contact",
        args,
        {
            "share": f"layers scene, 2 sheets of n² vertices, run up to {run_up} s by implicit Euler, then "
            f"{steps} steps timed: implicit Euler (PCG 1e-4) at 1/600 s, symplectic Euler at 0.4 sqrt(m/k)",
            "against Newton": f"layers scene, 2 x 33², 1/60 s frames of {SUBSTEPS} implicit steps, {frames} "
            "frames; Newton's SolverVBD (peers/newton_vbd.py) on the same sheets; crossings counted untimed",
        },
    )
    rows = [
        [
            f"2 x {s['n']}²",
            name,
            f"{s[name]['dt']:.3g}",
            f"{s[name]['ms_step']:.2f}",
            f"{s[name]['ms_contact']:.2f}",
            f"{100 * s[name]['share']:.0f}%",
            s[name]["pairs"],
        ]
        for s in shares
        for name in ("implicit Euler", "symplectic Euler")
        if name in s
    ]
    if rows:
        page.table(
            "Share of the step",
            ["sheets", "method", "dt [s]", "ms/step", "self-contact ms/step", "share", "proximity pairs"],
            rows,
        )
    base = summary(newton["taichi_anim"])["median_ms"] if newton else None
    rows = [
        [
            k,
            f"{s['median_ms']:.0f}",
            f"{s['cpu_ms']:.0f}",
            f"{r['first_frame_s']:.1f}",
            s["max_crossings"],
            s["frames_with_crossings"],
            f"{s['median_ms'] / base:.2f}",
        ]
        for k, r in newton.items()
        for s in (summary(r),)
    ]
    if rows:
        page.table(
            "Stacked sheets against Newton's VBD (same run)",
            [
                "solver",
                "median ms/frame",
                "CPU ms/frame",
                "first frame (compile) s",
                "max crossing pairs",
                "frames with crossings",
                "time / taichi_anim",
            ],
            rows,
        )
    page.write({"share": shares, "newton": newton})


if __name__ == "__main__":
    main()
