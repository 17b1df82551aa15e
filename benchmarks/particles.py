"""Particle throughput: emission into dead pool slots, ageing, gravity, a container box (six planes with
restitution) and the symplectic Euler step, Taichi against a vectorised NumPy implementation of the same
step, float32, at 10^4 ... 10^7 particles.

Scene (every size): one disc emitter of capacity N at (0, 0.25, 0), radius 0.25 m, facing +y, speed 4 m/s
(+-10 %), cone half-angle 0.5 rad, lifetime 0.5 s (+-20 %, and a second variant with no jitter), rate =
N / mean lifetime so the pool stays full in steady state; gravity (0, -9.81, 0) m/s^2; container box
[-1, 1] x [0, 2] x [-1, 1] m, restitution 0.5, no friction (collision mode "projection"); dt = 1/600 s,
`check_every` = 10 (ten steps per 60 Hz frame, the divergence counter read once per frame).

Measured: after the pool has filled (steady state), the wall time of K steps (ti.sync() before each clock
read) gives particle-steps/s = (alive particles) x K / wall time. Bytes per particle-step of the fused
Taichi step kernel (taichi_anim/integrators/symplectic_euler.py `_kernel`, with `Model.alive`): x and v
read and written, 4 x 12 B, plus the death time read, 4 B = 52 B (the mass is a compile-time constant
here, gravity and the planes are constants; `Model.release_if_dead` reads the same death time again, and
touches the free-slot bit words only for the ~dt/lifetime = 0.3 % of particles that die in the step).
The streaming limit is a NumPy copy of 512 MiB in the same run. Emission and the step kernel are then
timed apart (`model.emit`, `integ.advance_step`), a run with Taichi's kernel profiler counts launches per step
and the time of each kernel, and the integrator loop is timed serial against parallel at small N.

    .venv/bin/python benchmarks/particles.py           # full run (~4 min), writes benchmarks/RESULTS.md
    .venv/bin/python benchmarks/particles.py --quick   # smoke run (~1 min), writes benchmarks/out/
"""

import json
import math
import re
import time
from dataclasses import dataclass

import numpy as np
import taichi as ti
from common import (
    COMPILE_HEADERS,
    OtherLoad,
    clock,
    command_line,
    compile_rows,
    compile_times,
    engine_fingerprint,
    fmt_e,
    fmt_s,
    init,
    load_average,
    log,
    machine_info,
    machine_table,
    md_table,
    memory_bandwidth,
    output_paths,
    parse_args,
    write_section,
)

import taichi_anim as ta

DT = 1.0 / 600.0  # [s]
STEPS_PER_FRAME = 10  # = check_every
GRAVITY = (0.0, -9.81, 0.0)
BOX_LO = (-1.0, 0.0, -1.0)
BOX_HI = (1.0, 2.0, 1.0)
RESTITUTION = 0.5
LIFETIME = 0.5  # [s] mean
SPEED = 4.0
SPEED_JITTER = 0.1
SPREAD = 0.5  # [rad]
RADIUS = 0.25
CENTER = (0.0, 0.25, 0.0)
DIRECTION = (0.0, 1.0, 0.0)
SEED = 0
# Bytes moved per alive particle-step by the fused symplectic Euler kernel in f32 (see the docstring).
BYTES_PER_PARTICLE_STEP = 2 * 3 * 4 * 2 + 4


@dataclass(frozen=True)
class Variant:
    jitter: float

    @property
    def rate_per_capacity(self) -> float:
        return 1.0 / LIFETIME  # mean lifetime = LIFETIME whatever the (symmetric) jitter

    @property
    def fill_steps(self) -> int:
        """Steps until every slot has been used once and the longest first lifetime has run out."""
        return math.ceil(LIFETIME * (1.0 + self.jitter) / DT) + 2 * STEPS_PER_FRAME


def build(n: int, v: Variant):
    b = ta.Builder()
    b.add_particle_emitter(
        capacity=n,
        rate=n * v.rate_per_capacity,
        shape="disc",
        center=CENTER,
        radius=RADIUS,
        direction=DIRECTION,
        speed=SPEED,
        speed_jitter=SPEED_JITTER,
        spread=SPREAD,
        lifetime=LIFETIME,
        lifetime_jitter=v.jitter,
    )
    b.add_force_gravity(GRAVITY)
    b.add_collider_box(BOX_LO, BOX_HI, restitution=RESTITUTION, friction=0.0)
    model = b.finalize(seed=SEED)
    integ = ta.make_integrator("symplectic_euler", check_every=STEPS_PER_FRAME)
    return model, model.state(), integ


def steps_for(seconds: float, per_step: float, lo: int = 20, hi: int = 3000) -> int:
    k = int(seconds / max(per_step, 1e-9))
    return max(lo, min(hi, k // STEPS_PER_FRAME * STEPS_PER_FRAME))


def alive_stats(x: np.ndarray, v: np.ndarray, alive: np.ndarray) -> dict:
    """Sanity figures that two implementations of the same scene should share (different random streams)."""
    return {
        "alive_fraction": float(alive.mean()),
        "mean_height": float(x[alive, 1].mean()) if alive.any() else float("nan"),
        "mean_speed": float(np.linalg.norm(v[alive], axis=1).mean()) if alive.any() else float("nan"),
    }


# ---------------------------------------------------------------------------------------------------------
# Taichi


def taichi_run(n: int, v: Variant, window: float) -> dict:
    """Fill the pool, then time K whole steps, then K2 steps with emission and the step kernel apart."""
    init("f32")
    model, state, integ = build(n, v)
    t0 = clock()
    for _ in range(STEPS_PER_FRAME):
        integ.step(model, state, DT)
    t1 = clock()
    for _ in range(STEPS_PER_FRAME):
        integ.step(model, state, DT)
    t2 = clock()
    for _ in range(v.fill_steps - 2 * STEPS_PER_FRAME):
        integ.step(model, state, DT)
    t3 = clock()
    alive_before = int(state.alive_mask().sum())
    # A few steady steps to size K.
    t4 = clock()
    for _ in range(STEPS_PER_FRAME):
        integ.step(model, state, DT)
    per_step = (clock() - t4) / STEPS_PER_FRAME
    k = steps_for(window, per_step)
    alive_a = int(state.alive_mask().sum())
    t5 = clock()
    for _ in range(k):
        integ.step(model, state, DT)
    wall = clock() - t5
    alive_b = int(state.alive_mask().sum())
    state.check_finite()
    alive_mean = 0.5 * (alive_a + alive_b)

    # Emission and the step kernel apart (what Integrator.step does, minus trails, with a sync between).
    em = model.emitters[0]
    k2 = steps_for(0.5 * window, per_step, lo=20, hi=1000)
    t_emit = t_step = 0.0
    found, wanted = 0, 0
    for _ in range(k2):
        want = min(int(em.s.rate * DT + state.emit_carry[em.index]), em.capacity)
        a = clock()
        model.emit(state, DT)
        b = clock()
        integ.advance_step(model, state, DT)
        c = clock()
        state.time += DT
        state.step_count += 1
        t_emit += b - a
        t_step += c - b
        got = int(state.emit_found[em.index]) if want else 0
        found += got
        wanted += want
    state.check_finite()
    alive = state.alive_mask()
    stats = alive_stats(state.particle_x.to_numpy(), state.particle_v.to_numpy(), alive)
    return {
        "n": n,
        "jitter": v.jitter,
        "first_frame": t1 - t0,
        "second_frame": t2 - t1,
        "fill_steps": v.fill_steps,
        "fill_time": t3 - t0,
        "alive_after_fill": alive_before,
        "steps": k,
        "wall": wall,
        "step_time": wall / k,
        "alive_mean": alive_mean,
        "rate": alive_mean * k / wall,
        "split_steps": k2,
        "emit_time": t_emit / k2,
        "kernel_time": t_step / k2,
        "found_per_step": found / k2,
        "wanted_per_step": wanted / k2,
        **stats,
    }


_TASK = re.compile(r"^(?P<kernel>.+?)(_c\d+_\d+)?_kernel_(?P<task>\d+)_\w+$")


def taichi_profile(n: int, v: Variant, steps: int) -> dict:
    """Kernel launches per step and time per kernel, from Taichi's kernel profiler (a separate session:
    the profiler adds a timer around every task)."""
    init("f32", kernel_profiler=True)
    model, state, integ = build(n, v)
    for _ in range(v.fill_steps):
        integ.step(model, state, DT)
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    for _ in range(steps):
        integ.step(model, state, DT)
    ti.sync()
    total = ti.profiler.get_kernel_profiler_total_time()
    kernels: dict[str, dict[str, float]] = {}
    try:
        stats = ti.profiler.kernel_profiler.get_default_kernel_profiler()._statistical_results
    except AttributeError:  # the profiler's internals changed: report what is public
        stats = {}
    for name, s in stats.items():
        m = _TASK.match(name)
        kernel = m.group("kernel") if m else name
        entry = kernels.setdefault(kernel, {"launches": 0, "time": 0.0})
        if m is None or m.group("task") == "0":
            entry["launches"] += s.counter
        entry["time"] += s.total_time / 1e3
    return {
        "n": n,
        "steps": steps,
        "total_kernel_time": total,
        "launches_per_step": sum(e["launches"] for e in kernels.values()) / steps
        if kernels
        else float("nan"),
        "kernels": {
            k: {"launches_per_step": e["launches"] / steps, "ms_per_step": e["time"] / steps * 1e3}
            for k, e in kernels.items()
        },
    }


def taichi_stream_reference(n: int, window: float) -> dict:
    """A minimal Taichi kernel that moves the same 52 B per particle as the engine's step kernel (x, v
    read + write, death time read; gravity and symplectic update, no collisions): what a plain Taichi
    field kernel reaches on this machine, to separate the engine's costs from Taichi's."""
    init("f32")
    x = ti.Vector.field(3, ti.f32, n)
    v = ti.Vector.field(3, ti.f32, n)
    death = ti.field(ti.f32, n)
    death.fill(1.0e30)

    @ti.kernel
    def step(h: ti.f32, t: ti.f32):
        for i in range(n):
            if death[i] > t:
                v1 = v[i] + h * ti.Vector([0.0, -9.81, 0.0])
                x[i] = x[i] + h * v1
                v[i] = v1

    step(DT, 0.0)
    t0 = clock()
    step(DT, 0.0)
    per = clock() - t0
    k = steps_for(0.5 * window, per, lo=20, hi=2000)
    t0 = clock()
    for _ in range(k):
        step(DT, 0.0)
    per = (clock() - t0) / k
    return {"n": n, "steps": k, "time": per, "gbs": BYTES_PER_PARTICLE_STEP * n / per / 1e9}


def serial_threshold(sizes, window: float) -> list[dict]:
    """Whole-step time in steady state with the integrator's particle loop forced serial or parallel
    (`Model.serial`, read when the kernels compile, i.e. at the first step), per N: where the engine's
    CPU serial threshold (`taichi_anim.runtime.CPU_SERIAL_BELOW`) should sit."""
    v = Variant(0.2)
    out = []
    for n in sizes:
        row = {"n": n}
        for serial in (True, False):
            init("f32")
            model, state, integ = build(n, v)
            if not hasattr(model, "serial"):
                return []
            row.setdefault("default", bool(model.serial))
            model.serial = serial
            for _ in range(v.fill_steps):
                integ.step(model, state, DT)
            t0 = clock()
            for _ in range(STEPS_PER_FRAME):
                integ.step(model, state, DT)
            k = steps_for(0.25 * window, (clock() - t0) / STEPS_PER_FRAME)
            t0 = clock()
            for _ in range(k):
                integ.step(model, state, DT)
            row["serial" if serial else "parallel"] = (clock() - t0) / k
        out.append(row)
        log(f"serial threshold n={n:.0e}: serial {fmt_s(row['serial'])}, parallel {fmt_s(row['parallel'])}")
    return out


# ---------------------------------------------------------------------------------------------------------
# NumPy peer


def _basis(d):
    """The engine's two unit vectors orthogonal to `d` (taichi_anim/particles/emitters.py `_basis`)."""
    d = np.asarray(d, dtype=np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


class NumpyParticles:
    """The same step in vectorised NumPy, float32, structure of arrays (x[axis, particle]):
    emission into the first dead slots (death <= t) with the engine's sampling formulas (NumPy's own
    random stream), then for alive particles (death > t at the start of the step) symplectic Euler with
    gravity, and the six container planes in the engine's order (project onto the plane; reflect the
    normal velocity with restitution if it points into the wall)."""

    def __init__(self, n: int, v: Variant):
        f32 = np.float32
        self.n = n
        self.rate = n * v.rate_per_capacity
        self.jitter = v.jitter
        self.x = np.repeat(np.asarray(CENTER, f32)[:, None], n, axis=1)
        self.v = np.zeros((3, n), f32)
        self.birth = np.zeros(n, f32)
        self.death = np.full(n, -1.0, f32)
        self.alive = np.zeros(n, bool)
        self.m1 = np.zeros(n, bool)
        self.m2 = np.zeros(n, bool)
        self.tmp = np.zeros(n, f32)
        self.carry = 0.0
        self.t = 0.0
        self.rng = np.random.default_rng(SEED)
        u, w = _basis(DIRECTION)
        self.u = u.astype(f32)[:, None]
        self.w = w.astype(f32)[:, None]
        self.axis = np.asarray(DIRECTION, f32)[:, None]
        self.center = np.asarray(CENTER, f32)[:, None]

    def emit(self, t: float, dt: float) -> None:
        want = self.rate * dt + self.carry
        k = min(int(want), self.n)
        self.carry = want - int(want)
        if k == 0:
            return
        np.less_equal(self.death, np.float32(t), out=self.m1)
        slots = np.flatnonzero(self.m1)[:k]
        k = len(slots)
        r = self.rng.random((7, k), dtype=np.float32)
        two_pi = np.float32(2.0 * math.pi)
        rad = RADIUS * np.sqrt(r[0])
        ang = two_pi * r[1]
        pos = self.center + rad * (np.cos(ang) * self.u + np.sin(ang) * self.w)
        cos_t = 1.0 - r[3] * np.float32(1.0 - math.cos(SPREAD))
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        phi = two_pi * r[4]
        dirn = cos_t * self.axis + sin_t * (np.cos(phi) * self.u + np.sin(phi) * self.w)
        speed = SPEED * (1.0 + SPEED_JITTER * (2.0 * r[5] - 1.0))
        life = LIFETIME * (1.0 + self.jitter * (2.0 * r[6] - 1.0))
        self.x[:, slots] = pos
        self.v[:, slots] = speed * dirn
        self.birth[slots] = t
        self.death[slots] = np.float32(t) + life

    def step(self, dt: float) -> None:
        t = self.t
        self.emit(t, dt)
        x, v, alive, m1, m2, tmp = self.x, self.v, self.alive, self.m1, self.m2, self.tmp
        h = np.float32(dt)
        np.greater(self.death, np.float32(t), out=alive)
        for a in range(3):
            if GRAVITY[a] != 0.0:
                np.add(v[a], np.float32(dt * GRAVITY[a]), out=v[a], where=alive)
            np.multiply(v[a], h, out=tmp)
            np.add(x[a], tmp, out=x[a], where=alive)
        e = np.float32(-RESTITUTION)
        for a in range(3):
            for bound, below in ((np.float32(BOX_LO[a]), True), (np.float32(BOX_HI[a]), False)):
                (np.less if below else np.greater)(x[a], bound, out=m1)
                np.logical_and(m1, alive, out=m1)
                np.copyto(x[a], bound, where=m1)
                (np.less if below else np.greater)(v[a], 0.0, out=m2)
                np.logical_and(m1, m2, out=m2)
                np.multiply(v[a], e, out=v[a], where=m2)
        self.t = t + dt


def numpy_run(n: int, v: Variant, window: float) -> dict:
    sim = NumpyParticles(n, v)
    t0 = time.perf_counter()
    for _ in range(v.fill_steps):
        sim.step(DT)
    fill = time.perf_counter() - t0
    per_step = fill / v.fill_steps
    k = steps_for(window, per_step, lo=10)
    alive_a = int((sim.death > np.float32(sim.t)).sum())
    t1 = time.perf_counter()
    for _ in range(k):
        sim.step(DT)
    wall = time.perf_counter() - t1
    alive = sim.death > np.float32(sim.t)
    alive_mean = 0.5 * (alive_a + int(alive.sum()))
    stats = alive_stats(sim.x.T, sim.v.T, alive)
    return {
        "n": n,
        "jitter": v.jitter,
        "steps": k,
        "wall": wall,
        "step_time": wall / k,
        "alive_mean": alive_mean,
        "rate": alive_mean * k / wall,
        "fill_time": fill,
        **stats,
    }


# ---------------------------------------------------------------------------------------------------------
# output


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    md_path, fig_dir = output_paths(args)
    fig_dir.mkdir(parents=True, exist_ok=True)
    if args.quick:
        sizes = [10**4, 10**5]
        threshold_sizes = [10**3, 10**4]
        window = 0.3
        modes = ("offline cache off",)
    else:
        sizes = [10**4, 10**5, 10**6, 10**7]
        threshold_sizes = [10**3, 3 * 10**3, 10**4, 2 * 10**4, 5 * 10**4, 10**5]
        window = 2.0
        modes = ("offline cache off", "offline cache on, cold", "offline cache on, warm")
    variants = [Variant(0.2), Variant(0.0)]
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()

    bw_start = memory_bandwidth()
    log(f"NumPy copy bandwidth {bw_start['best']:.1f} GB/s (read + write)")

    def first_and_steady():
        model, state, integ = build(10**4, variants[0])
        a = clock()
        for _ in range(STEPS_PER_FRAME):
            integ.step(model, state, DT)
        b = clock()
        for _ in range(STEPS_PER_FRAME):
            integ.step(model, state, DT)
        return b - a, clock() - b

    comp = compile_times(first_and_steady, precision="f32", modes=modes)
    log("compile: " + ", ".join(f"{m}: {fmt_s(r['compile'])}" for m, r in comp.items()))

    reference = {}
    for n in sizes:
        reference[n] = taichi_stream_reference(n, window)
        log(
            f"plain Taichi kernel n={n:.0e}: {fmt_s(reference[n]['time'])} per launch, "
            f"{reference[n]['gbs']:.1f} GB/s"
        )

    threshold = serial_threshold(threshold_sizes, window)

    rows = []
    for v in variants:
        for n in sizes:
            tr = taichi_run(n, v, window)
            log(
                f"taichi n={n:.0e} jitter={v.jitter}: {tr['rate']:.3g} particle-steps/s, "
                f"emit {fmt_s(tr['emit_time'])}"
                f" + step {fmt_s(tr['kernel_time'])}"
            )
            nr = numpy_run(n, v, window)
            log(f"numpy  n={n:.0e} jitter={v.jitter}: {nr['rate']:.3g} particle-steps/s")
            pr = taichi_profile(n, v, steps=max(STEPS_PER_FRAME, min(100, tr["steps"])))
            log(
                f"profile n={n:.0e}: {pr['launches_per_step']:.2f} launches/step, "
                + ", ".join(f"{k} {e['ms_per_step']:.3g} ms" for k, e in pr["kernels"].items())
            )
            rows.append({"taichi": tr, "numpy": nr, "profile": pr})
    bw_end = memory_bandwidth()
    bw = max(bw_start["best"], bw_end["best"])
    total = time.perf_counter() - started
    load_end = load_average()
    log(f"NumPy copy bandwidth at the end {bw_end['best']:.1f} GB/s")

    def gbs(rate):
        return BYTES_PER_PARTICLE_STEP * rate / 1e9

    main_rows, split_rows, kernel_rows = [], [], []
    for r in rows:
        t, p, pr = r["taichi"], r["numpy"], r["profile"]
        ceiling = p["step_time"] / (BYTES_PER_PARTICLE_STEP * t["alive_mean"] / (bw * 1e9))
        main_rows.append(
            [
                f"{t['n']:.0e}",
                f"{t['jitter']:g}",
                f"{t['alive_mean'] / t['n']:.3f}",
                t["steps"],
                fmt_s(t["step_time"]),
                fmt_e(t["rate"], 3),
                fmt_s(p["step_time"]),
                fmt_e(p["rate"], 3),
                f"**{t['rate'] / p['rate']:.2f}x**",
                f"{ceiling:.1f}x",
                f"{gbs(t['rate']):.1f}",
                f"**{gbs(t['rate']) / bw:.2f}**",
            ]
        )
        k_rate = t["alive_mean"] / t["kernel_time"]
        split_rows.append(
            [
                f"{t['n']:.0e}",
                f"{t['jitter']:g}",
                t["split_steps"],
                fmt_s(t["emit_time"]),
                fmt_s(t["kernel_time"]),
                f"{t['emit_time'] / (t['emit_time'] + t['kernel_time']):.0%}",
                f"{t['found_per_step']:.0f} / {t['wanted_per_step']:.0f}",
                f"{gbs(k_rate):.1f}",
                f"{gbs(k_rate) / bw:.2f}",
                f"{fmt_s(reference[t['n']]['time'])} = {reference[t['n']]['gbs']:.1f} GB/s",
            ]
        )
        for name, e in pr["kernels"].items():
            kernel_rows.append(
                [
                    f"{t['n']:.0e}",
                    f"{t['jitter']:g}",
                    name,
                    f"{e['launches_per_step']:.2f}",
                    f"{e['ms_per_step']:.3g} ms",
                ]
            )
        kernel_rows.append(
            [
                f"{t['n']:.0e}",
                f"{t['jitter']:g}",
                "**all**",
                f"**{pr['launches_per_step']:.2f}**",
                f"{pr['total_kernel_time'] / pr['steps'] * 1e3:.3g} ms",
            ]
        )
    sanity_rows = [
        [
            f"{r['taichi']['n']:.0e}",
            f"{r['taichi']['jitter']:g}",
            f"{r['taichi']['alive_fraction']:.3f} / {r['numpy']['alive_fraction']:.3f}",
            f"{r['taichi']['mean_height']:.3f} / {r['numpy']['mean_height']:.3f}",
            f"{r['taichi']['mean_speed']:.3f} / {r['numpy']['mean_speed']:.3f}",
            f"{fmt_s(r['taichi']['fill_time'])} / {fmt_s(r['numpy']['fill_time'])}",
        ]
        for r in rows
    ]

    def at(n, jitter):
        return next((r for r in rows if r["taichi"]["n"] == n and r["taichi"]["jitter"] == jitter), None)

    goals = []
    main_v = variants[0].jitter
    for n in (10**6, 10**7):
        r = at(n, main_v)
        if r:
            ratio = r["taichi"]["rate"] / r["numpy"]["rate"]
            frac = gbs(r["taichi"]["rate"]) / bw
            goals.append(
                f"N = {n:.0e} (jitter {main_v:g}): Taichi/NumPy = {ratio:.2f}x (goal >= 10x: "
                f"{'met' if ratio >= 10 else 'MISSED'}); fraction of the streaming limit = {frac:.2f} "
                f"(goal >= 0.5: {'met' if frac >= 0.5 else 'MISSED'})"
            )
    small = at(10**4, main_v)
    small_prof = small["profile"] if small else None
    text = (
        "## Particles: throughput against NumPy\n\n"
        f"Regenerate: `{command_line(args, 'particles.py')}` (took {total / 60:.1f} min).\n\n"
        "Settings: float32 (`ta.init('cpu', precision='f32')`), one disc emitter of capacity N (radius "
        f"{RADIUS} m at {CENTER}, +y, speed {SPEED} m/s +-{SPEED_JITTER:.0%}, cone half-angle {SPREAD} rad), "
        f"lifetime {LIFETIME} s with lifetime_jitter 0.2 (main) or 0 (second variant), "
        f"rate = N / {LIFETIME} s "
        f"(pool full in steady state); gravity {GRAVITY} m/s²; container box {BOX_LO}..{BOX_HI} m (six "
        f"planes), restitution {RESTITUTION}, friction 0, collision mode projection; symplectic Euler, "
        f"dt = 1/{round(1 / DT)} s, `check_every` = {STEPS_PER_FRAME} (= steps per 60 Hz frame; the "
        "divergence counter is read once per frame). Each size runs in a fresh `ta.init`; the pool is filled "
        f"first ({variants[0].fill_steps} steps for jitter 0.2, {variants[1].fill_steps} for 0: every slot "
        "used and the first generation dead), then K steps are timed with `ti.sync()` before each clock "
        "read; particle-steps/s counts alive particles (mean of before and after). The NumPy peer "
        "(`NumpyParticles` in `benchmarks/particles.py`) does the same step vectorised (emission into dead "
        "slots found with `flatnonzero(death <= t)`, alive mask from death times, gravity, symplectic "
        "update and the six planes restricted to alive particles, float32, structure of arrays), in the same "
        "process, filled the same way. Bytes per particle-step of the Taichi step kernel: "
        f"{BYTES_PER_PARTICLE_STEP} B (x, v read + write 48 B, death time read 4 B: "
        "`taichi_anim/integrators/symplectic_euler.py` `_kernel` and `Model.alive`; mass, gravity and planes "
        "are compile-time constants). Streaming limit: NumPy copy of 512 MiB counted as read + write, "
        f"{bw_start['best']:.1f} GB/s at the start and {bw_end['best']:.1f} GB/s at the end of the run "
        f"(best of 5 each; the higher, {bw:.1f} GB/s, is used).\n\n"
        + machine_table(
            machine_info(), load_start=load_start, load_end=load_end, date=date, engine=engine, other=other
        )
        + "\n\n### Throughput\n\n"
        '"ceiling" = NumPy step time / (52 B x alive particles / copy bandwidth): the largest ratio a step '
        "moving only its 52 B per particle at the copy bandwidth could reach against this NumPy peer. "
        '"GB/s" = 52 B x Taichi particle-steps/s (whole step, emission included); "fraction" = that / '
        "copy bandwidth.\n\n"
        + md_table(
            [
                "N (capacity)",
                "lifetime jitter",
                "alive / N",
                "K steps",
                "Taichi per step",
                "Taichi particle-steps/s",
                "NumPy per step",
                "NumPy particle-steps/s",
                "Taichi / NumPy",
                "ceiling",
                "GB/s",
                "fraction of streaming limit",
            ],
            main_rows,
        )
        + "\n\n**Goals.** "
        + "; ".join(goals or ["(full run only: 10^6 and 10^7)"])
        + ".\n\n"
        + (
            f"Launch-bound regime (N = 10^4, jitter {main_v:g}): "
            f"{fmt_s(small['taichi']['step_time'])} per step "
            f"with {small_prof['launches_per_step']:.2f} kernel launches per step.\n\n"
            if small
            else ""
        )
        + "### Where the time goes\n\n"
        "Emission (`model.emit`: the emitter's serial free-slot search + the parallel spawn kernel) and "
        "the fused step kernel (`integ.advance_step`) timed apart, with `ti.sync()` between them (adds "
        "one sync per part). The "
        "reference is a minimal Taichi kernel moving the same 52 B per particle (gravity, symplectic "
        "update, alive check, no collisions; `taichi_stream_reference`): what a plain Taichi field kernel "
        "reaches here.\n\n"
        + md_table(
            [
                "N",
                "jitter",
                "steps",
                "emit per step",
                "step kernel per step",
                "emission share",
                "found / wanted per step",
                "step kernel GB/s",
                "step kernel fraction of streaming limit",
                "reference: plain Taichi kernel, same 52 B",
            ],
            split_rows,
        )
        + "\n\nKernel profiler (separate session, `ta.init(..., kernel_profiler=True)`; launches per step "
        "counted from each kernel's first task, times summed over its tasks):\n\n"
        + md_table(["N", "jitter", "kernel", "launches per step", "time per step"], kernel_rows)
        + "\n\nSanity check that both implementations simulate the same scene (Taichi / NumPy, end of run; "
        "different random streams, so the figures agree statistically, not exactly):\n\n"
        + md_table(
            [
                "N",
                "jitter",
                "alive / N",
                "mean height of alive [m]",
                "mean speed of alive [m/s]",
                "fill time (Taichi incl. compile)",
            ],
            sanity_rows,
        )
        + "\n\n### Serial threshold of the integrator loops\n\n"
        "Whole step per N in steady state (jitter 0.2) with the integrator's particle loop forced serial or "
        "parallel (`Model.serial`, set before the first step compiles); the engine runs it serially below "
        "`taichi_anim.runtime.CPU_SERIAL_BELOW` particles. The emitter's free-slot search is serial in "
        "both.\n\n"
        + (
            md_table(
                ["N", "serial per step", "parallel (2 threads) per step", "faster", "engine's choice"],
                [
                    [
                        f"{r['n']:.0e}",
                        fmt_s(r["serial"]),
                        fmt_s(r["parallel"]),
                        "serial" if r["serial"] < r["parallel"] else "parallel",
                        "serial" if r["default"] else "parallel",
                    ]
                    for r in threshold
                ],
            )
            if threshold
            else "(skipped: this engine version has no `Model.serial`)"
        )
        + "\n\n### JIT compile time (N = 10^4, first frame of 10 steps minus the second frame)\n\n"
        'Each in a fresh `ta.init`; "cold" uses an empty offline-cache folder, "warm" the same folder '
        "after re-initialising Taichi.\n\n"
        + md_table(COMPILE_HEADERS, compile_rows("particles, N = 1e4", comp))
        + "\n"
    )
    write_section(md_path, "particles", text)
    (fig_dir / "particles.json").write_text(
        json.dumps(
            {
                "rows": rows,
                "reference": reference,
                "serial_threshold": threshold,
                "bandwidth": [bw_start, bw_end],
                "compile": comp,
            },
            indent=1,
            default=str,
        )
    )
    plot(rows, bw, fig_dir / "particles.png")
    log(f"wrote {md_path} and {fig_dir}/particles.png in {total / 60:.1f} min")


def plot(rows, bw: float, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    for jitter, style in ((0.2, "-"), (0.0, "--")):
        sel = [r for r in rows if r["taichi"]["jitter"] == jitter]
        if not sel:
            continue
        ns = [r["taichi"]["n"] for r in sel]
        ax.plot(
            ns,
            [r["taichi"]["rate"] for r in sel],
            style,
            marker="o",
            color="C0",
            label=f"Taichi, whole step (jitter {jitter:g})",
        )
        ax.plot(
            ns,
            [r["taichi"]["alive_mean"] / r["taichi"]["kernel_time"] for r in sel],
            style,
            marker="^",
            color="C2",
            label=f"Taichi, step kernel alone (jitter {jitter:g})",
        )
        ax.plot(
            ns,
            [r["numpy"]["rate"] for r in sel],
            style,
            marker="s",
            color="C1",
            label=f"NumPy peer (jitter {jitter:g})",
        )
    ax.axhline(
        bw * 1e9 / BYTES_PER_PARTICLE_STEP,
        color="grey",
        lw=1,
        label=f"streaming limit: {bw:.0f} GB/s / {BYTES_PER_PARTICLE_STEP} B",
    )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("particles N (pool capacity)")
    ax.set_ylabel("particle-steps per second")
    ax.set_title("Emit + age + gravity + 6 planes, symplectic Euler, f32, 2-core CPU", fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
