"""Particle throughput, Taichi against the same step in vectorised NumPy, f32, 10^4 ... 10^7 particles.

Scene (both sides): a disc emitter of capacity N (centre (0, 0.25, 0), radius 0.25 m, +y, 4 m/s +-10 %,
cone half-angle 0.5 rad, lifetime 0.5 s +-20 %, rate N / 0.5 s so the pool stays full), gravity, a
container box [-1, 1] x [0, 2] x [-1, 1] m with restitution 0.5; dt = 1/600 s, frames of 10 steps.
Measured once the pool is full: particle-steps/s = alive x steps / wall time, alive counted after the
timed frames (not inside them: on a GPU that count is a copy of every death time to the host). Ours runs
a frame the two ways the engine can: `Stepper.advance(state, dt, 10)` (the default for a scene's frame:
one blocked launch takes each particle through the 10 substeps, integrators/blocked.py, on the CPU in
packs of 8 particles; also timed with packs off, one particle per iteration) and ten
`step(state, dt)` calls (one emission and one fused step kernel per substep, the path before blocked
frames). Bytes per particle-step: the per-step path moves x, v read and written and the death time read,
52 B; the blocked frame about 80 B per particle per frame (x, v, birth, death read and written, its
scratch), 8 B per particle-step; both against a NumPy copy's bandwidth. "Of the streaming limit": the
rate against what a step that streams its 52 B per particle-step at the copy bandwidth could reach.
The speed-up is also measured in 5 rounds that alternate ours and NumPy, each round's ratio from its two
median frame times: the engines' separate runs above are minutes apart, and this VM's speed drifts.

    .venv/bin/python benchmarks/particles.py [--quick] [--arch cuda]

With `--arch cuda` ours runs on the GPU (page `particles_cuda`); NumPy stays on the host's one core. A
frame with emitters is blocked on the CPU only (integrators/blocked.py), so on CUDA both of our rows take
the per-step path.
"""

import math
import time

import numpy as np
from harness import Page, Run, clock, compile_times, fmt_s, init, log, parse_args, time_run

import taichi_anim as ta
import taichi_anim.integrators.blocked as blocked

DT, STEPS = 1.0 / 600.0, 10
LO, HI, RESTITUTION = (-1.0, 0.0, -1.0), (1.0, 2.0, 1.0), 0.5
CENTER, RADIUS, SPEED, SPEED_JITTER, SPREAD = (0.0, 0.25, 0.0), 0.25, 4.0, 0.1, 0.5
LIFETIME, LIFE_JITTER, G = 0.5, 0.2, -9.81
BYTES = 2 * 3 * 4 * 2 + 4  # per alive particle-step of the per-step fused kernel
# Per particle-step of the blocked frame, whose launch moves per slot and frame: x, v, birth, death read
# and written (2 x 32 B), the free bits (1/8 B), its scratch free_from and birth_head written and read
# (16 B): ~80 B a frame of STEPS substeps.
FRAME_BYTES = (2 * 32 + 1 / 8 + 16) / STEPS
ENGINES = ("taichi_anim", "one per iteration", "per step", "numpy")
FILL_FRAMES = math.ceil(LIFETIME * (1 + LIFE_JITTER) / DT / STEPS) + 2


def build(n: int):
    b = ta.Builder()
    b.add_particle_emitter(
        capacity=n,
        rate=n / LIFETIME,
        shape="disc",
        center=CENTER,
        radius=RADIUS,
        direction=(0, 1, 0),
        speed=SPEED,
        speed_jitter=SPEED_JITTER,
        spread=SPREAD,
        lifetime=LIFETIME,
        lifetime_jitter=LIFE_JITTER,
    )
    b.add_force_gravity((0.0, G, 0.0))
    b.add_collider_box(LO, HI, restitution=RESTITUTION, friction=0.0)
    model = b.finalize(seed=0)
    return model, model.state(), ta.make_integrator("symplectic_euler", check_every=STEPS)


def ours(n: int, alive: list, per_step: bool = False, arch: str = "cpu", packed=None):
    """A frame of ours; alive[0] counts the particles alive (call it after the timing). packed=False:
    the blocked frame takes one particle per iteration instead of packs (integrators/blocked.py)."""
    init("f32", arch)
    blocked.PACKED = packed
    model, state, integ = build(n)
    stepper = integ.stepper_for(model)

    def frame():
        if per_step:
            for _ in range(STEPS):
                stepper.step(state, DT)
        else:
            stepper.advance(state, DT, STEPS)

    alive.append(lambda: int(state.alive_mask().sum()))

    for _ in range(FILL_FRAMES):
        frame()
    return frame


class NumpyParticles:
    """The same step, structure of arrays: emit into the first dead slots, then for alive particles
    v += h g, x += h v, and the six box planes (project; reflect the inward normal velocity)."""

    def __init__(self, n: int):
        f = np.float32
        self.n, self.rng, self.t, self.carry = n, np.random.default_rng(0), 0.0, 0.0
        self.x, self.v = np.zeros((3, n), f), np.zeros((3, n), f)
        self.death = np.full(n, -1.0, f)

    def emit(self):
        want = self.n / LIFETIME * DT + self.carry
        self.carry = want - int(want)
        slots = np.flatnonzero(self.death <= np.float32(self.t))[: int(want)]
        r = self.rng.random((6, len(slots)), dtype=np.float32)
        rad, ang = RADIUS * np.sqrt(r[0]), 2 * np.pi * r[1]
        cos_t = 1 - r[2] * np.float32(1 - math.cos(SPREAD))
        sin_t, phi = np.sqrt(np.maximum(1 - cos_t**2, 0)), 2 * np.pi * r[3]
        speed = SPEED * (1 + SPEED_JITTER * (2 * r[4] - 1))
        self.x[:, slots] = np.array(CENTER, np.float32)[:, None] + [
            rad * np.cos(ang),
            0 * rad,
            rad * np.sin(ang),
        ]
        self.v[:, slots] = speed * np.array([sin_t * np.cos(phi), cos_t, sin_t * np.sin(phi)])
        self.death[slots] = self.t + LIFETIME * (1 + LIFE_JITTER * (2 * r[5] - 1))

    def step(self):
        self.emit()
        alive = self.death > np.float32(self.t)
        x, v = self.x, self.v
        np.add(v[1], np.float32(DT * G), out=v[1], where=alive)
        np.add(x, np.float32(DT) * v, out=x, where=alive)
        for a in range(3):
            for bound, outside in ((LO[a], np.less), (HI[a], np.greater)):
                hit = outside(x[a], bound) & alive
                np.copyto(x[a], np.float32(bound), where=hit)
                np.multiply(v[a], np.float32(-RESTITUTION), out=v[a], where=hit & outside(v[a], 0))
        self.t += DT
        return alive


def numpy_peer(n: int, alive: list):
    sim = NumpyParticles(n)

    def frame():
        for _ in range(STEPS):
            sim.step()

    alive.append(lambda: int((sim.death > np.float32(sim.t - DT)).sum()))  # alive in the last step

    for _ in range(FILL_FRAMES):
        frame()
    return frame


def alternating(n: int, frames: int, rounds: int = 5) -> list[float]:
    """Ours / NumPy in particle-steps/s, measured in `rounds` rounds that alternate the two engines
    (median frame time of `frames` frames each): a ratio that the machine's drift between the engines'
    separate runs above does not move (NumPy's own 10^4 rate moved from 7e7 to 1e8 between runs here)."""
    alive_o: list = []
    alive_n: list = []
    engines = [(ours(n, alive_o), clock), (numpy_peer(n, alive_n), time.perf_counter)]
    medians: list[list[float]] = [[], []]
    for _ in range(rounds):
        for k, (frame, now) in enumerate(engines):
            times = []
            for _ in range(frames):
                a = now()
                frame()
                times.append(now() - a)
            medians[k].append(float(np.median(times)))
    rate = alive_o[0]() / alive_n[0]()  # alive counts after the rounds: both pools stay ~99 % full
    return [rate * tn / to for to, tn in zip(*medians, strict=True)]


def copy_bandwidth(nbytes: int = 2**29) -> float:
    """Best GB/s (read + write) of a NumPy copy of 512 MiB, beyond the caches."""
    src = np.ones(nbytes // 4, np.float32)
    dst = np.empty_like(src)
    best = 0.0
    for _ in range(4):
        t0 = time.perf_counter()
        np.copyto(dst, src)
        best = max(best, 2 * nbytes / (time.perf_counter() - t0) / 1e9)
    return best


def main(argv=None) -> None:
    args = parse_args(
        __doc__, argv, lambda p: p.add_argument("--arch", choices=("cpu", "cuda"), default="cpu")
    )
    arch = args.arch
    sizes, frames = ([10**4, 10**5], 5) if args.quick else ([10**4, 10**5, 10**6, 10**7], 30)
    bw = copy_bandwidth(2**26 if args.quick else 2**29)
    log(f"copy bandwidth {bw:.1f} GB/s")

    def compile_run():
        a = clock()
        model, state, integ = build(10**4)
        stepper = integ.stepper_for(model)
        stepper.advance(state, DT, STEPS)  # a frame, as timed below
        first = clock() - a
        a = clock()
        stepper.advance(state, DT, STEPS)
        return first, clock() - a

    comp = compile_times(compile_run, arch=arch)
    rows, data = [], []
    for n in sizes:
        log(f"{n:.0e} particles")
        res = {}
        engines = (
            ("taichi_anim", lambda n, a: ours(n, a, False, arch)),
            ("one per iteration", lambda n, a: ours(n, a, False, arch, packed=False)),
            ("per step", lambda n, a: ours(n, a, True, arch)),
            ("numpy", numpy_peer),
        )
        for name, make in engines:
            alive: list = []
            r = time_run(
                Run(name, lambda make=make, alive=alive, n=n: make(n, alive)), frames=frames, warmup=1
            )
            r["alive"] = float(alive[0]())
            r["rate"] = r["alive"] * STEPS / r["median"]
            res[name] = r
        alt = alternating(n, max(3, frames // 6))
        log(f"  alternating rounds, ours / NumPy: {', '.join(f'{a:.2f}' for a in alt)}")
        res["alternating"] = alt
        t, s, p = res["taichi_anim"], res["per step"], res["numpy"]
        one = res["one per iteration"]
        gbs, step_gbs = FRAME_BYTES * t["rate"] / 1e9, BYTES * s["rate"] / 1e9
        rows.append([f"{n:.0e}", f"{t['alive'] / n:.3f}", f"{t['rate']:.3g}", f"{one['rate']:.3g}"])
        rows[-1] += [f"{s['rate']:.3g}", f"{p['rate']:.3g}"]
        rows[-1] += [
            f"**{t['rate'] / p['rate']:.2f}x**",
            f"**{np.median(alt):.2f}x** ({min(alt):.2f}-{max(alt):.2f})",
        ]
        rows[-1] += [f"{one['rate'] / p['rate']:.2f}x"]
        rows[-1] += [f"{s['rate'] / p['rate']:.2f}x"]
        rows[-1] += [f"{gbs:.1f}", f"{gbs / bw:.2f}", f"{BYTES * t['rate'] / 1e9 / bw:.2f}"]
        rows[-1] += [f"{step_gbs / bw:.2f}", f"{t['cores']:.2f}"]
        data.append({"n": n, **res})
    page = Page(
        "particles" + ("_cuda" if arch == "cuda" else ""),
        "Particle step: taichi_anim against NumPy" + (" (taichi_anim on CUDA)" if arch == "cuda" else ""),
        args,
        {
            "arch": f"taichi_anim {arch}; NumPy on one host core",
            "scene": "disc emitter (pool N, lifetime 0.5 s +-20 %), gravity, box (restitution 0.5)",
            "step": f"symplectic Euler, dt 1/600 s, {STEPS} steps a frame, f32, after {FILL_FRAMES} frames",
            "taichi_anim": f"Stepper.advance(state, dt, {STEPS}): one blocked launch per frame, particles "
            f"in packs of {blocked.PACK} on the CPU",
            "one per iteration": "the same launch with packs off (blocked.PACKED = False)",
            "per step": f"{STEPS} x Stepper.step(state, dt): emission + fused step kernel per substep",
            "frames timed": f"{frames}; alternating: 5 rounds of {max(3, frames // 6)} of ours, then NumPy",
            "bytes per particle-step": f"per step {BYTES}; blocked frame {FRAME_BYTES:g}",
            "NumPy copy bandwidth": f"{bw:.1f} GB/s",
        },
    )
    page.table(
        "Throughput",
        [
            "N",
            "alive",
            "taichi_anim particle-steps/s",
            "one per iteration",
            "per step",
            "NumPy",
            "speed-up",
            "speed-up, alternating rounds (median of 5, range)",
            "one per iteration / NumPy",
            "per step / NumPy",
            "GB/s moved",
            "of copy bandwidth",
            f"of the streaming limit ({BYTES} B at the copy bandwidth)",
            "per step: of copy bandwidth",
            "cores busy",
        ],
        rows,
    )
    comp_rows = [[m, fmt_s(c["first"]), fmt_s(c["steady"]), fmt_s(c["compile"])] for m, c in comp.items()]
    page.table(
        "Compile (10^4 pool, fresh ta.init)",
        ["offline cache", "first frame", "steady frame", "compile"],
        comp_rows,
    )
    page.plot(
        {
            k: (sizes, [d[k]["rate"] for d in data])
            for k in ("taichi_anim", "one per iteration", "per step", "numpy")
        },
        xlabel="particles",
        ylabel="particle-steps/s",
    )
    page.write({"bandwidth": bw, "compile": comp, "sizes": data})


if __name__ == "__main__":
    main()
