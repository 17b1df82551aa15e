"""Hard spheres: particle-steps/s of the engine's sphere contacts at 10^4, 10^5 and 10^6 spheres against
the same algorithm on Warp's HashGrid (peers/warp_spheres.py, warp-lang's CPU kernels, one thread) and
against the engine's brute-force search at 10^4, same start, same process.

Scene: N spheres (r = 0.01 m, 0.01 kg) on a jittered cubic lattice of spacing 2.2 r filling the lower half
of a container box; gravity; walls and pairs with restitution 0.5, friction 0.3; 4 Jacobi sweeps,
rest_speed 0.05 m/s; symplectic Euler at dt = 1/600 s, f32. The lattice first collapses for 150 engine
steps (60 with --quick) so the timed steps, of both sides, start from the same pile in contact.
Reported: particle-steps/s, the neighbour rebuild's share of our step, and the piles' kinetic energy and
largest overlap after the same steps (summation order differs: they agree statistically).

    .venv/bin/python benchmarks/spheres.py [--quick] [--arch cuda]

With `--arch cuda` both sides run on the GPU (ours `ta.init("cuda")`, Warp's kernels on device "cuda"),
page `spheres_cuda`.
"""

import math

import numpy as np
from harness import Page, Run, clock, host_clock, init, log, parse_args, peer, ratio, time_run

import taichi_anim as ta

R, MASS, DT, SETTLE = 0.01, 0.01, 1.0 / 600.0, 150
CONTACT = {"restitution": 0.5, "friction": 0.3, "iterations": 4, "rest_speed": 0.05}


def lattice(n: int):
    nx = math.ceil(n ** (1 / 3) - 1e-9)
    ny = math.ceil(n / nx**2)
    iy, iz, ix = np.unravel_index(np.arange(n), (ny, nx, nx))
    s = 2.2 * R
    x = (np.stack([ix, iy, iz], 1) + 0.5) * s + np.random.default_rng(0).uniform(-0.05 * R, 0.05 * R, (n, 3))
    return x, (0.0, 0.0, 0.0), (nx * s, 2 * ny * s, nx * s)


def build(x, v, lo, hi, method="auto"):
    b = ta.Builder()
    b.add_particles(x, v, MASS, radius=R)
    b.add_force_gravity((0.0, -9.81, 0.0))
    b.add_collider_box(lo, hi, restitution=0.5, friction=0.3)
    b.add_sphere_contacts(neighbor_search=method, **CONTACT)
    model = b.finalize(seed=0)
    integ = ta.make_integrator("symplectic_euler", check_every=10)
    return model, model.state(), integ


def settle(n: int, steps: int, arch: str = "cpu") -> dict:
    init("f32", arch)
    x, lo, hi = lattice(n)
    model, state, integ = build(x, None, lo, hi)
    for _ in range(steps):
        integ.step(model, state, DT)
    relax = float(integ.stepper_for(model).contacts.relaxation)
    return {
        "x": state.particle_x.to_numpy(),
        "v": state.particle_v.to_numpy(),
        "lo": lo,
        "hi": hi,
        "relax": relax,
    }


def ours(start: dict, steps: int, method: str, share: dict, arch: str = "cpu"):
    init("f32", arch)
    model, state, integ = build(start["x"], start["v"], start["lo"], start["hi"], method)
    contacts = integ.stepper_for(model).contacts
    share["search"] = contacts.neighbors.describe()
    rebuild = contacts.neighbors.build

    def timed_rebuild(*a, **kw):  # the rebuild's share of the step, behind a synchronised clock
        t0 = clock()
        rebuild(*a, **kw)
        share["rebuild"] = share.get("rebuild", 0.0) + clock() - t0

    contacts.neighbors.build = timed_rebuild

    def frame():
        for _ in range(steps):
            integ.step(model, state, DT)
        return state.particle_x.to_numpy(), state.particle_v.to_numpy()

    share["overlap"] = lambda: float(contacts.overlap_stats(model, state)[0])  # after the timing

    return frame


def warp(ws, start: dict, steps: int, sim_overlap: list, device: str = "cpu"):
    sim = ws.WarpSpheres(
        start["x"],
        start["v"],
        radius=R,
        mass=MASS,
        gravity=(0.0, -9.81, 0.0),
        lo=start["lo"],
        hi=start["hi"],
        wall_restitution=0.5,
        wall_friction=0.3,
        relaxation=start["relax"],
        device=device,
        **CONTACT,
    )

    def frame():
        for _ in range(steps):
            sim.step(DT)
        sim.sync()
        return sim.positions(), sim.velocities()

    sim_overlap.append(sim.max_overlap)

    return frame


def res_of(runs, name: str):
    return next(r.result for r in runs if r.name == name)


def pile(result, overlap: float) -> str:
    x, v = result
    return f"{0.5 * MASS * float((v.astype(np.float64) ** 2).sum()):.3g} J, {overlap / R:.3f} r"


def main(argv=None) -> None:
    args = parse_args(
        __doc__, argv, lambda p: p.add_argument("--arch", choices=("cpu", "cuda"), default="cpu")
    )
    arch = args.arch
    plan = [(10**4, 10), (10**5, 3)] if args.quick else [(10**4, 50), (10**5, 10), (10**6, 3)]
    frames = 3 if args.quick else 7
    ws = peer("warp_spheres")
    rows, data = [], []
    for n, steps in plan:
        log(f"{n:.0e} spheres, frames of {steps} steps")
        start = settle(n, 60 if args.quick else SETTLE, arch)
        share: dict = {}
        warp_overlap: list = []
        runs = []
        if n <= 10**4:  # brute force: frames of one step (it is ~100x slower); first, as each ta.init
            runs.append(Run("brute force", lambda s=start: ours(s, 1, "brute", {}, arch)))  # frees the last
        runs.append(Run("taichi_anim", lambda s=start, k=steps, sh=share: ours(s, k, "auto", sh, arch)))
        if ws is not None:
            runs.append(
                Run(
                    "warp HashGrid",
                    lambda s=start, k=steps, o=warp_overlap: warp(ws, s, k, o, arch),
                    sync=host_clock,
                )
            )
        res = {r.name: time_run(r, frames=frames) for r in runs}
        rate = {k: n * (1 if k == "brute force" else steps) / r["median"] for k, r in res.items()}
        timed_steps = steps * (res["taichi_anim"]["frames"] + 2)
        rebuild = share.get("rebuild", 0.0) / timed_steps / (res["taichi_anim"]["median"] / steps)
        warp_r = res.get("warp HashGrid")
        rows.append(
            [
                f"{n:.0e}",
                f"{rate['taichi_anim']:.3g}",
                f"{rate.get('warp HashGrid', 0):.3g}",
                ratio(warp_r and warp_r["median"], res["taichi_anim"]["median"]),
                f"{rate['brute force']:.3g}" if "brute force" in rate else "–",
                f"{rebuild:.0%}",
                f"{res['taichi_anim']['cores']:.2f} / {warp_r['cores']:.2f}" if warp_r else "–",
                pile(res_of(runs, "taichi_anim"), share["overlap"]()),
                pile(runs[-1].result, warp_overlap[0]()) if ws else "–",
            ]
        )
        data.append(
            {"n": n, "steps": steps, "runs": res, "search": share["search"], "rebuild_share": rebuild}
        )
    page = Page(
        "spheres" + ("_cuda" if arch == "cuda" else ""),
        "Hard spheres against Warp's HashGrid" + (" (CUDA, both sides)" if arch == "cuda" else ""),
        args,
        {
            "scene": "jittered lattice (spacing 2.2 r) collapsing in a box, r = 0.01 m, 0.01 kg, gravity",
            "contacts": f"{CONTACT}, walls restitution 0.5 friction 0.3, relaxation: the engine's",
            "step": f"symplectic Euler dt = 1/600 s, f32, after {SETTLE} settling steps, {frames} frames",
            "threads": "CUDA, both sides"
            if arch == "cuda"
            else "taichi_anim: Taichi's default (all cores); Warp: one thread (its CPU kernels)",
        },
    )
    page.table(
        "particle-steps/s",
        [
            "N",
            "taichi_anim",
            "warp HashGrid",
            "speed-up",
            "brute force",
            "rebuild share",
            "cores busy (ours / warp)",
            "ours: kinetic energy, worst overlap",
            "warp: same",
        ],
        rows,
        "cores busy: CPU time over wall time while the frames are timed.",
    )
    page.write(data)


if __name__ == "__main__":
    main()
