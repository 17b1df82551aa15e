"""The stability guard against measurement: predicted against measured largest stable steps, and the
estimate's cost.

Part 1. Scene: cloth_solvers.py's stability cloth at 32² (1 m square, edge j = 0 pinned, 0.2 kg/m²,
stretch k, shear k/10, bend k/100 N/m with damping 0.15/0.015/0.0015 kg/s, gravity, flat at rest), for
k = 10^2 ... 10^5 N/m and each fixed-step explicit method (explicit Euler, symplectic Euler, midpoint,
RK4), f64. Predicted: `stability.frequency` at the starting state (Lanczos omega_max and the top mode's
damping ratio; the block-Gershgorin bound beside it) and `stability.stability_limit` (the step at which
the stiffest modes' energy would grow by more than 1% per second), the step the guard compares with.
Reference omega_max: scipy's eigsh (ARPACK, tol 1e-10) on M^-1/2 K M^-1/2 of the springs at rest, as
cloth_solvers.py assembles it. Measured: cloth_solvers.py's bisection on log dt for the largest step
whose run over T_STAB stays stable (finite, every vertex below 50 m/s, total energy below its start +
0.1 M g (1 m), checked every 0.01 s), bracketing by factors of 2 from the prediction, then BISECT halvings
of the bracket in log dt. The guard is right when no step it lets through (dt <= 0.95 x predicted) was
measured unstable.

Part 2. Cost of the estimate on 128² cloths (springs at k = 10^4, and the continuum fabric of the cloth
demo: StVK membrane + dihedral bending), f32 as the demos run: wall time of `state_frequency` (first
call, with any kernel compile, and a second call), its Lanczos steps, against one symplectic Euler step
of the same cloth; for the fabric also with blocks=True (its exact element Hessians, which give the
Gershgorin bound but compile for long). The guard pays it once per stepper, never per step.

    .venv/bin/python benchmarks/stability.py           # full run, writes benchmarks/results/stability.md
    .venv/bin/python benchmarks/stability.py --quick   # smoke run (< 1 min), writes benchmarks/out/
"""

from __future__ import annotations

import dataclasses
import json
import time

import cloth_solvers as cs
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
from taichi_anim import stability

METHODS = ("explicit_euler", "symplectic_euler", "midpoint", "rk4")
FULL = dataclasses.replace(cs.FULL, n_stab=32, t_stab=0.25, bisect=4, dt_floor=1e-5)
QUICK = dataclasses.replace(cs.QUICK, n_stab=8, ks=(1e4,), t_stab=0.1, bisect=2, dt_floor=1e-5)
COST_N = (128, 32)  # full, quick
IGNORE = {"stability": "ignore"}  # the measurements step beyond the limit on purpose


def measure_limits(s) -> list[dict]:
    init("f64")
    rows = []
    for k in s.ks:
        cloth = cs.Cloth(cs.Scene(s.n_stab, k))
        est = stability.frequency(cloth.model, cloth.x0)
        ref = cloth.omega_max()
        log(f"[k={k:.0e}] omega {est.omega:.1f} (ref. {ref:.1f}, bound {est.bound:.1f}), zeta {est.zeta:.3g}")
        for name in METHODS:
            predicted = stability.stability_limit(name, est.omega, est.zeta)
            integ = ta.make_integrator(name, check_every=cs.CHECK_EVERY, policy=IGNORE)
            log(f"  {name}: predicted {predicted:.4g} s")
            t0 = time.perf_counter()
            found = cs.largest_stable(cloth, integ, predicted, s)
            rows.append(
                {
                    "k": k,
                    "method": name,
                    "omega": est.omega,
                    "omega_reference": ref,
                    "omega_bound": est.bound,
                    "zeta": est.zeta,
                    "predicted": predicted,
                    "stable": found["lo"],
                    "unstable": found["hi"],
                    "result": found["result"],
                    "why": next((t["why"] for t in found["tests"] if t["dt"] == found["hi"]), ""),
                    "seconds": time.perf_counter() - t0,
                }
            )
    return rows


def cost_cloth(n: int, membrane: bool):
    b = ta.Builder()
    b.add_force_gravity()
    material = ta.FabricMaterial(
        density=0.2, youngs_modulus=1.0e3, poisson_ratio=0.3, bending_stiffness=5.0e-5
    )
    b.add_cloth_grid(
        origin=(0.0, 1.0, 0.0),
        size=(1.0, 1.0),
        resolution=(n, n),
        plane="xz",
        material=material if membrane else ta.ClothMaterial(stretch_stiffness=1e4),
        pinned=[0, n - 1],
    )
    return b.finalize()


def measure_cost(n: int) -> list[dict]:
    init("f32")
    rows = []
    for membrane, blocks in ((False, None), (True, None), (True, True)):
        model = cost_cloth(n, membrane)
        state = model.state()
        x, v = state.particle_x.to_numpy(), state.particle_v.to_numpy()
        t0 = time.perf_counter()
        stability.frequency(model, x, v, blocks=blocks)
        first_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        again = stability.frequency(model, x, v, blocks=blocks)
        again_s = time.perf_counter() - t0
        integ = ta.make_integrator("symplectic_euler", check_every=cs.CHECK_EVERY, policy=IGNORE)
        dt = 0.5 * stability.stability_limit("symplectic_euler", again.omega, again.zeta)
        for _ in range(3):  # warm-up (compile)
            integ.step(model, state, dt)
        steps = 50
        t0 = clock()
        for _ in range(steps):
            integ.step(model, state, dt)
        step_s = (clock() - t0) / steps
        rows.append(
            {
                "cloth": f"{n}² "
                + ("membrane + bending" if membrane else "springs k = 1e4")
                + (", blocks=True" if blocks and membrane else ""),
                "dofs": 3 * model.particle_count,
                "first_s": first_s,
                "again_s": again_s,
                "lanczos_steps": again.iterations,
                "omega": again.omega,
                "bound": again.bound if again.bound == again.bound else None,
                "step_s": step_s,
            }
        )
        log(f"[cost] {rows[-1]}")
    return rows


def guard_right(r: dict) -> bool:
    """No step the guard lets through (dt <= GUARD_SAFETY x predicted) was measured unstable."""
    return r["unstable"] is None or r["unstable"] > stability.GUARD_SAFETY * r["predicted"]


def limits_table(rows: list[dict]) -> str:
    out = []
    for r in rows:
        if r["stable"] is None:
            measured = f"< {cs.fmt_e(r['unstable'], 3)} (floor)"
            ratio = "–"
        else:
            top = "≥ cap" if r["unstable"] is None else f"{r['unstable']:.3g} ({r['why']})"
            measured = f"{r['stable']:.3g} / {top}"
            hi = "∞" if r["unstable"] is None else f"{r['unstable'] / r['predicted']:.3f}"
            ratio = f"{r['stable'] / r['predicted']:.3f}–{hi}"
        safe = guard_right(r)
        out.append(
            [
                f"{r['k']:.0e}",
                r["method"],
                f"{r['omega']:.0f} ({r['omega_reference']:.0f}; {r['omega_bound']:.0f})",
                f"{r['zeta']:.3g}",
                f"{r['predicted']:.3g}",
                measured,
                ratio,
                "yes" if safe else "**NO**",
            ]
        )
    headers = [
        "k [N/m]",
        "method",
        "omega_max [rad/s] (reference; Gershgorin)",
        "zeta",
        "predicted limit [s]",
        "measured stable / unstable [s]",
        "measured limit / predicted (bracket)",
        "guard right",
    ]
    return md_table(headers, out)


def cost_table(rows: list[dict]) -> str:
    out = [
        [
            r["cloth"],
            r["dofs"],
            fmt_s(r["first_s"]),
            fmt_s(r["again_s"]),
            r["lanczos_steps"],
            "–" if r["bound"] is None else f"{r['bound'] / r['omega']:.2f}",
            fmt_s(r["step_s"]),
            f"{r['again_s'] / r['step_s']:.0f}",
        ]
        for r in rows
    ]
    headers = [
        "cloth (f32)",
        "dofs",
        "estimate, first call (compile incl.)",
        "estimate, again",
        "Lanczos steps",
        "Gershgorin / Lanczos",
        "symplectic Euler step",
        "estimate / step",
    ]
    return md_table(headers, out)


def main(argv=None) -> None:
    args = parse_args(__doc__.split("\n")[0], argv)
    s = QUICK if args.quick else FULL
    md_path, folder = output_paths(args)
    page = folder / "stability.md"
    load_start, engine, other, t0 = load_average(), engine_fingerprint(), OtherLoad(), time.perf_counter()
    limits = measure_limits(s)
    cost = measure_cost(COST_N[1] if args.quick else COST_N[0])
    wall = time.perf_counter() - t0
    info = machine_table(
        machine_info(),
        load_start=load_start,
        load_end=load_average(),
        date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        engine=engine,
        other=other,
    )
    wrong = [r for r in limits if not guard_right(r)]
    text = f"""# Stability guard: predicted against measured step limits

Regenerate: `{command_line(args, "stability.py")}` (took {wall / 60:.1f} min). The module docstring of
`benchmarks/stability.py` describes the method. Timings were taken on a shared 2-core machine (other
sessions ran tests meanwhile; see the load averages): read them as orders of magnitude.

{info}

## 1. Largest stable step: predicted by the guard, measured by bisection

{s.n_stab}² cloth, f64, T = {s.t_stab:g} s per run, {s.bisect} bisections after bracketing, nothing tested
below {s.dt_floor:g} s or above {s.dt_cap:.3g} s. Each cell "measured" gives the largest stable step found
and the smallest unstable one (with why it failed). "guard right": the smallest unstable step lies above
{stability.GUARD_SAFETY} x predicted, so the guard warns before any step that failed
({len(wrong)} of {len(limits)} cases wrong).

{limits_table(limits)}

## 2. Cost of the estimate

Once per stepper (the guard caches it; `auto_substeps` shares it). Springs need no kernel (NumPy blocks);
the fabric's estimate multiplies by differences of the total force, whose kernel compiles on the first
call (blocks=True: the terms' element Hessians instead, which compile for much longer).

{cost_table(cost)}
"""
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(text)
    (folder / "stability.json").write_text(json.dumps({"limits": limits, "cost": cost}, indent=1))
    log(f"wrote {page}")


if __name__ == "__main__":
    main()
