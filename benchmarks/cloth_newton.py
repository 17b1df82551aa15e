"""Honest implicit solves: Baraff & Witkin's linearised backward Euler against Newton iterations (with
and without the residual line search) on a stiff cloth, and how often PCG ends at its iteration cap.

Scene: an n x n, 1 m cloth (0.2 kg/m^2) pinned at two corners, falling from rest under gravity; every
spring family at `scale` x (stretch 1e3, shear 1e2, bend 10 N/m), damped; dt = 1/60 s, 60 steps (1 s).
(1) Per mode and stiffness: ms per step (warm: the first 2 steps, which hold the compile, are not
timed; `ti.sync()` before each clock read), linear (PCG) iterations and Newton iterations per step, the
share of linear solves that ended at the cap, and the energy drift max_n (E_n - E_0) and E_N - E_0 with
E = kinetic + gravity + spring energy (the linearised step gains energy on stiff springs; backward
Euler itself dissipates); f64. The last two modes solve each linear system to tol 1e-7 (cap 2000).
(2) PCG at its cap: the share of default solves (tol 1e-4, 200
iterations) that end at the cap and the largest relative residual, 32^2 cloth, f32, 120 steps, as
counted by the run's Health. (3) The cost of reading a solve's result (the one small device read per
solve that the reports use) against the step time, 64^2 cloth, f32.
Writes `results/cloth_newton.md` (or benchmarks/out/ with --quick).
"""

import time

import common
import numpy as np

import taichi_anim as ta

DT = 1.0 / 60.0
G = np.array([0.0, -9.81, 0.0])
MODES = {
    "linearised (default)": {},
    "Newton, 10 it": {"newton_iterations": 10},
    "Newton, 10 it + line search": {"newton_iterations": 10, "line_search": True},
    "linearised, PCG tol 1e-7 / 2000 it": {"tol": 1e-7, "max_iterations": 2000},
    "Newton + line search, PCG tol 1e-7 / 2000 it": {
        "newton_iterations": 10,
        "line_search": True,
        "tol": 1e-7,
        "max_iterations": 2000,
    },
}


def cloth(n: int, scale: float):
    material = ta.ClothMaterial(
        stretch_stiffness=1e3 * scale,
        stretch_damping=0.05,
        shear_stiffness=1e2 * scale,
        shear_damping=0.01,
        bend_stiffness=10.0 * scale,
        bend_damping=0.005,
    )
    b = ta.Builder()
    b.add_cloth_grid(
        origin=(0, 1, 0), size=(1.0, 1.0), resolution=(n, n), material=material, pinned=[0, n - 1]
    )
    b.add_force_gravity(G)
    return b.finalize()


def energy(model, x, v) -> float:
    """Kinetic + spring energy (model.energy) + gravity's potential -sum m g.x [J]."""
    m = model.particle_masses()
    return float(sum(model.energy(x, v).values()) - np.sum(m * (x @ G)))


def run_mode(n: int, scale: float, options: dict, steps: int) -> list:
    """One row of table (1)."""
    model = cloth(n, scale)
    state = model.state()
    integ = ta.IntegratorImplicitEuler(policy={"nonconvergence": "ignore"}, check_every=10, **options)
    x = state.particle_x.to_numpy()
    e0 = energy(model, x, np.zeros_like(x))
    drift, busy = [], 0.0
    for k in range(steps):
        start = common.clock()
        integ.step(model, state, DT)
        if k >= 2:
            busy += common.clock() - start
        drift.append(energy(model, state.particle_x.to_numpy(), state.particle_v.to_numpy()) - e0)
    c = integ.stepper_for(model).health.counts
    solves = c["linear_solves"]
    return [
        f"{1e3 * scale:.0e}",
        f"{1e3 * busy / (steps - 2):.1f}",
        f"{c['linear_iterations'] / steps:.0f}",
        f"{c.get('newton_iterations', steps) / steps:.2f}",
        f"{c.get('linear_unconverged', 0) / solves:.0%}",
        f"{c.get('newton_unconverged', 0)}",
        common.fmt_e(max(drift)),
        common.fmt_e(drift[-1]),
    ]


def cap_share(n: int, scale: float, steps: int) -> list:
    """One row of table (2)."""
    model = cloth(n, scale)
    state = model.state()
    integ = ta.IntegratorImplicitEuler(policy={"nonconvergence": "ignore"}, check_every=10)
    worst = 0.0
    for _ in range(steps):
        integ.step(model, state, DT)
        worst = max(worst, integ.last_solve.residual)
    c = integ.stepper_for(model).health.counts
    share = c["linear_unconverged"] / c["linear_solves"]
    capped = f"{c['linear_unconverged']}/{c['linear_solves']} ({share:.0%})"
    return [f"{1e3 * scale:.0e}", capped, f"{worst:.2g}"]


def read_cost(n: int, steps: int) -> list:
    """Table (3): ms per step and µs per result read (the solver's two small reads after a sync)."""
    model = cloth(n, 10.0)
    state = model.state()
    integ = ta.IntegratorImplicitEuler(check_every=10, policy={"nonconvergence": "ignore"})
    for _ in range(3):
        integ.step(model, state, DT)
    start = common.clock()
    for _ in range(steps):
        integ.step(model, state, DT)
    step_ms = 1e3 * (common.clock() - start) / steps
    solver = integ.linear_solver
    start = common.clock()
    for _ in range(200):
        int(solver.status[1])
        solver.final.to_numpy()
    read_us = 1e6 * (time.perf_counter() - start) / 200
    return [f"{n}^2", f"{step_ms:.1f}", f"{read_us:.0f}", f"{read_us / (10 * step_ms):.2f}%"]


def main() -> None:
    args = common.parse_args(__doc__.splitlines()[0])
    _, folder = common.output_paths(args)
    quick = args.quick
    n, steps = (12, 12) if quick else (32, 60)
    load_start = common.load_average()
    engine = common.engine_fingerprint()
    other = common.OtherLoad()
    common.init("f64")
    rows = []
    for scale in (100.0, 1000.0):
        for label, options in MODES.items():
            common.log(f"k={1e3 * scale:.0e} {label}")
            rows.append([label, *run_mode(n, scale, options, steps)])
    common.init("f32")
    caps = [cap_share(16 if quick else 32, s, 12 if quick else 120) for s in (10.0, 100.0, 1000.0)]
    cost = read_cost(32 if quick else 64, 10 if quick else 60)
    text = "\n\n".join(
        [
            "# Linearised implicit Euler against Newton with a line search; PCG at its cap",
            f"Command: `{common.command_line(args, 'cloth_newton.py')}`. Scene and measures: the module "
            "docstring of `benchmarks/cloth_newton.py`.",
            f"## (1) {n}^2 cloth, dt = 1/60 s, {steps} steps, f64, PCG tol 1e-4 / 200 it unless named, "
            "newton_tol 1e-2",
            common.md_table(
                [
                    "mode",
                    "k [N/m]",
                    "ms/step",
                    "PCG it/step",
                    "Newton it/step",
                    "solves at cap",
                    "Newton at cap",
                    "max (E_n - E_0) [J]",
                    "E_N - E_0 [J]",
                ],
                rows,
            ),
            f"## (2) PCG (tol 1e-4, cap 200) at dt = 1/60 s, {32 if not quick else 16}^2 cloth, f32",
            common.md_table(["k [N/m]", "solves at cap", "largest relative residual"], caps),
            "## (3) Cost of a solve's result read (one per solve), k = 1e4 N/m, f32",
            common.md_table(["cloth", "ms/step", "µs per read", "read / step"], [cost]),
            common.machine_table(
                common.machine_info(),
                load_start=load_start,
                load_end=common.load_average(),
                date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                engine=engine,
                other=other,
            ),
        ]
    )
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cloth_newton.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
