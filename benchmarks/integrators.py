"""Speed against error for every integrator, on damped spring-mass systems that have a closed form.

Systems (precision f64, no gravity, no collisions):
  (a) one particle of mass m on the x axis, tied to an anchor at the origin by a damped spring of rest
      length L0, released at rest from x(0) = L0 + A;
  (b) 10^5 such particles, independent, with stiffnesses spread log-uniformly over [10, 10^4] N/m.

While the spring stays stretched along +x (A < L0, so |x| = x > 0) the anchor-spring force
f = -k (|x| - L0) n - c (v . n) n, n = x / |x|, is linear, m x'' = -k (x - L0) - c x', with the closed form

    x(t) = L0 + A exp(-zeta w t) [cos(w_d t) + (zeta w / w_d) sin(w_d t)],
    w = sqrt(k / m),  zeta = c / (2 sqrt(k m)) < 1,  w_d = w sqrt(1 - zeta^2),

which satisfies x(0) = L0 + A and x'(0) = 0.

Error metric: max over particles of |x_i(T) - x_exact_i(T)| (Euclidean) at T = 1 s. Cost: wall-clock time
per simulated second (ti.sync() before every clock read), measured after a warm-up step per integrator
(whose time, with the JIT compile in it, is reported apart). A run is "unstable" when its error exceeds the
amplitude A, "diverged" when a position is NaN/inf or the integrator raised DivergenceError; such runs are
kept in the tables and plotted as crosses at error = A.

Fixed-step methods run at dt = 1/30 ... 1/3840 s (powers of two); rk45 and adaptive(rk4) run at several
tolerances, with dt the outer (frame) step they subdivide. The NumPy peer runs the fixed-step methods with
the same formulas on the same systems in the same process.

    .venv/bin/python benchmarks/integrators.py           # full run (~7 min), writes benchmarks/RESULTS.md
    .venv/bin/python benchmarks/integrators.py --quick   # smoke run (~1 min), writes benchmarks/out/
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass

import numpy as np
from common import (
    COMPILE_HEADERS,
    OtherLoad,
    clock,
    command_line,
    compile_rows,
    compile_times,
    engine_fingerprint,
    fmt_dt,
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
    write_section,
)

import taichi_anim as ta

T_END = 1.0  # [s] time at which the error is measured
CHECK_EVERY = 10**9  # no divergence check inside the timed loop; checked once after it
MIN_RUN_TIME = 0.3  # [s] short runs are repeated (from the same initial state) up to this total ...
MAX_REPEATS = 5  # ... and this many times; the fastest repeat is reported


# ---------------------------------------------------------------------------------------------------------
# systems and their closed form


@dataclass(frozen=True)
class System:
    """n independent damped springs along x: stiffness k (n,) [N/m], damping c (n,) [kg/s], mass m [kg],
    rest length L0 [m], initial stretch A [m] (the amplitude)."""

    key: str
    title: str
    k: np.ndarray
    c: np.ndarray
    m: float
    rest: float
    amplitude: float

    @property
    def n(self) -> int:
        return len(self.k)

    def x0(self) -> np.ndarray:
        x = np.zeros((self.n, 3))
        x[:, 0] = self.rest + self.amplitude
        return x

    def exact(self, t: float) -> np.ndarray:
        """(n,3) closed-form positions at time t [s] (see the module docstring)."""
        w = np.sqrt(self.k / self.m)
        zeta = self.c / (2.0 * np.sqrt(self.k * self.m))
        wd = w * np.sqrt(1.0 - zeta**2)
        u = self.amplitude * np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta * w / wd * np.sin(wd * t))
        x = np.zeros((self.n, 3))
        x[:, 0] = self.rest + u
        return x

    def describe(self) -> str:
        w = np.sqrt(self.k / self.m)
        zeta = self.c / (2.0 * np.sqrt(self.k * self.m))
        return (
            f"{self.n} particle(s), m = {self.m:g} kg, L0 = {self.rest:g} m, A = {self.amplitude:g} m, "
            f"k = {self.k.min():.4g}..{self.k.max():.4g} N/m (w = {w.min():.3g}..{w.max():.3g} rad/s), "
            f"zeta = {zeta.min():.3g}..{zeta.max():.3g}, anchor at the origin, "
            "x(0) = (L0 + A, 0, 0), v(0) = 0"
        )


def single_system() -> System:
    k = (2.0 * math.pi * 2.0) ** 2  # 2 Hz with m = 1 kg
    zeta = 0.05
    return System(
        "single",
        "(a) one damped spring-mass particle",
        np.array([k]),
        np.array([2.0 * zeta * math.sqrt(k)]),
        1.0,
        1.0,
        0.5,
    )


def many_system(n: int) -> System:
    k = np.geomspace(10.0, 1.0e4, n)
    zeta = 0.05
    return System(
        "many", f"(b) {n:.0e} independent spring-mass particles", k, 2.0 * zeta * np.sqrt(k), 1.0, 1.0, 0.5
    )


def build(system: System):
    """The system through the public Builder API; returns (model, state, seconds spent adding springs)."""
    b = ta.Builder()
    b.add_particles(system.x0(), np.zeros((system.n, 3)), system.m)
    t0 = time.perf_counter()
    for i in range(system.n):
        b.add_force_anchor_spring(
            i, (0.0, 0.0, 0.0), stiffness=system.k[i], rest_length=system.rest, damping=system.c[i]
        )
    springs_s = time.perf_counter() - t0
    model = b.finalize(seed=0)
    return model, model.state(), springs_s


def reset(state, system: System, integ) -> None:
    """Back to t = 0 through the state's public fields; rk45 and adaptive carry their step size `h`
    from one step to the next, so it is cleared as in a new integrator (h_init=None)."""
    state.particle_x.from_numpy(system.x0())
    state.particle_v.from_numpy(np.zeros((system.n, 3)))
    state.time = 0.0
    state.step_count = 0
    state.nonfinite_count[None] = 0
    state.nonfinite_step[None] = 2**31 - 1
    if hasattr(integ, "h"):
        integ.h = None


# ---------------------------------------------------------------------------------------------------------
# integrator configurations


@dataclass(frozen=True)
class Config:
    label: str
    name: str
    options: tuple  # ((key, value), ...)
    adaptive: bool = False

    def make(self):
        return ta.make_integrator(self.name, check_every=CHECK_EVERY, **dict(self.options))


FIXED = ["explicit_euler", "symplectic_euler", "midpoint", "rk4", "implicit_euler"]


def configs(tolerances) -> list[Config]:
    out = [Config(n, n, ()) for n in FIXED]
    out += [Config(f"rk45 tol={t:.0e}", "rk45", (("rtol", t), ("atol", t)), True) for t in tolerances]
    out += [
        Config(f"adaptive(rk4) tol={t:.0e}", "adaptive", (("base", "rk4"), ("tol", t)), True)
        for t in tolerances
    ]
    return out


# ---------------------------------------------------------------------------------------------------------
# one run


def classify(err: float, system: System) -> str:
    if not math.isfinite(err):
        return "diverged"
    return "unstable" if err > system.amplitude else "ok"


def simulate(model, state, system: System, integ, dt: float) -> dict:
    """Integrate 0 -> T_END from the initial state; wall time of the fastest of up to MAX_REPEATS runs."""
    steps = round(T_END / dt)
    walls = []
    while True:
        reset(state, system, integ)
        ev0 = integ.evaluations
        acc0, rej0 = getattr(integ, "accepted", 0), getattr(integ, "rejected", 0)
        note = ""
        t0 = clock()
        try:
            for _ in range(steps):
                integ.step(model, state, dt)
            walls.append(clock() - t0)
            state.check_finite()
        except ta.DivergenceError as e:
            walls.append(clock() - t0)
            note = str(e).split(":")[0] + ": " + str(e).split(":", 1)[-1].strip()[:80]
        x = state.particle_x.to_numpy()
        err = float(np.max(np.linalg.norm(x - system.exact(steps * dt), axis=1)))
        status = "diverged" if note else classify(err, system)
        if status != "ok" or sum(walls) >= MIN_RUN_TIME or len(walls) >= MAX_REPEATS:
            break
    sim = steps * dt
    return {
        "dt": dt,
        "steps": steps,
        "repeats": len(walls),
        "wall": min(walls),
        "wall_per_sim_s": min(walls) / sim,
        "error": err,
        "status": status,
        "note": note,
        "evals_per_sim_s": (integ.evaluations - ev0) / sim,
        "accepted": getattr(integ, "accepted", 0) - acc0,
        "rejected": getattr(integ, "rejected", 0) - rej0,
        "x": x,
    }


WARM_STEPS = 10


def warm_up(model, state, system: System, integ, dt: float) -> dict:
    """The first WARM_STEPS steps from t = 0 (JIT compile, or loading from the offline cache, included),
    then the same steps again from t = 0: compile = first - second. Several steps, because rk45 and
    adaptive swap scratch fields between internal steps and each pairing of fields passed as
    `ti.template()` is a kernel of its own, compiled the first time that pairing occurs (see RESULTS.md)."""
    times = []
    for _ in range(2):
        reset(state, system, integ)
        t0 = clock()
        for _ in range(WARM_STEPS):
            integ.step(model, state, dt)
        state.check_finite()  # compiles the field reader used after the timed loop
        times.append(clock() - t0)
    return {"first": times[0], "steady": times[1]}


# ---------------------------------------------------------------------------------------------------------
# NumPy peer: the same formulas (see taichi_anim/forces/anchor_spring.py and the integrators)


class NumpySprings:
    """Anchor springs at the origin: f = -k (l - L0) n - c (v . n) n, with its Jacobian for implicit Euler."""

    def __init__(self, system: System):
        self.k = system.k
        self.c = system.c
        self.m = system.m
        self.rest = system.rest

    def _frame(self, x):
        length = np.sqrt(np.einsum("ij,ij->i", x, x))
        n = x / np.maximum(length, 1e-12)[:, None]
        return length, n

    def force(self, x, v):
        length, n = self._frame(x)
        s = -self.k * (length - self.rest) - self.c * np.einsum("ij,ij->i", v, n)
        return s[:, None] * n

    def accel(self, x, v):
        return self.force(x, v) / self.m

    def jacobian(self, x):
        length, n = self._frame(x)
        nn = n[:, :, None] * n[:, None, :]
        transverse = np.maximum(1.0 - self.rest / np.maximum(length, 1e-12), 0.0)
        eye = np.eye(3)[None]
        kx = -self.k[:, None, None] * (nn + transverse[:, None, None] * (eye - nn))
        kv = -self.c[:, None, None] * nn
        return kx, kv


def numpy_step(method: str, sp: NumpySprings, x, v, h):
    if method == "explicit_euler":
        return x + h * v, v + h * sp.accel(x, v)
    if method == "symplectic_euler":
        v1 = v + h * sp.accel(x, v)
        return x + h * v1, v1
    if method == "midpoint":
        xm = x + 0.5 * h * v
        vm = v + 0.5 * h * sp.accel(x, v)
        return x + h * vm, v + h * sp.accel(xm, vm)
    if method == "rk4":
        k1x, k1v = v, sp.accel(x, v)
        k2x = v + 0.5 * h * k1v
        k2v = sp.accel(x + 0.5 * h * k1x, k2x)
        k3x = v + 0.5 * h * k2v
        k3v = sp.accel(x + 0.5 * h * k2x, k3x)
        k4x = v + h * k3v
        k4v = sp.accel(x + h * k3x, k4x)
        return (
            x + h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x),
            v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v),
        )
    if method == "implicit_euler":
        # Baraff & Witkin (1998) eq. 6, per particle: (M - h df/dv - h^2 df/dx) dv = h (f0 + h df/dx v0).
        f = sp.force(x, v)
        kx, kv = sp.jacobian(x)
        a = sp.m * np.eye(3)[None] - h * kv - h * h * kx
        rhs = h * (f + h * np.einsum("nij,nj->ni", kx, v))
        v1 = v + np.linalg.solve(a, rhs[..., None])[..., 0]
        return x + h * v1, v1
    raise ValueError(method)


def numpy_simulate(method: str, system: System, dt: float) -> dict:
    sp = NumpySprings(system)
    steps = round(T_END / dt)
    walls = []
    with np.errstate(all="ignore"):
        while True:
            x, v = system.x0(), np.zeros((system.n, 3))
            t0 = time.perf_counter()
            for _ in range(steps):
                x, v = numpy_step(method, sp, x, v, dt)
            walls.append(time.perf_counter() - t0)
            if sum(walls) >= MIN_RUN_TIME or len(walls) >= MAX_REPEATS:
                break
        err = float(np.max(np.linalg.norm(x - system.exact(steps * dt), axis=1)))
    return {
        "dt": dt,
        "steps": steps,
        "wall": min(walls),
        "wall_per_sim_s": min(walls) / (steps * dt),
        "error": err,
        "status": classify(err, system),
        "x": x,
    }


# ---------------------------------------------------------------------------------------------------------
# sweeps


def sweep(system: System, cfgs: list[Config], dts, adaptive_dts, numpy_dts) -> dict:
    """All configurations at all their steps on one system, in one Taichi session, plus the NumPy peer."""
    init("f64")
    t0 = time.perf_counter()
    model, state, springs_s = build(system)
    build_s = time.perf_counter() - t0
    log(f"[{system.key}] built {system.n} particles in {build_s:.2f} s ({springs_s:.2f} s in springs)")
    runs, warm = [], {}
    for cfg in cfgs:
        integ = cfg.make()
        warm[cfg.label] = warm_up(model, state, system, integ, dts[0])
        for dt in adaptive_dts if cfg.adaptive else dts:
            r = simulate(model, state, system, integ, dt)
            r.update(label=cfg.label, method=cfg.name, adaptive=cfg.adaptive)
            runs.append(r)
            log(
                f"[{system.key}] {cfg.label:26s} dt={fmt_dt(dt):7s} err={fmt_e(r['error'], 3):>10s} "
                f"wall/sim-s={fmt_s(r['wall_per_sim_s']):>9s} {r['status']} {r['note']}"
            )
    peer = []
    for method in FIXED:
        for dt in numpy_dts:
            p = numpy_simulate(method, system, dt)
            ref = next(r for r in runs if r["label"] == method and r["dt"] == dt)
            with np.errstate(all="ignore"):
                p["diff_vs_taichi"] = float(np.max(np.abs(p["x"] - ref["x"])))
            p.update(method=method, taichi_wall_per_sim_s=ref["wall_per_sim_s"], taichi_error=ref["error"])
            peer.append(p)
            log(
                f"[{system.key}] numpy {method:18s} dt={fmt_dt(dt):7s} err={fmt_e(p['error'], 3):>10s} "
                f"wall/sim-s={fmt_s(p['wall_per_sim_s']):>9s} taichi/numpy speed-up "
                f"{p['wall_per_sim_s'] / ref['wall_per_sim_s']:.1f}x"
            )
    return {
        "system": system,
        "runs": runs,
        "warm": warm,
        "peer": peer,
        "build_s": build_s,
        "springs_s": springs_s,
    }


def compile_section(cfgs: list[Config], modes) -> tuple[dict, dict]:
    """Compile time of each integrator on system (a) at dt = 1/60 s, per offline-cache condition, and the
    time of each of the first WARM_STEPS steps in the first condition's session (a step after the first
    that takes far longer than the others is a compile in the middle of the run)."""
    system = single_system()
    out, per_step = {}, {}
    for cfg in cfgs:

        def first_and_steady(cfg=cfg):
            model, state, _ = build(system)
            integ = cfg.make()
            reset(state, system, integ)
            steps = []
            for _ in range(WARM_STEPS):
                t0 = clock()
                integ.step(model, state, 1.0 / 60.0)
                steps.append(clock() - t0)
            per_step.setdefault(cfg.label, steps)
            w = warm_up(model, state, system, integ, 1.0 / 60.0)  # compiled already: both runs are steady
            return sum(steps), w["steady"]

        out[cfg.label] = compile_times(first_and_steady, precision="f64", modes=modes)
        log(
            f"[compile] {cfg.label}: "
            + ", ".join(f"{m}: {fmt_s(r['compile'])}" for m, r in out[cfg.label].items())
            + " | per step: "
            + " ".join(fmt_s(t) for t in per_step[cfg.label])
        )
    return out, per_step


def stall_table(per_step: dict) -> str:
    rows = []
    for label, steps in per_step.items():
        later = steps[1:]
        k = int(np.argmax(later))
        rows.append(
            [label, fmt_s(steps[0]), f"{fmt_s(later[k])} (step {k + 2})", fmt_s(float(np.median(later)))]
        )
    return md_table(
        ["integrator", "step 1", f"slowest of steps 2..{WARM_STEPS}", f"median of steps 2..{WARM_STEPS}"],
        rows,
    )


# ---------------------------------------------------------------------------------------------------------
# output


def cell(r: dict) -> str:
    if r["status"] == "ok":
        return f"{fmt_e(r['error'])} / {fmt_s(r['wall_per_sim_s'])}"
    return f"**{r['status'].upper()}** ({fmt_e(r['error'])}) / {fmt_s(r['wall_per_sim_s'])}"


def pivot_table(res: dict, dts) -> str:
    labels = list(dict.fromkeys(r["label"] for r in res["runs"]))
    rows = []
    for label in labels:
        row = [label]
        for dt in dts:
            r = next((r for r in res["runs"] if r["label"] == label and r["dt"] == dt), None)
            row.append(cell(r) if r else "–")
        rows.append(row)
    return md_table(["integrator \\ dt [s]", *[fmt_dt(dt) for dt in dts]], rows)


def detail_table(res: dict) -> str:
    rows = []
    for r in res["runs"]:
        rows.append(
            [
                r["label"],
                fmt_dt(r["dt"]),
                r["steps"],
                r["repeats"],
                fmt_s(r["wall_per_sim_s"]),
                fmt_e(r["error"], 3),
                r["status"] + (f" ({r['note']})" if r["note"] else ""),
                f"{r['evals_per_sim_s']:.0f}",
                f"{r['accepted']}/{r['rejected']}" if r["adaptive"] else "–",
            ]
        )
    return md_table(
        [
            "integrator",
            "dt (outer)",
            "steps",
            "repeats",
            "wall per simulated s",
            "max \\|x - x_exact\\| [m]",
            "status",
            "force evals / particle / sim-s",
            "internal steps accepted/rejected",
        ],
        rows,
    )


def warm_table(res: dict) -> str:
    rows = [
        [label, fmt_s(w["first"]), fmt_s(w["steady"]), fmt_s(max(w["first"] - w["steady"], 0.0))]
        for label, w in res["warm"].items()
    ]
    return md_table(
        [
            "integrator",
            f"first {WARM_STEPS} steps (incl. compile)",
            "the same steps again",
            "difference (compile)",
        ],
        rows,
    )


def peer_table(res: dict) -> str:
    rows = []
    for p in res["peer"]:
        rows.append(
            [
                p["method"],
                fmt_dt(p["dt"]),
                fmt_s(p["taichi_wall_per_sim_s"]),
                fmt_s(p["wall_per_sim_s"]),
                f"{p['wall_per_sim_s'] / p['taichi_wall_per_sim_s']:.1f}x",
                fmt_e(p["taichi_error"], 3),
                fmt_e(p["error"], 3),
                fmt_e(p["diff_vs_taichi"], 2),
            ]
        )
    return md_table(
        [
            "integrator",
            "dt",
            "Taichi wall / sim-s",
            "NumPy wall / sim-s",
            "Taichi speed-up (NumPy / Taichi)",
            "Taichi error",
            "NumPy error",
            "max \\|x_taichi - x_numpy\\|",
        ],
        rows,
    )


def cheapest(res: dict, targets) -> list[tuple[float, dict | None, dict | None]]:
    ok = [r for r in res["runs"] if r["status"] == "ok"]
    out = []
    for target in targets:
        best = {}
        for r in ok:
            if r["error"] <= target and (r["label"] not in best or r["wall"] < best[r["label"]]["wall"]):
                best[r["label"]] = r
        ranked = sorted(best.values(), key=lambda r: r["wall_per_sim_s"])
        out.append((target, ranked[0] if ranked else None, ranked[1] if len(ranked) > 1 else None))
    return out


def reading(res: dict, targets) -> str:
    """The cheapest run per error target, and each fixed-step method's largest stable dt, in words."""
    rows = []
    for target, best, second in cheapest(res, targets):

        def desc(r):
            wall, err = fmt_s(r["wall_per_sim_s"]), fmt_e(r["error"])
            return f"{r['label']} at dt = {fmt_dt(r['dt'])} ({wall}, error {err})"

        rows.append(
            [f"≤ {target:.0e} m", desc(best) if best else "none reached it", desc(second) if second else "–"]
        )
    table = md_table(
        ["max error", "cheapest run (wall per simulated s)", "runner-up (another integrator)"], rows
    )
    limits = []
    for method in FIXED:
        ok = [r["dt"] for r in res["runs"] if r["label"] == method and r["status"] == "ok"]
        bad = [r["dt"] for r in res["runs"] if r["label"] == method and r["status"] != "ok"]
        limits.append(
            f"{method}: "
            + (f"stable up to dt = {fmt_dt(max(ok))}" if ok else "unstable at every dt")
            + (f", unstable/diverged at dt ≥ {fmt_dt(min(bad))}" if bad else "")
        )
    winners = [b["label"] for _, b, _ in cheapest(res, targets) if b]
    costs, orders = [], []
    for method in FIXED:
        ok = sorted(
            (r for r in res["runs"] if r["label"] == method and r["status"] == "ok"), key=lambda r: -r["dt"]
        )
        if ok:
            per_eval = np.median([r["wall_per_sim_s"] / r["evals_per_sim_s"] for r in ok])
            costs.append(f"{method} {fmt_s(per_eval)}")
        # Observed order: slope of log(error) against log(dt) over the stable runs whose error is well above
        # round-off (the smallest three such dt).
        fit = [r for r in ok if r["error"] > 1e-11][-3:]
        if len(fit) >= 2:
            slope = np.polyfit(np.log([r["dt"] for r in fit]), np.log([r["error"] for r in fit]), 1)[0]
            orders.append(f"{method} {slope:.1f}")
    text = (
        "**Reading.** The table above gives, for each error target, the run with the least wall time per "
        "simulated second that met it (each integrator at its best dt or tolerance) and the best run of "
        "another integrator. Cheapest over the targets, loosest first: "
        f"{', '.join(winners) if winners else 'none'}. "
        "Stability over the dt range: " + "; ".join(limits) + ". "
        "Observed order (slope of log error against log dt over the three smallest stable dt): "
        + (", ".join(orders) or "–")
        + ". Wall time per force evaluation (median over stable runs): "
        + (", ".join(costs) or "–")
        + ". Cost per evaluation is close to equal across explicit methods, so "
        "the cheapest method for a given error is the one whose order and stability let it take the largest "
        "step; rk45 and adaptive(rk4) add an error estimate (one extra stage and a read-back per internal "
        "step for rk45, three base steps per accepted step for step doubling), and a small outer dt caps "
        "their internal step and only adds cost. The error at a single instant can dip where the phase error "
        "changes sign (a point below its neighbours' trend), so read trends rather than single points."
    )
    return table + "\n\n" + text


def plot(res: dict, path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    system = res["system"]
    fig, ax = plt.subplots(figsize=(9, 6.5))
    labels = list(dict.fromkeys(r["label"] for r in res["runs"]))
    palette = [*plt.get_cmap("tab10").colors, (0.0, 0.0, 0.0)]
    for j, label in enumerate(labels):
        runs = [r for r in res["runs"] if r["label"] == label]
        ok = [r for r in runs if r["status"] == "ok"]
        bad = [r for r in runs if r["status"] != "ok"]
        adaptive = runs[0]["adaptive"]
        color = palette[j % len(palette)]
        ax.plot(
            [r["wall_per_sim_s"] for r in ok],
            [max(r["error"], 1e-16) for r in ok],
            "--" if adaptive else "-",
            marker="s" if adaptive else "o",
            ms=4,
            color=color,
            label=label,
        )
        if bad:
            ax.plot(
                [r["wall_per_sim_s"] for r in bad],
                [system.amplitude] * len(bad),
                "x",
                ms=8,
                mew=2,
                color=color,
            )
    labelled = False
    for method in FIXED:
        peer = sorted(
            (p for p in res["peer"] if p["method"] == method and p["status"] == "ok"), key=lambda p: p["dt"]
        )
        if peer:
            ax.plot(
                [p["wall_per_sim_s"] for p in peer],
                [max(p["error"], 1e-16) for p in peer],
                ":",
                marker="o",
                mfc="none",
                ms=5,
                color=palette[labels.index(method) % len(palette)],
                alpha=0.7,
                label="_" if labelled else "NumPy " + method,
            )
            labelled = True
    ax.axhline(system.amplitude, color="grey", lw=0.8, label="amplitude A (error above it: unstable)")
    ax.plot([], [], "x", color="grey", ms=8, mew=2, label="unstable / diverged run (drawn at A)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time per simulated second [s] (2-core CPU, Taichi f64)")
    ax.set_ylabel("max position error at T = 1 s [m]")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    handles, names = ax.get_legend_handles_labels()
    names = [n if not n.startswith("NumPy ") else "NumPy peer (dotted, hollow; same colours)" for n in names]
    ax.legend(handles, names, fontsize=7, ncol=2, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def json_ready(res: dict) -> dict:
    s = res["system"]
    strip = [{k: v for k, v in r.items() if k != "x"} for r in res["runs"]]
    peer = [{k: v for k, v in p.items() if k != "x"} for p in res["peer"]]
    return {
        "system": s.describe(),
        "runs": strip,
        "warm": res["warm"],
        "peer": peer,
        "build_s": res["build_s"],
    }


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    md_path, fig_dir = output_paths(args)
    fig_dir.mkdir(parents=True, exist_ok=True)
    if args.quick:
        dts = [1 / 30, 1 / 120, 1 / 480]
        adaptive_dts = [1 / 30]
        numpy_dts = [1 / 30, 1 / 120]
        tolerances = [1e-4, 1e-8]
        n_many = 10**4
        modes = ("offline cache off",)
    else:
        dts = [1 / (30 * 2**k) for k in range(8)]  # 1/30 ... 1/3840
        adaptive_dts = [1 / 30, 1 / 240, 1 / 1920]
        numpy_dts = [1 / 30, 1 / 120, 1 / 480]
        tolerances = [1e-4, 1e-6, 1e-8]
        n_many = 10**5
        modes = ("offline cache off", "offline cache on, cold", "offline cache on, warm")
    cfgs = configs(tolerances)
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()

    comp, per_step = compile_section(
        [c for c in cfgs if not c.adaptive]
        + [
            Config("rk45 tol=1e-06", "rk45", (("rtol", 1e-6), ("atol", 1e-6)), True),
            Config("adaptive(rk4) tol=1e-06", "adaptive", (("base", "rk4"), ("tol", 1e-6)), True),
        ],
        modes,
    )
    results = [
        sweep(single_system(), cfgs, dts, adaptive_dts, numpy_dts),
        sweep(many_system(n_many), cfgs, dts, adaptive_dts, numpy_dts),
    ]
    total = time.perf_counter() - started
    load_end = load_average()

    sections = []
    for res in results:
        s = res["system"]
        png = fig_dir / f"integrators_{s.key}.png"
        plot(res, png, f"{s.title}: error at T = 1 s vs cost, dt = {fmt_dt(dts[0])}..{fmt_dt(dts[-1])} s")
        rel = png.relative_to(md_path.parent) if png.is_relative_to(md_path.parent) else png
        targets = [1e-2, 1e-4, 1e-6, 1e-8] + ([1e-10] if s.n == 1 else [])
        sections.append(
            f"### {s.title}\n\n{s.describe()}. "
            f"Model built in {res['build_s']:.2f} s through the public Builder API "
            f"({res['springs_s']:.2f} s of it in `add_force_anchor_spring`).\n\n"
            f"![{s.key}]({rel.as_posix()})\n\n"
            "Each cell: max position error at T = 1 s [m] / wall time per simulated second. "
            "UNSTABLE: error > A; DIVERGED: NaN/inf or DivergenceError (the error shown is what was left). "
            "rk45 uses rtol = atol = tol on (x, v); adaptive(rk4) is step doubling with the max-norm "
            "tolerance tol; for both, dt is the outer step and they subdivide it.\n\n"
            f"{pivot_table(res, dts)}\n\n{reading(res, targets)}\n\n"
            f"First {WARM_STEPS} steps of each integrator in this session (JIT compile or offline-cache "
            f"load included), then the same steps again from t = 0; dt = {fmt_dt(dts[0])}:\n\n"
            f"{warm_table(res)}\n\n"
            "NumPy peer (same formulas, vectorised over particles, float64, same process):\n\n"
            f"{peer_table(res)}\n\n"
            f"<details><summary>every run</summary>\n\n{detail_table(res)}\n\n</details>\n"
        )
        (fig_dir / f"integrators_{s.key}.json").write_text(json.dumps(json_ready(res), indent=1, default=str))

    comp_rows = [row for label, r in comp.items() for row in compile_rows(label, r)]
    text = (
        "## Integrators: speed against error\n\n"
        f"Regenerate: `{command_line(args, 'integrators.py')}` (took {total / 60:.1f} min).\n\n"
        "Settings: precision f64; error metric max over particles of \\|x(T) - x_exact(T)\\| at T = 1 s "
        "against "
        "the closed form x(t) = L0 + A e^(-zeta w t) [cos(w_d t) + (zeta w / w_d) sin(w_d t)] "
        "(see the docstring of `benchmarks/integrators.py`); no gravity, no colliders. "
        f"Fixed-step dt = {', '.join(fmt_dt(d) for d in dts)} s; rk45 and adaptive(rk4) at tol = "
        f"{', '.join(f'{t:.0e}' for t in tolerances)} with outer dt = "
        f"{', '.join(fmt_dt(d) for d in adaptive_dts)} s. "
        f"Wall time: `ti.sync()` before each clock read; the divergence check (`check_every`={CHECK_EVERY}) "
        "runs once after the timed loop, not per step; runs shorter than "
        f"{MIN_RUN_TIME} s are repeated from the initial state up to {MAX_REPEATS} times and the fastest "
        "is kept. Each integrator object is built once per system and reused across dt (state reset through "
        "its fields, `h` cleared), so the JIT compile falls in its warm-up step, reported apart. "
        "The NumPy peer runs the five fixed-step methods with the same force and update formulas "
        f"at dt = {', '.join(fmt_dt(d) for d in numpy_dts)} s.\n\n"
        + machine_table(
            machine_info(), load_start=load_start, load_end=load_end, date=date, engine=engine, other=other
        )
        + "\n\n"
        + "\n".join(sections)
        + "\n### JIT compile time\n\n"
        f"System (a), dt = 1/60 s: the first {WARM_STEPS} steps in a fresh `ta.init` minus the same "
        f'{WARM_STEPS} steps run again from t = 0 in that session. "cold" uses an empty offline-cache '
        'folder, "warm" the same folder after re-initialising Taichi.\n\n'
        + md_table(COMPILE_HEADERS, comp_rows)
        + "\n\nTime of each of those first steps (offline cache off): a later step far slower than the "
        "median is a kernel compiled in the middle of the run. rk45 and adaptive swap scratch fields "
        "between internal steps and pass them as `ti.template()` arguments, so each pairing of fields is a "
        "kernel of its own, compiled the first time that pairing occurs.\n\n" + stall_table(per_step) + "\n"
    )
    write_section(md_path, "integrators", text)
    log(f"wrote {md_path} and {fig_dir}/integrators_*.png in {total / 60:.1f} min")


if __name__ == "__main__":
    main()
