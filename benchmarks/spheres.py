"""Hard spheres: particle-steps per second of taichi_anim's sphere contacts at 10^4, 10^5 and 10^6 spheres,
against the same algorithm on NVIDIA Warp's HashGrid (warp-lang on the CPU, optional) in the same run, and
against the engine's brute-force neighbour search at 10^4.

Scene (every N): N equal spheres of radius r = 0.01 m and mass 0.01 kg on a cubic lattice of spacing
2.2 r (nx = nz = ceil(N^(1/3)) columns, filled layer by layer from the floor; each centre jittered by up
to +-0.05 r per axis, seed 0, so no pair overlaps at t = 0), at rest, in a container box
[0, nx s] x [0, 2 ny s] x [0, nz s] (s the spacing, ny the number of layers: the lattice fills the lower
half), gravity (0, -9.81, 0) m/s^2. The engine then runs 150 steps (0.25 s; 60 with --quick) so the
lattice collapses into a pile in contact; the timed runs of every implementation start from that state.
Walls: restitution 0.5, friction 0.3. Sphere contacts (`Builder.add_sphere_contacts`): restitution 0.5,
friction 0.3, 4 Jacobi iterations with the engine's default over-relaxation, rest_speed 0.05 m/s, not
continuous (one substep); the neighbour search the engine picks ("auto": a bounded grid over the box at
these sizes), and "brute" at 10^4. Symplectic Euler, dt = 1/600 s, `check_every` = 10, float32.

Peer: benchmarks/peers/warp_spheres.py, the engine's step ported to Warp kernels (same formulas, same
order of operations, same averaging and walls; `warp.HashGrid` with cells of 2 r over the box), from the
same initial state, for the same steps. Warp runs CPU kernels on one thread; Taichi uses its default
thread count (both cores here).

Measured per N and implementation: the first step (taichi_anim: JIT compile included, offline cache
off; Warp's kernels are compiled once beforehand into an empty kernel cache and timed), `WARMUP` - 1 more
steps, then M steps timed with `ti.sync()` (Warp: `wp.synchronize_device`)
before each clock read: particle-steps/s = N M / wall time; the process's CPU time over the same window
gives the cores it kept busy. Then K more steps timed in parts: for taichi_anim the neighbour rebuild
(`ContactSpheres.neighbors.build`, wrapped with a synchronised clock) and the whole contact solve
(`ContactSpheres.solve`), the rest being the integrator's kernel; for Warp the prediction, the HashGrid
build and the sweeps. At the end of the run both report the kinetic energy, the mean height and the
largest overlap between spheres (statistics of the same scene: summation order differs, so the piles
agree statistically, not bit for bit).

Equivalence check (before timing): two spheres head-on, two spheres colliding off-centre with friction,
and a pile of 1000 spheres for 100 steps, stepped by both implementations; per-step positions and
velocities compared (see the results for what agrees to float tolerance and what only statistically).

    .venv/bin/python benchmarks/spheres.py           # full run, writes benchmarks/results/spheres.*
    .venv/bin/python benchmarks/spheres.py --quick   # smoke run (10^4 and 10^5, few steps), benchmarks/out/
"""

import json
import math
import os
import time

import numpy as np
from common import (
    OtherLoad,
    clock,
    command_line,
    engine_fingerprint,
    fmt_e,
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

RADIUS = 0.01  # [m]
MASS = 0.01  # [kg]
SPACING = 2.2 * RADIUS  # [m] lattice spacing
JITTER = 0.05 * RADIUS  # [m] per axis, uniform
GRAVITY = (0.0, -9.81, 0.0)
DT = 1.0 / 600.0  # [s]
RESTITUTION = 0.5
FRICTION = 0.3
WALL_RESTITUTION = 0.5
WALL_FRICTION = 0.3
ITERATIONS = 4
REST_SPEED = 0.05  # [m/s]
CHECK_EVERY = 10
WARMUP = 5  # steps before the timed window (the first holds the compile)
SETTLE_STEPS = 150  # engine steps from the lattice to the state both implementations start from (0.25 s)
SEED = 0


# ---------------------------------------------------------------------------------------------------------
# scene


def lattice(n: int):
    """(x (n,3), lo, hi): the jittered lattice and its container box (module docstring)."""
    nx = math.ceil(n ** (1.0 / 3.0) - 1e-9)
    ny = math.ceil(n / (nx * nx))
    iy, iz, ix = np.unravel_index(np.arange(n), (ny, nx, nx))
    rng = np.random.default_rng(SEED)
    x = (np.stack([ix, iy, iz], axis=1) + 0.5) * SPACING + rng.uniform(-JITTER, JITTER, (n, 3))
    lo = (0.0, 0.0, 0.0)
    hi = (nx * SPACING, 2 * ny * SPACING, nx * SPACING)
    return x, lo, hi


def build_engine(x, lo, hi, *, method: str = "auto", gravity=GRAVITY, v=None, restitution=RESTITUTION,
                 friction=FRICTION):  # fmt: skip
    b = ta.Builder()
    b.add_particles(x, v, MASS, radius=RADIUS)
    if gravity is not None:
        b.add_force_gravity(gravity)
    b.add_collider_box(lo, hi, restitution=WALL_RESTITUTION, friction=WALL_FRICTION)
    b.add_sphere_contacts(
        restitution=restitution,
        friction=friction,
        iterations=ITERATIONS,
        rest_speed=REST_SPEED,
        neighbor_search=method,
    )
    model = b.finalize(seed=SEED)
    integ = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY)
    return model, model.state(), integ


def build_warp(x, lo, hi, *, relaxation, gravity=GRAVITY, v=None, restitution=RESTITUTION, friction=FRICTION):
    """The Warp port with the engine's settings; relaxation: the engine's (`ContactSpheres.relaxation`,
    its default unless the scene sets it)."""
    from peers.warp_spheres import WarpSpheres

    return WarpSpheres(
        x,
        np.zeros_like(x) if v is None else v,
        radius=RADIUS,
        mass=MASS,
        gravity=(0.0, 0.0, 0.0) if gravity is None else gravity,
        lo=lo,
        hi=hi,
        restitution=restitution,
        friction=friction,
        wall_restitution=WALL_RESTITUTION,
        wall_friction=WALL_FRICTION,
        iterations=ITERATIONS,
        relaxation=relaxation,
        rest_speed=REST_SPEED,
    )


def stats(x: np.ndarray, v: np.ndarray, overlap: float) -> dict:
    return {
        "kinetic_energy": float(0.5 * MASS * (v.astype(np.float64) ** 2).sum()),
        "mean_height": float(x[:, 1].astype(np.float64).mean()),
        "max_overlap": overlap,
        "max_overlap_over_r": overlap / RADIUS,
        "finite": bool(np.isfinite(x).all() and np.isfinite(v).all()),
    }


def engine_overlap(model, state, integ) -> float:
    return float(integ.stepper_for(model).contacts.overlap_stats(model, state)[0])


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system


# ---------------------------------------------------------------------------------------------------------
# timing


def settle(n: int, steps: int) -> dict:
    """The timed runs start from the lattice after `steps` engine steps (auto neighbour search): the pile
    has collapsed into contact by then, so every size is timed in the same phase (a fresh lattice has no
    contacts at all). Both implementations start from this state (float32 arrays)."""
    init("f32")
    x, lo, hi = lattice(n)
    model, state, integ = build_engine(x, lo, hi)
    t0 = clock()
    for _ in range(steps):
        integ.step(model, state, DT)
    wall = clock() - t0
    state.check_finite()
    xs, vs = state.particle_x.to_numpy(), state.particle_v.to_numpy()
    return {"x": xs, "v": vs, "lo": lo, "hi": hi, "steps": steps, "wall": wall,
            "relaxation": float(integ.stepper_for(model).contacts.relaxation),
            **stats(xs, vs, engine_overlap(model, state, integ))}  # fmt: skip


def run_engine(start: dict, steps: int, split_steps: int, method: str = "auto") -> dict:
    init("f32", offline_cache=False)  # the first step's compile is a real compile
    from taichi.lang import impl

    threads = impl.current_cfg().cpu_max_num_threads
    n = len(start["x"])
    t_build0 = time.perf_counter()
    model, state, integ = build_engine(start["x"], start["lo"], start["hi"], method=method, v=start["v"])
    t_model = time.perf_counter() - t_build0
    contacts = integ.stepper_for(model).contacts
    a = clock()
    integ.step(model, state, DT)
    first = clock() - a
    a = clock()
    for _ in range(WARMUP - 1):
        integ.step(model, state, DT)
    warm = (clock() - a) / max(WARMUP - 1, 1)
    c0 = cpu_seconds()
    a = clock()
    for _ in range(steps):
        integ.step(model, state, DT)
    wall = clock() - a
    cores = (cpu_seconds() - c0) / wall
    # The same steps again in parts: wrap the rebuild and the solve with synchronised clocks.
    parts = {"build": 0.0, "solve": 0.0}
    build, solve = contacts.neighbors.build, contacts.solve

    def timed_build(*args, **kw):
        t0 = clock()
        build(*args, **kw)
        parts["build"] += clock() - t0

    def timed_solve(*args, **kw):
        t0 = clock()
        solve(*args, **kw)
        parts["solve"] += clock() - t0

    contacts.neighbors.build, contacts.solve = timed_build, timed_solve
    a = clock()
    for _ in range(split_steps):
        integ.step(model, state, DT)
    split_wall = clock() - a
    del contacts.neighbors.build, contacts.solve  # back to the class's methods
    state.check_finite()
    st = stats(state.particle_x.to_numpy(), state.particle_v.to_numpy(), engine_overlap(model, state, integ))
    step = split_wall / split_steps
    return {
        "impl": f"taichi_anim ({method}, {threads} threads)",
        "n": n,
        "threads": threads,
        "neighbor_search": contacts.neighbors.describe(),
        "contacts": contacts.settings(),
        "model_build_time": t_model,
        "first_step": first,
        "warm_step": warm,
        "compile": max(first - warm, 0.0),
        "steps": steps,
        "wall": wall,
        "step_time": wall / steps,
        "rate": n * steps / wall,
        "cores_busy": cores,
        "split_steps": split_steps,
        "split": {
            "step": step,
            "build": parts["build"] / split_steps,
            "solve_without_build": (parts["solve"] - parts["build"]) / split_steps,
            "integrator_and_rest": (split_wall - parts["solve"]) / split_steps,
        },
        "build_fraction": parts["build"] / split_wall,
        "simulated_steps": 1 + (WARMUP - 1) + steps + split_steps,
        **st,
    }


def warp_compile() -> dict:
    """Compile the peer's kernels into an empty kernel cache (so the time is a real compile, whatever
    ~/.cache/warp holds); call before any other Warp use. Returns the folder and the seconds taken."""
    import tempfile

    import warp as wp

    folder = tempfile.mkdtemp(prefix="taichi_anim_bench_warp_cache_")
    wp.config.kernel_cache_dir = folder
    wp.config.quiet = True
    wp.init()
    import peers.warp_spheres as module

    t0 = time.perf_counter()
    wp.load_module(module, device="cpu")
    return {"folder": folder, "compile": time.perf_counter() - t0}


def run_warp(start: dict, steps: int, split_steps: int, compile_time: float) -> dict:
    import warp as wp

    n = len(start["x"])
    t0 = time.perf_counter()
    sim = build_warp(start["x"], start["lo"], start["hi"], v=start["v"], relaxation=start["relaxation"])
    t_model = time.perf_counter() - t0
    sim.sync()
    a = time.perf_counter()
    sim.step(DT)
    sim.sync()
    first = time.perf_counter() - a
    a = time.perf_counter()
    for _ in range(WARMUP - 1):
        sim.step(DT)
    sim.sync()
    warm = (time.perf_counter() - a) / max(WARMUP - 1, 1)
    c0 = cpu_seconds()
    a = time.perf_counter()
    for _ in range(steps):
        sim.step(DT)
    sim.sync()
    wall = time.perf_counter() - a
    cores = (cpu_seconds() - c0) / wall
    parts = {"predict": 0.0, "build": 0.0, "solve": 0.0}
    for _ in range(split_steps):
        for name, fn in (("predict", sim.predict), ("build", lambda _h: sim.build()), ("solve", sim.solve)):
            t = time.perf_counter()
            fn(DT)
            sim.sync()
            parts[name] += time.perf_counter() - t
    split_wall = sum(parts.values())
    st = stats(sim.positions(), sim.velocities(), sim.max_overlap())
    return {
        "impl": "warp HashGrid (CPU)",
        "n": n,
        "warp": wp.config.version,
        "grid": sim.settings(),
        "model_build_time": t_model,
        "first_step": first,
        "warm_step": warm,
        "compile": compile_time,
        "steps": steps,
        "wall": wall,
        "step_time": wall / steps,
        "rate": n * steps / wall,
        "cores_busy": cores,
        "split_steps": split_steps,
        "split": {
            "step": split_wall / split_steps,
            "build": parts["build"] / split_steps,
            "solve_without_build": parts["solve"] / split_steps,
            "integrator_and_rest": parts["predict"] / split_steps,
        },
        "build_fraction": parts["build"] / split_wall,
        "simulated_steps": 1 + (WARMUP - 1) + steps + split_steps,
        **st,
    }


# ---------------------------------------------------------------------------------------------------------
# equivalence


def lockstep(x, v, lo, hi, steps: int, *, gravity, friction, method="auto", every: int = 1):
    """Step the engine and the Warp port side by side from (x, v); per-step differences and statistics."""
    init("f32")
    model, state, integ = build_engine(x, lo, hi, method=method, gravity=gravity, v=v, friction=friction)
    sim = build_warp(
        x,
        lo,
        hi,
        gravity=gravity,
        v=v,
        friction=friction,
        relaxation=integ.stepper_for(model).contacts.relaxation,
    )
    rows = []
    for k in range(1, steps + 1):
        integ.step(model, state, DT)
        sim.step(DT)
        if k % every and k != steps:
            continue
        xe, ve = state.particle_x.to_numpy(), state.particle_v.to_numpy()
        xw, vw = sim.positions(), sim.velocities()
        se = stats(xe, ve, engine_overlap(model, state, integ))
        sw = stats(xw, vw, sim.max_overlap())
        rows.append(
            {
                "step": k,
                "max_dx": float(np.abs(xe - xw).max()),
                "max_dv": float(np.abs(ve - vw).max()),
                "engine": se,
                "warp": sw,
            }
        )
    return {
        "n": len(x),
        "steps": steps,
        "neighbor_search": integ.stepper_for(model).contacts.neighbors.describe(),
        "rows": rows,
    }


def equivalence(pile_n: int, pile_steps: int) -> dict:
    lo, hi = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
    c = 0.5
    # (a) head-on at 1 m/s each, no gravity: one contact, restitution only.
    head_on = lockstep(
        np.array([[c - 0.015, c, c], [c + 0.015, c, c]]),
        np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]),
        lo,
        hi,
        20,
        gravity=None,
        friction=0.0,
    )
    # (b) off-centre with friction and gravity: normal and tangential parts, a wall later.
    oblique = lockstep(
        np.array([[c - 0.015, c + 0.006, c], [c + 0.015, c, c + 0.002]]),
        np.array([[1.0, 0.0, 0.2], [-1.0, 0.3, 0.0]]),
        lo,
        hi,
        40,
        gravity=GRAVITY,
        friction=FRICTION,
    )
    x, plo, phi = lattice(pile_n)
    pile = lockstep(x, None, plo, phi, pile_steps, gravity=GRAVITY, friction=FRICTION, method="grid")
    return {"head_on": head_on, "oblique": oblique, "pile": pile}


# ---------------------------------------------------------------------------------------------------------
# output


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    _, fig_dir = output_paths(args)
    fig_dir.mkdir(parents=True, exist_ok=True)
    if args.quick:
        plan = [(10**4, 20, 10), (10**5, 5, 3)]
        brute = [(10**4, 3, 2)]
        settle_steps = 60
        pile_n, pile_steps = 512, 30
    else:
        plan = [(10**4, 200, 50), (10**5, 40, 10), (10**6, 10, 3)]
        brute = [(10**4, 5, 3)]
        settle_steps = SETTLE_STEPS
        pile_n, pile_steps = 1000, 100
    try:
        wc = warp_compile()
        have_warp = True
        log(f"Warp kernels compiled in {fmt_s(wc['compile'])} (empty kernel cache)")
    except ImportError:
        wc = {"folder": None, "compile": float("nan")}
        have_warp = False
        log("warp-lang is not installed: the Warp peer is skipped (pip install -e '.[bench]')")
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()

    eq = equivalence(pile_n, pile_steps) if have_warp else None
    if eq:
        for key in ("head_on", "oblique"):
            last = eq[key]["rows"][-1]
            worst = max(r["max_dx"] for r in eq[key]["rows"])
            log(f"equivalence {key}: max |dx| over the steps {worst:.2e} m, last |dv| {last['max_dv']:.2e}")

    rows = []
    starts = {}
    for n, steps, split in plan:
        starts[n] = start = settle(n, settle_steps)
        log(
            f"settled n={n:.0e}: {settle_steps} steps in {fmt_s(start['wall'])}, max overlap "
            f"{start['max_overlap_over_r']:.3f} r, kinetic energy {start['kinetic_energy']:.3g} J"
        )
        r_e = run_engine(start, steps, split)
        log(
            f"taichi_anim n={n:.0e} {r_e['neighbor_search']}: {r_e['rate']:.3g} particle-steps/s "
            f"({fmt_s(r_e['step_time'])}/step, {r_e['cores_busy']:.2f} cores), build fraction "
            f"{r_e['build_fraction']:.2f}, compile {fmt_s(r_e['compile'])}"
        )
        r_w = None
        if have_warp:
            r_w = run_warp(start, steps, split, wc["compile"])
            log(
                f"warp        n={n:.0e}: {r_w['rate']:.3g} particle-steps/s ({fmt_s(r_w['step_time'])}/step, "
                f"{r_w['cores_busy']:.2f} cores), build fraction {r_w['build_fraction']:.2f}"
            )
        rows.append(
            {
                "n": n,
                "engine": r_e,
                "warp": r_w,
                "settle": {k: v for k, v in start.items() if k not in ("x", "v")},
            }
        )
    brute_rows = []
    for n, steps, split in brute:
        r_b = run_engine(starts.get(n) or settle(n, settle_steps), steps, split, method="brute")
        log(
            f"taichi_anim brute n={n:.0e}: {r_b['rate']:.3g} particle-steps/s "
            f"({fmt_s(r_b['step_time'])}/step)"
        )
        brute_rows.append(r_b)
    total = time.perf_counter() - started
    load_end = load_average()
    if wc["folder"]:
        import shutil

        shutil.rmtree(wc["folder"], ignore_errors=True)

    write_outputs(args, fig_dir, rows, brute_rows, eq, total, load_start, load_end, date, engine, other)


def _ratio(a, b) -> str:
    return f"{a / b:.2f}x" if a and b else "–"


def write_outputs(args, fig_dir, rows, brute_rows, eq, total, load_start, load_end, date, engine, other):
    import warp as wp

    main_rows = []
    for r in rows:
        e, w = r["engine"], r["warp"]
        for res in [e] + ([w] if w else []):
            main_rows.append(
                [
                    f"{r['n']:.0e}",
                    res["impl"],
                    res.get("neighbor_search", f"HashGrid {res.get('grid', {}).get('hash_grid_dims')}"),
                    res["steps"],
                    fmt_s(res["step_time"]),
                    f"**{fmt_e(res['rate'], 3)}**",
                    f"{res['cores_busy']:.2f}",
                    f"**{_ratio(res['rate'], w['rate'])}**" if w else "–",
                    fmt_s(res["first_step"]),
                    fmt_s(res["compile"]),
                ]
            )
        for b in brute_rows:
            if b["n"] == r["n"]:
                main_rows.append(
                    [
                        f"{b['n']:.0e}",
                        b["impl"],
                        b["neighbor_search"],
                        b["steps"],
                        fmt_s(b["step_time"]),
                        f"**{fmt_e(b['rate'], 3)}**",
                        f"{b['cores_busy']:.2f}",
                        f"**{_ratio(b['rate'], w['rate'])}**" if w else "–",
                        fmt_s(b["first_step"]),
                        fmt_s(b["compile"]),
                    ]
                )
    split_rows = []
    for r in rows:
        for res in (
            [r["engine"]] + ([r["warp"]] if r["warp"] else []) + [b for b in brute_rows if b["n"] == r["n"]]
        ):
            s = res["split"]
            split_rows.append(
                [
                    f"{r['n']:.0e}",
                    res["impl"],
                    res["split_steps"],
                    fmt_s(s["step"]),
                    fmt_s(s["integrator_and_rest"]),
                    fmt_s(s["build"]),
                    fmt_s(s["solve_without_build"]),
                    f"**{res['build_fraction']:.2f}**",
                ]
            )
    stat_rows = []
    for r in rows:
        for res in [r["engine"]] + ([r["warp"]] if r["warp"] else []):
            stat_rows.append(
                [
                    f"{r['n']:.0e}",
                    res["impl"],
                    res["simulated_steps"],
                    f"{res['kinetic_energy']:.4g}",
                    f"{res['mean_height']:.5f}",
                    f"{res['max_overlap_over_r']:.3f}",
                    "yes" if res["finite"] else "**NO**",
                ]
            )
    goals = []
    for r in rows:
        if r["n"] in (10**5, 10**6) and r["warp"]:
            ratio = r["engine"]["rate"] / r["warp"]["rate"]
            goals.append(
                f"N = {r['n']:.0e}: taichi_anim / Warp = {ratio:.2f}x (goal >= 4x: "
                f"{'met' if ratio >= 4 else 'MISSED'})"
            )
        frac = r["engine"]["build_fraction"]
        goals.append(
            f"N = {r['n']:.0e}: neighbour rebuild = {frac:.2f} of the engine's step (goal < 1/3: "
            f"{'met' if frac < 1 / 3 else 'MISSED'})"
        )
    eq_text = equivalence_text(eq) if eq else "(skipped: warp-lang not installed)"
    e0 = rows[0]["engine"]
    text = (
        "# Hard spheres: taichi_anim against Warp's HashGrid\n\n"
        f"Regenerate: `{command_line(args, 'spheres.py')}` (took {total / 60:.1f} min).\n\n"
        "Settings: float32 (`ta.init('cpu', precision='f32')`, Taichi's default thread count), one fresh "
        f"`ta.init` per run. Scene: N spheres of radius {RADIUS} m, mass {MASS} kg, on a cubic lattice of "
        f"spacing {SPACING / RADIUS:g} r jittered by +-{JITTER / RADIUS:g} r per axis (seed {SEED}), at "
        "rest, filling the lower half of a container box [0, nx s] x [0, 2 ny s] x [0, nz s] "
        f"(nx = nz = ceil(N^(1/3))); gravity {GRAVITY} m/s²; walls restitution {WALL_RESTITUTION}, friction "
        f"{WALL_FRICTION}; sphere contacts restitution {RESTITUTION}, friction {FRICTION}, "
        f"{ITERATIONS} Jacobi iterations, rest_speed {REST_SPEED} m/s, one substep; symplectic Euler, "
        f"dt = 1/{round(1 / DT)} s, `check_every` = {CHECK_EVERY}. Every timed run starts from the state "
        f"after {rows[0]['settle']['steps']} engine steps from the lattice (the pile collapsed into contact; "
        "table below). Engine contact settings: "
        f"`{e0['contacts']}`. Warp peer: `benchmarks/peers/warp_spheres.py` (warp-lang {wp.config.version}, "
        "CPU, one thread; HashGrid cells of 2 r with dims covering the box), the same algorithm from the "
        f"same initial state for the same steps. Each run: first step (compile) + {WARMUP - 1} warm-up "
        "steps, then M timed steps (`ti.sync()` / `wp.synchronize_device` before each clock read), then K "
        "steps timed in parts. Cores busy = process CPU time / wall time over the timed window. JIT "
        "compile: taichi_anim, the first step minus a warm step with the offline cache off "
        "(`offline_cache=False`), per run; Warp, `wp.load_module` of the peer into an empty kernel cache, "
        "once per process (its first step then holds no compile).\n\n"
        + machine_table(
            machine_info(), load_start=load_start, load_end=load_end, date=date, engine=engine, other=other
        )
        + "\n\n![spheres](spheres.png)\n\n## Throughput\n\n"
        + md_table(
            [
                "N",
                "implementation",
                "neighbour search",
                "M steps",
                "per step",
                "particle-steps/s",
                "cores busy",
                "/ Warp",
                "first step",
                "JIT compile",
            ],
            main_rows,
        )
        + "\n\n**Goals.** "
        + "; ".join(goals)
        + ".\n\n## Where the step goes\n\n"
        "taichi_anim: the neighbour rebuild (`neighbors.build`) and the whole contact solve "
        "(`ContactSpheres.solve`) timed with synchronised clocks inside `Integrator.step`; the rest is the "
        "integrator kernel (prediction and walls) and bookkeeping. Warp: prediction kernel, "
        "`HashGrid.build`, sweeps.\n\n"
        + md_table(
            [
                "N",
                "implementation",
                "K steps",
                "step",
                "integrator / prediction",
                "neighbour rebuild",
                "contact sweeps",
                "rebuild fraction",
            ],
            split_rows,
        )
        + "\n\n## Same scene: state at the start and at the end of each run\n\n"
        "Start (after the settling steps, taichi_anim auto, offline cache on):\n\n"
        + md_table(
            [
                "N",
                "settling steps",
                "wall time (compile included)",
                "kinetic energy [J]",
                "mean height [m]",
                "max overlap / r",
            ],
            [
                [
                    f"{r['n']:.0e}",
                    r["settle"]["steps"],
                    fmt_s(r["settle"]["wall"]),
                    f"{r['settle']['kinetic_energy']:.4g}",
                    f"{r['settle']['mean_height']:.5f}",
                    f"{r['settle']['max_overlap_over_r']:.3f}",
                ]
                for r in rows
            ],
        )
        + "\n\nEnd:\n\n"
        "Both implementations ran the same number of steps from the same initial state; the piles agree "
        "statistically (float summation order differs, and a pile amplifies rounding differences).\n\n"
        + md_table(
            [
                "N",
                "implementation",
                "steps after the start",
                "kinetic energy [J]",
                "mean height [m]",
                "max overlap / r",
                "finite",
            ],
            stat_rows,
        )
        + "\n\n## Equivalence of the Warp port\n\n"
        + eq_text
        + "\n"
    )
    (fig_dir / "spheres.md").write_text(text)
    (fig_dir / "spheres.json").write_text(
        json.dumps(
            {
                "settings": {
                    "radius": RADIUS,
                    "mass": MASS,
                    "spacing": SPACING,
                    "jitter": JITTER,
                    "gravity": GRAVITY,
                    "dt": DT,
                    "restitution": RESTITUTION,
                    "friction": FRICTION,
                    "wall_restitution": WALL_RESTITUTION,
                    "wall_friction": WALL_FRICTION,
                    "iterations": ITERATIONS,
                    "rest_speed": REST_SPEED,
                    "check_every": CHECK_EVERY,
                    "warmup": WARMUP,
                    "precision": "f32",
                },
                "machine": machine_info(),
                "load": [load_start, load_end],
                "rows": rows,
                "brute": brute_rows,
                "equivalence": eq,
            },
            indent=1,
            default=str,
        )
    )
    plot(rows, brute_rows, eq, fig_dir / "spheres.png")
    log(f"wrote {fig_dir}/spheres.md, .json, .png in {total / 60:.1f} min")


EXACT_TOL = 1e-6  # [m], [m/s]: two-sphere cases must agree to float rounding


def equivalence_text(eq) -> str:
    out = []
    for key, title in (
        ("head_on", "Two spheres head-on, 1 m/s each, no gravity (one contact: restitution only)"),
        ("oblique", "Two spheres off-centre with friction and gravity"),
    ):
        rows = eq[key]["rows"]
        worst_dx = max(r["max_dx"] for r in rows)
        worst_dv = max(r["max_dv"] for r in rows)
        verdict = (
            "agree" if max(worst_dx, worst_dv) <= EXACT_TOL else "**DIFFER: the port no longer matches**"
        )
        out.append(
            f"- {title} ({verdict}), {eq[key]['steps']} steps, engine search "
            f"`{eq[key]['neighbor_search']}`: largest "
            f"|x_taichi - x_warp| over all steps {worst_dx:.2e} m, |v_taichi - v_warp| {worst_dv:.2e} m/s; "
            f"final kinetic energy {rows[-1]['engine']['kinetic_energy']:.6g} J (taichi_anim) and "
            f"{rows[-1]['warp']['kinetic_energy']:.6g} J (Warp)."
        )
    p = eq["pile"]
    picks = sorted({1, 2, 5, 10, 20, 50, p["steps"]} & {r["step"] for r in p["rows"]})
    by_step = {r["step"]: r for r in p["rows"]}
    table = md_table(
        [
            "step",
            "max |dx| [m]",
            "max |dv| [m/s]",
            "KE taichi_anim [J]",
            "KE Warp [J]",
            "max overlap / r, taichi_anim",
            "max overlap / r, Warp",
            "mean height taichi_anim / Warp [m]",
        ],
        [
            [
                s,
                f"{by_step[s]['max_dx']:.2e}",
                f"{by_step[s]['max_dv']:.2e}",
                f"{by_step[s]['engine']['kinetic_energy']:.5g}",
                f"{by_step[s]['warp']['kinetic_energy']:.5g}",
                f"{by_step[s]['engine']['max_overlap_over_r']:.4f}",
                f"{by_step[s]['warp']['max_overlap_over_r']:.4f}",
                f"{by_step[s]['engine']['mean_height']:.6f} / {by_step[s]['warp']['mean_height']:.6f}",
            ]
            for s in picks
        ],
    )
    out.append(
        f"- A pile of {p['n']} spheres (the benchmark's scene), {p['steps']} steps, engine search "
        f"`{p['neighbor_search']}`:\n\n" + table
    )
    return "\n".join(out)


def plot(rows, brute_rows, eq, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    ax = axes[0]
    ns = [r["n"] for r in rows]
    ax.plot(ns, [r["engine"]["rate"] for r in rows], "-o", color="C0", label="taichi_anim (grid, 2 threads)")
    if rows[0]["warp"]:
        ax.plot(
            ns, [r["warp"]["rate"] for r in rows if r["warp"]], "-s", color="C1", label="Warp HashGrid (CPU)"
        )
        ax.plot(
            ns,
            [4 * r["warp"]["rate"] for r in rows if r["warp"]],
            ":",
            color="C1",
            label="4x Warp (goal)",
        )
    if brute_rows:
        ax.plot(
            [b["n"] for b in brute_rows],
            [b["rate"] for b in brute_rows],
            "^",
            color="C3",
            label="taichi_anim, brute force",
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("spheres N")
    ax.set_ylabel("particle-steps per second")
    ax.set_title("throughput", fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)

    ax = axes[1]
    labels, parts = [], {"integrator / prediction": [], "neighbour rebuild": [], "contact sweeps": []}
    for r in rows:
        for res, tag in ((r["engine"], "taichi"), (r["warp"], "warp")):
            if res is None:
                continue
            labels.append(f"{tag}\n{r['n']:.0e}")
            s = res["split"]
            parts["integrator / prediction"].append(s["integrator_and_rest"] / s["step"])
            parts["neighbour rebuild"].append(s["build"] / s["step"])
            parts["contact sweeps"].append(s["solve_without_build"] / s["step"])
    bottom = np.zeros(len(labels))
    for name, vals in parts.items():
        ax.bar(labels, vals, bottom=bottom, label=name)
        bottom += np.asarray(vals)
    ax.axhline(1 / 3, color="grey", lw=1, ls="--", label="1/3 (rebuild goal)")
    ax.set_ylabel("fraction of the step")
    ax.set_title("where the step goes", fontsize=10)
    ax.tick_params(axis="x", labelsize=7)
    ax.legend(fontsize=7)

    ax = axes[2]
    if eq:
        p = eq["pile"]["rows"]
        steps = [r["step"] for r in p]
        ax.plot(steps, [r["engine"]["kinetic_energy"] for r in p], "-", color="C0", label="KE taichi_anim")
        ax.plot(steps, [r["warp"]["kinetic_energy"] for r in p], "--", color="C1", label="KE Warp")
        ax.set_xlabel("step")
        ax.set_ylabel("kinetic energy [J]")
        ax2 = ax.twinx()
        ax2.plot(
            steps, [r["engine"]["max_overlap_over_r"] for r in p], "-", color="C2", label="overlap/r taichi"
        )
        ax2.plot(
            steps, [r["warp"]["max_overlap_over_r"] for r in p], "--", color="C3", label="overlap/r Warp"
        )
        ax2.set_ylabel("max overlap / r")
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, fontsize=7)
        ax.set_title(f"equivalence: pile of {eq['pile']['n']} spheres", fontsize=10)
    fig.suptitle(
        f"Hard spheres, f32, dt = 1/{round(1 / DT)} s, {ITERATIONS} iterations, 2-core CPU", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
