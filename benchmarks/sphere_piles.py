"""Hard-sphere piles: accuracy (the largest overlap left in a settled pile) against cost (wall time per
simulated second) for step sizes and Jacobi sweeps per step — where the sphere solver holds a pile and
where it does not.

Scene: 40 x 40 x 7 = 11,200 spheres of radius r = 1 cm, mass 1 g, on a jittered lattice (spacing 2.2 r,
+-0.1 r, seed 0) 2 r above the floor of a box 0.9 m wide, random velocities N(0, 0.3 m/s), gravity 9.81,
walls and spheres restitution 0.5, friction 0.3, rest_speed 0.05 m/s, relaxation 2 (the engine's
defaults otherwise), symplectic Euler, float32, 2 threads. Each configuration simulates 1 s; the error is
the largest overlap r_i + r_j - |x_i - x_j| over all pairs at the end, over r (`overlap_stats`), and the
kinetic energy left shows whether the pile came to rest. Wall time excludes the first step (JIT).

    .venv/bin/python benchmarks/sphere_piles.py           # writes benchmarks/results/sphere_piles.*
    .venv/bin/python benchmarks/sphere_piles.py --quick   # 0.25 s per configuration, benchmarks/out/
"""

import json
import time

import numpy as np
import taichi as ti
from common import (
    OtherLoad,
    clock,
    command_line,
    engine_fingerprint,
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

R, MASS = 0.01, 1e-3
CONFIGS = [(600, 1), (600, 4), (600, 16), (1200, 1), (1200, 2), (2400, 1), (2400, 2), (4800, 1)]


def pile():
    g = np.stack(np.meshgrid(np.arange(40), np.arange(7), np.arange(40), indexing="ij"), -1).reshape(-1, 3)
    half = 40 * 1.1 * R + R
    rng = np.random.default_rng(0)
    x = g * 2.2 * R + np.array([-half + 2 * R, 2 * R, -half + 2 * R]) + rng.uniform(-0.1, 0.1, g.shape) * R
    return x, rng.normal(0.0, 0.3, g.shape), ((-half, 0.0, -half), (half, 1.0, half))


def run(rate: int, iterations: int, seconds: float) -> dict:
    init("f32")
    x, v, box = pile()
    b = ta.Builder()
    b.add_force_gravity()
    b.add_particles(x, v, mass=MASS, radius=R)
    b.add_collider_box(*box, restitution=0.5, friction=0.3)
    b.add_sphere_contacts(restitution=0.5, friction=0.3, iterations=iterations)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator("symplectic_euler", check_every=100)
    dt = 1.0 / rate
    integ.step(model, state, dt)  # JIT compile
    steps = int(round(seconds * rate)) - 1
    t0 = clock()
    for _ in range(steps):
        integ.step(model, state, dt)
    wall = clock() - t0
    spheres = integ.stepper_for(model).contacts
    overlap, contacts = spheres.overlap_stats(model, state)
    vel = state.particle_v.to_numpy()
    return {
        "rate_hz": rate,
        "iterations": iterations,
        "sweeps_per_simulated_s": rate * (iterations + 1),
        "wall_per_simulated_s": wall / (steps * dt),
        "ms_per_step": 1e3 * wall / steps,
        "max_overlap_over_r": overlap / R,
        "contacts": contacts,
        "kinetic_energy": float(0.5 * MASS * (vel.astype(np.float64) ** 2).sum()),
        "spheres": len(x),
        "neighbor_search": spheres.neighbors.describe(),
    }


def main() -> None:
    args = parse_args(__doc__.split("\n")[0])
    md_path, out_dir = output_paths(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    seconds = 0.25 if args.quick else 1.0
    load_start, other, engine = load_average(), OtherLoad(), engine_fingerprint()
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    rows = []
    for rate, iterations in CONFIGS:
        r = run(rate, iterations, seconds)
        log(
            f"dt 1/{rate}, {iterations} sweeps: overlap {r['max_overlap_over_r']:.4f} r, "
            f"{r['ms_per_step']:.2f} ms"
        )
        rows.append(r)
    table = md_table(
        [
            "dt",
            "sweeps/step",
            "ms/step",
            "wall s per simulated s",
            "largest overlap / r",
            "kinetic energy [J]",
        ],
        [
            [
                f"1/{r['rate_hz']}",
                r["iterations"],
                f"{r['ms_per_step']:.2f}",
                f"{r['wall_per_simulated_s']:.1f}",
                f"**{r['max_overlap_over_r']:.4f}**",
                f"{r['kinetic_energy']:.2e}",
            ]
            for r in rows
        ],
    )
    machine = machine_table(
        machine_info(), load_start=load_start, load_end=load_average(), date=date, engine=engine, other=other
    )
    text = "\n\n".join(
        [
            "# Hard-sphere piles: largest overlap against cost",
            f"Regenerate: `{command_line(args, 'sphere_piles.py')}`.",
            __doc__.split("\n\n")[1].replace("\n", " "),
            f"Simulated time per configuration: {seconds} s; {rows[0]['spheres']} spheres; neighbour search "
            f"{rows[0]['neighbor_search']}.",
            machine,
            table,
        ]
    )
    md = out_dir / "sphere_piles.md" if md_path.name == "RESULTS.md" else md_path
    md.write_text(text + "\n")
    (out_dir / "sphere_piles.json").write_text(json.dumps(rows, indent=1))
    log(f"wrote {md}")
    ti.reset()


if __name__ == "__main__":
    main()
