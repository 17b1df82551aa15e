"""Liquid against SPlisHSPlasH: its DamBreakModel scene (6,859 particles, DFSPH, 0.05 % density
tolerance) in SPlisHSPlasH (pysplishsplash, in a child process) and the same particle set in taichi_anim
(the first step's positions and velocities SPlisHSPlasH reports), for the same simulated time, by both
of its solvers (DFSPH and position-based fluids, to the same density tolerance).

Reports per engine: median ms per step (wall, after the first steps), CPU-ms per step, particle-steps per
second, pressure iterations per step (density and divergence solves), and the mean and largest
compression max(rho / rho0 - 1, 0) of the particles every few steps, computed the same way for both.
Differences that stay: SPlisHSPlasH's walls are volume maps (Bender et al. 2019) and its viscosity
is the standard SPH one (0.01); taichi_anim's walls are boundary particles (Akinci 2012) and its
viscosity XSPH (0.01). Both use the cubic spline with support 4 radii, a 0.4 CFL factor capped at 5 ms."""

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import taichi as ti
from harness import Page, compile_times, cpu_seconds, init, log, parse_args

import taichi_anim as ta

GL = "/usr/lib/x86_64-linux-gnu/libGLdispatch.so.0"
PEER = Path(__file__).parent / "peers" / "splishsplash_dam_break.py"
SAMPLE_EVERY = 10  # steps between density samples
SKIP = 5  # first steps left out of the medians (SPlisHSPlasH builds its maps, Taichi compiles)
# Our frames: the solver splits each into equal CFL substeps (at most 5 ms), so a frame much longer than
# a step loses little to the rounding: 5 ms frames took 815 steps for 2 s, 1/60 s frames fewer.
FRAME_DT = 1.0 / 60.0


def run_peer(seconds: float, threads: int) -> dict:
    """SPlisHSPlasH's record (peers/splishsplash_dam_break.py)."""
    out = Path(tempfile.mkdtemp(prefix="splishsplash_")) / "peer.json"
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    if Path(GL).exists():
        env["LD_PRELOAD"] = GL
    cmd = [sys.executable, str(PEER), str(out), str(seconds), str(SAMPLE_EVERY)]
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return json.loads(out.read_text())


def peer_figures(rec: dict) -> dict:
    steps = rec["steps"]
    timed = [k for k in range(SKIP, len(steps)) if len(steps[k]) == 6]  # a sampling step is not timed
    wall = [steps[k][0] - steps[k - 1][0] for k in timed]
    cpu = [steps[k][1] - steps[k - 1][1] for k in timed]
    samples = np.array(rec["samples"])
    return dict(
        particles=len(rec["first"]["x"]), steps=len(steps), simulated=steps[-1][2],
        wall=statistics.median(wall), cpu=statistics.median(cpu),
        density_iterations=float(np.mean([s[4] for s in steps])),
        divergence_iterations=float(np.mean([s[5] for s in steps])),
        mean_error=float(samples[:, 1].mean()), max_error=float(samples[:, 2].max()),
    )  # fmt: skip


def build(first: dict, method: str = "dfsph"):
    """Our scene: SPlisHSPlasH's tank (the unit box scaled 4 x 3 x 1.5 with its floor at 0) and particles,
    made incompressible by `method` ("dfsph" or "pbf")."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((-2.0, 0.0, -0.75), (2.0, 3.0, 0.75), restitution=0.0)
    b.add_fluid(spacing=2.0 * first["radius"], density=first["density0"], tolerance=5e-4, method=method,
                divergence_tolerance=1e-3, viscosity=0.01, cfl=0.4, max_step=0.005)  # fmt: skip
    b.add_fluid_particles(np.array(first["x"]), np.array(first["v"]))
    model = b.finalize()
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    return model, state, stepper, next(s for s in stepper.solvers if s.name == "fluid")


def frame(stepper, state) -> tuple[float, float]:
    """Wall and CPU seconds of one frame of FRAME_DT (the solver's CFL substeps)."""
    ti.sync()
    w0, c0 = time.perf_counter(), cpu_seconds()
    stepper.advance(state, FRAME_DT, 1)
    ti.sync()
    return time.perf_counter() - w0, cpu_seconds() - c0


def run_ours(first: dict, seconds: float, method: str = "dfsph") -> dict:
    init("f32")
    model, state, stepper, fluid = build(first, method)
    walls, cpus, samples, steps, density_it, divergence_it = [], [], [], 0, 0, 0
    while state.time < seconds - 1e-9:
        wall, cpu = frame(stepper, state)
        stats = fluid.frame_stats()
        walls.append(wall / stats["steps"])
        cpus.append(cpu / stats["steps"])
        steps += stats["steps"]
        density_it += stats["density_iterations"]
        divergence_it += stats["divergence_iterations"]
        if len(walls) % SAMPLE_EVERY == 0:
            rho = state.fluid_densities() / first["density0"]
            samples.append([float(np.maximum(rho - 1.0, 0.0).mean()), float(rho.max() - 1.0)])
    samples = np.array(samples)
    return dict(
        particles=model.fluid_count, steps=steps, simulated=state.time,
        wall=statistics.median(walls[SKIP:]), cpu=statistics.median(cpus[SKIP:]),
        density_iterations=density_it / steps, divergence_iterations=divergence_it / steps,
        mean_error=float(samples[:, 0].mean()), max_error=float(samples[:, 1].max()),
        unconverged=fluid.stats()["unconverged_steps"],
    )  # fmt: skip


def compile_figures(first: dict) -> dict:
    """Cold and warm compile (harness.compile_times): the first 5 ms frame against a steady one."""

    def first_and_steady():
        model, state, stepper, fluid = build(first)
        times = [frame(stepper, state)[0] for _ in range(4)]
        return times[0], statistics.median(times[1:])

    return compile_times(first_and_steady, precision="f32")


def main() -> None:
    args = parse_args(__doc__, extra=lambda p: p.add_argument("--seconds", type=float, default=2.0))
    seconds = 0.3 if args.quick else args.seconds
    threads = os.cpu_count() or 1
    log(f"SPlisHSPlasH, {seconds} s of DamBreakModel on {threads} threads")
    rec = run_peer(seconds, threads)
    theirs = peer_figures(rec)
    log(f"  {theirs}")
    log("taichi_anim, the same particles")
    ours = run_ours(rec["first"], seconds)
    log(f"  {ours}")
    log("taichi_anim, position-based fluids, the same particles")
    pbf = run_ours(rec["first"], seconds, "pbf")
    log(f"  {pbf}")
    comp = compile_figures(rec["first"])
    engines = (
        ("SPlisHSPlasH 2.19 (DFSPH, volume maps)", theirs),
        ("taichi_anim (DFSPH, boundary particles)", ours),
        ("taichi_anim (PBF, boundary particles)", pbf),
    )
    rows = [
        [name, r["particles"], r["steps"], f"{r['wall'] * 1e3:.2f}", f"{r['cpu'] * 1e3:.2f}",
         f"{r['particles'] / r['wall']:.3g}", f"{r['density_iterations']:.2f}",
         f"{r['divergence_iterations']:.2f}", f"{r['mean_error'] * 100:.4f} %",
         f"{r['max_error'] * 100:.2f} %"]
        for name, r in engines
    ]  # fmt: skip
    per_step = theirs["wall"] / ours["wall"] * ours["particles"] / theirs["particles"]
    # Per simulated second: the engines choose different step sizes under the same CFL factor.
    per_second = (theirs["wall"] * theirs["steps"]) / (ours["wall"] * ours["steps"])
    pbf_second = (theirs["wall"] * theirs["steps"]) / (pbf["wall"] * pbf["steps"])
    page = Page(
        "fluid_dam_break",
        "Liquid: SPlisHSPlasH's dam break in both engines",
        args,
        {"scene": "SPlisHSPlasH DamBreakModel.json (particle radius 0.025 m, tank 4 x 3 x 1.5 m)",
         "simulated": f"{seconds} s", "threads": threads, "precision (ours)": "f32",
         "tolerances": "density 0.05 %, divergence 0.1 % (both)",
         "density error": f"mean and max of max(rho / rho0 - 1, 0) every {SAMPLE_EVERY} steps (ours: frames)",
         "our frames": f"{FRAME_DT:.4g} s, split by the CFL condition (SPlisHSPlasH: a step at a time)",
         "medians": f"per step, after the first {SKIP} steps (a step that sampled densities is not timed)"},
    )  # fmt: skip
    page.table(
        "Per step",
        ["engine", "particles", "steps", "ms/step", "CPU-ms/step", "particle-steps/s", "density iterations",
         "divergence iterations", "mean compression", "max compression"],
        rows,
        f"Particle-steps per second, ours / SPlisHSPlasH: {per_step:.2f}x; simulated seconds per wall second "
        f"(median step x steps): {per_second:.2f}x (PBF: {pbf_second:.2f}x). "
        f"Our compile: cold {comp['cold']['compile']:.2f} s, "
        f"warm {comp['warm']['compile']:.2f} s (first frame minus a steady one, fresh cache folder).",
    )  # fmt: skip
    page.write({"splishsplash": theirs, "taichi_anim": ours, "taichi_anim_pbf": pbf, "compile": comp})


if __name__ == "__main__":
    main()
