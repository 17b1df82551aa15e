"""Springs against membrane + bending on the same fabric: speed against error, distance from the continuum
answer, implicit steps/s at frame-size steps, and Newton's semi-implicit triangle FEM as a peer.

Scene (parts 1 and 3): a square cloth of side 1 m, n x n vertices (`Builder.add_cloth_grid`, plane "xz",
origin (0, 1, 0): flat, horizontal, at rest), areal density 0.2 kg/m^2 lumped by triangle area, gravity
(0, -9.81, 0) m/s^2, the whole edge j = 0 pinned (vertices 0 ... n-1), no colliders, no drag. It swings
down about that edge, passing the vertical near t = 0.45 s. The edge rather than two corners: with two
corners pinned the sheet compresses between the pins and buckles, and no affordable reference converges
(benchmarks/cloth_solvers.py, "Why not two corners"). Two models of one fabric, same stretch stiffness:
- springs: `ClothMaterial()` defaults (Provot's springs; stretch 1e3 N/m, shear 1e2, bend 10; damping
  0.05, 0.01, 0.005 kg/s along the springs; stretch beta = c / k = 5e-5 s);
- membrane: `FabricMaterial` = the demos' `scenes.cloth.FABRIC` (StVK membrane E = 1e3 N/m areal, nu = 0.3,
  dihedral bending D = 5e-5 N m, bending damping 1e-2 s) with its Rayleigh damping set to the springs'
  stretch beta, 5e-5 s, instead of FabricMaterial's default 1e-3 s. Why: with 1e-3 s the damping of the
  highest membrane modes (zeta = beta omega / 2 ~ 3 at 32^2) caps an explicit step near 4e-5 s whatever
  the stiffness (measured below, "Default membrane damping"), so an explicit comparison would measure the
  damping constant, not the model; and on finer meshes that cap falls like the cell squared, which makes
  a fine-mesh reference unaffordable. Matching beta gives both models the same damping of stretching.

Part 1, speed against error (32^2, T = 0.5 s, float64). For each model: a converged reference of THAT
model (RK4 at dt = 5e-5 s, checked against RK4 at 1e-4 s: RK4's error falls ~16x per halving, so the
reference's own error is ~1/15 of that difference); symplectic Euler at dt = 1/20000, 1/10000, 1/5000,
1/4000, 1/3000 ... s in that order until a run fails (non-finite, a vertex above 50 m/s, or the engine's
divergence error); implicit Euler (linearised
backward Euler, block-Jacobi PCG, warm start, max 1000 iterations) at dt = 1/60 ... 1/960 s and relative
residual tol 1e-4 and 1e-6. Error: max and RMS over the free vertices of |x(T) - x_ref(T)| [m], against
wall time per simulated second (`ti.sync()` before every clock read, positions read back 5 times per run
outside the timed segments; runs under 0.3 s repeated, fastest kept; each integrator warmed up first, the
compile reported apart). The continuum answer: the membrane on 2x and 3x refined meshes (63^2 and 94^2
vertices, so every coarse vertex is a fine vertex: sampled, not interpolated), RK4 at dt = 1e-4 s and
1/15000 s (the same dt / cell; the 63^2 run repeated at half its step shows what the step contributes).
Not 125^2: its RK4 run (dt = 5e-5 s, stable) took 152 s in f32 on this shared machine during
development, a third of the budget of the whole benchmark. Every model's converged 32^2 answer, the 63^2
membrane and springs on the 63^2 mesh are measured against the 94^2 membrane at the coarse material
points; every run of the sweep too (second plot panel): how far its
cloth is from the continuum answer per unit of wall time.

Part 2, implicit steps/s at dt = 1/60 s (float32, Taichi's default threads): membrane and springs at
64^2 and 128^2, the same fabric pinned at the two corners of one edge (the demos' and
benchmarks/cloth_implicit.py's layout; one step per frame), PCG at tol 1e-3 and 1e-4 (max 1000
iterations, warm start, check_every 10). One integrator per model and size: its first step (JIT compile
included) and a second step timed apart; each tol then resets the state in place (no recompile) and times
60 steps one by one; runs past RUN_BUDGET_S of timed steps are cut. Iterations per step: mean, max,
steps that reached the cap. Compile: first step minus second step, with Taichi's offline cache as the
machine has it (each model and size is a new compile: the kernels are specialised on the model's fields);
the three cache conditions of common.compile_times are not measured here (about a minute more, mostly
the membrane's implicit step, ~20-25 s per cold compile).

Part 3, Newton (`benchmarks/peers/newton_fem.py`): the part-1 scene (membrane, 32^2, edge pinned),
Newton's `SolverSemiImplicit` with triangle FEM + edge bending on the CPU (`wp.set_device("cpu")`, one
thread), same vertices, triangles, masses, pins, gravity, frame 1/60 s x NEWTON_SUBSTEPS symplectic steps,
T = 0.5 s (30 frames, positions copied to NumPy each frame), against taichi_anim's symplectic Euler on the
same scene at the same dt in float32 (Newton is float32), in the same process. Parameter mapping in the
peer's docstring (tri_ke = mu_L, tri_ka = lambda_L + mu_L, edge_ke = D / a^3, tri_kd = 2 beta mu_L,
edge_kd = beta_b edge_ke / a^2); Newton runs with that damping and with none. Checks of the mapping:
accelerations of both engines at the same perturbed positions (an in-plane displacement of the membrane
cloths; an out-of-plane bump of bending-only cloths, each minus its acceleration at rest), and the NumPy
check of the linearised energy. Our membrane also runs undamped, the counterpart of Newton's undamped
run. Reported: ms per frame (first frame with the cold compile apart: Warp's kernel cache in a fresh
folder), CPU cores busy, and the final shape against our runs (same dt, f32) and against the converged
f64 membrane reference.

    .venv/bin/python benchmarks/cloth_continuum_speed.py          # full run (~8 min), benchmarks/results/
    .venv/bin/python benchmarks/cloth_continuum_speed.py --quick  # smoke run (~2 min), benchmarks/out/
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass

import numpy as np
from common import (
    OtherLoad,
    clock,
    command_line,
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
)

import taichi_anim as ta
from taichi_anim.scenes.cloth import FABRIC

GRAVITY = 9.81  # [m/s^2]
SIDE = 1.0  # [m]
HEIGHT = 1.0  # [m] the cloth starts in the plane y = HEIGHT
FRAME = 1.0 / 60.0  # [s]
SPRINGS = ta.ClothMaterial()
BETA = SPRINGS.stretch_damping / SPRINGS.stretch_stiffness  # [s] 5e-5
MEMBRANE = dataclasses.replace(FABRIC, damping=BETA)
MATERIALS = {"springs": SPRINGS, "membrane": MEMBRANE}
CHECK_EVERY = 10**9  # the divergence counter is read only where the benchmark reads positions
MAX_SPEED = 50.0  # [m/s]
SNAPSHOTS = 5
WARM_STEPS = 3
MIN_RUN_TIME = 0.3  # [s]
MAX_REPEATS = 3
IMPLICIT_MAX_ITERATIONS = 1000
STEPS2_CHECK_EVERY = 10
RUN_BUDGET_S = 15.0  # [s] of timed steps per part-2 run at most
IN_PLANE, OUT_OF_PLANE = "in-plane (membrane)", "out-of-plane (bending only)"
FORCE_AMPLITUDE = {IN_PLANE: 1e-3, OUT_OF_PLANE: 1e-2}  # [m]
LOADED_CORES = 0.1


@dataclass(frozen=True)
class Settings:
    n: int
    t_end: float
    ref_dt: float  # RK4 reference step (checked at 2 ref_dt)
    sym_dts: tuple  # symplectic Euler steps, tried in order until one fails
    implicit_dts: tuple
    implicit_tols: tuple
    refine: tuple  # (factor, RK4 dt) of the membrane on refined meshes; the last is the continuum answer
    refine_check: int  # this factor runs again at half its dt
    springs_refine: tuple  # (factor, RK4 dt) of springs on a refined mesh
    sizes2: tuple
    tols2: tuple
    steps2: int
    newton_substeps: int


FULL = Settings(
    n=32,
    t_end=0.5,
    ref_dt=5e-5,
    sym_dts=tuple(1.0 / k for k in (20000, 10000, 5000, 4000, 3000, 2500, 2000, 1000)),
    implicit_dts=(1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 960),
    implicit_tols=(1e-4, 1e-6),
    refine=((2, 1e-4), (3, 1.0 / 15000)),
    refine_check=2,
    springs_refine=((2, 1e-4),),
    sizes2=(64, 128),
    tols2=(1e-3, 1e-4),
    steps2=60,
    newton_substeps=128,
)
QUICK = Settings(
    n=8,
    t_end=0.1,
    ref_dt=1e-4,
    sym_dts=tuple(1.0 / k for k in (10000, 5000, 2500, 1000, 500)),
    implicit_dts=(1 / 60, 1 / 120),
    implicit_tols=(1e-4,),
    refine=((2, 1e-4),),
    refine_check=0,
    springs_refine=(),
    sizes2=(16,),
    tols2=(1e-3, 1e-4),
    steps2=10,
    newton_substeps=32,
)


# ---------------------------------------------------------------------------------------------------------
# scene


def material_text(name: str) -> str:
    m = MATERIALS[name]
    if name == "springs":
        return (
            "ClothMaterial() defaults: springs stretch/shear/bend "
            f"{m.stretch_stiffness:g}/{m.shear_stiffness:g}/{m.bend_stiffness:g} N/m, damping "
            f"{m.stretch_damping:g}/{m.shear_damping:g}/{m.bend_damping:g} kg/s"
        )
    return (
        f"FabricMaterial (scenes.cloth.FABRIC with damping = {m.damping:g} s): StVK membrane E = "
        f"{m.youngs_modulus:g} N/m, nu = {m.poisson_ratio:g}, Rayleigh damping {m.damping:g} s; dihedral "
        f"bending D = {m.bending_stiffness:g} N m, damping {m.bending_damping:g} s"
    )


class Sheet:
    """A built cloth: model, one reusable state, initial positions, masses, free vertices, triangles."""

    def __init__(self, material, n: int, pins: str = "edge"):
        self.n = n
        b = ta.Builder()
        pinned = list(range(n)) if pins == "edge" else [0, n - 1]
        handle = b.add_cloth_grid(
            origin=(0.0, HEIGHT, 0.0),
            size=(SIDE, SIDE),
            resolution=(n, n),
            plane="xz",
            material=material,
            thickness=0.005,
            pinned=pinned,
        )
        b.add_force_gravity((0.0, -GRAVITY, 0.0))
        self.model = b.finalize(seed=0)
        self.state = self.model.state()
        x0 = self.state.particle_x.to_numpy()
        self.dtype = x0.dtype
        self.x0 = x0.astype(np.float64)
        m = self.model.particle_mass
        self.mass = (
            m.to_numpy().astype(np.float64)
            if m is not None
            else np.full(len(x0), self.model.uniform_mass, dtype=np.float64)
        )
        self.free = self.mass > 0.0
        self.triangles = np.asarray(handle.triangles)
        self.pinned = np.asarray(handle.pinned)

    def set(self, integ, x: np.ndarray, v: np.ndarray) -> None:
        st = self.state
        st.particle_x.from_numpy(np.asarray(x, dtype=self.dtype))
        st.particle_v.from_numpy(np.asarray(v, dtype=self.dtype))
        st.time = 0.0
        st.step_count = 0
        st.nonfinite_count[None] = 0
        st.nonfinite_step[None] = 2**31 - 1
        if getattr(integ, "system", None) is not None:
            integ.system.solution.fill(0.0)

    def reset(self, integ) -> None:
        self.set(integ, self.x0, np.zeros_like(self.x0))

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        return (
            self.state.particle_x.to_numpy().astype(np.float64),
            self.state.particle_v.to_numpy().astype(np.float64),
        )


def worst_vertex(x: np.ndarray, ref: np.ndarray, free: np.ndarray, n: int) -> str:
    """Grid vertex (i, j) of the largest |x - ref| among free vertices (j = 0: the pinned edge)."""
    d = np.where(free, np.linalg.norm(x - ref, axis=1), -1.0)
    k = int(np.argmax(d))
    return f"({k % n}, {k // n})"


def coarse_index(n: int, factor: int) -> np.ndarray:
    """Indices, on the (n-1) factor + 1 grid, of the n x n grid's vertices (row-major j n + i)."""
    nf = (n - 1) * factor + 1
    j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return (factor * j * nf + factor * i).ravel()


def errors(x: np.ndarray, ref: np.ndarray, free: np.ndarray) -> tuple[float, float]:
    """(max, RMS) over free vertices of |x - ref| [m]; NaN if not finite."""
    with np.errstate(all="ignore"):
        e = np.linalg.norm(x[free] - ref[free], axis=1)
    if not np.all(np.isfinite(e)):
        return float("nan"), float("nan")
    return float(e.max()), float(np.sqrt(np.mean(e**2)))


# ---------------------------------------------------------------------------------------------------------
# runs


def warm_up(sheet: Sheet, integ, dt: float) -> dict:
    """WARM_STEPS steps (JIT compile included), then the same again: compile = difference."""
    times = []
    for _ in range(2):
        sheet.reset(integ)
        t0 = clock()
        for _ in range(WARM_STEPS):
            integ.step(sheet.model, sheet.state, dt)
        times.append(clock() - t0)
    return {"first": times[0], "steady": times[1], "compile": max(times[0] - times[1], 0.0)}


def simulate(sheet: Sheet, integ, dt: float, t_end: float, *, implicit: bool = False) -> dict:
    """0 -> t_end from rest; positions read SNAPSHOTS times outside the timed segments; stops at the
    first non-finite value, vertex speed above MAX_SPEED or divergence error."""
    steps = round(t_end / dt)
    if abs(steps * dt - t_end) > 1e-9 * t_end:
        raise ValueError(f"t_end = {t_end} is not a whole number of steps of {dt}")
    seg = max(steps // SNAPSHOTS, 1)
    walls: list[float] = []
    while True:
        sheet.reset(integ)
        its: list[int] = []
        status, note, wall, done = "ok", "", 0.0, 0
        x = sheet.x0
        while done < steps:
            k = min(seg, steps - done)
            t0 = clock()
            try:
                for _ in range(k):
                    integ.step(sheet.model, sheet.state, dt)
                    if implicit:
                        its.append(int(integ.last_solve.iterations))
                wall += clock() - t0
                sheet.state.check_finite()
            except ta.DivergenceError as e:
                wall += clock() - t0
                status, note = "diverged", str(e).split(":")[0][:60]
            done += k
            x, v = sheet.read()
            if status == "ok" and not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
                status, note = "diverged", "non-finite positions"
            elif status == "ok" and float(np.max(np.linalg.norm(v, axis=1))) > MAX_SPEED:
                status, note = "unstable", f"speed > {MAX_SPEED:g} m/s at t = {done * dt:.3g} s"
            if status != "ok":
                break
        walls.append(wall)
        if status != "ok" or sum(walls) >= MIN_RUN_TIME or len(walls) >= MAX_REPEATS:
            break
    out = {
        "dt": dt,
        "steps": steps,
        "steps_run": done,
        "status": status,
        "note": note,
        "x": x,
        "wall": min(walls),
        "repeats": len(walls),
        "wall_per_sim_s": min(walls) / max(done * dt, 1e-300),
    }
    if implicit and its:
        a = np.asarray(its)
        out.update(iter_mean=float(a.mean()), iter_max=int(a.max()))
    return out


def rk4_run(sheet: Sheet, dt: float, t_end: float) -> dict:
    """RK4 from rest to t_end; one integrator per sheet (warmed up, compile apart, on first use)."""
    integ = getattr(sheet, "rk4", None)
    warm = None
    if integ is None:
        integ = sheet.rk4 = ta.make_integrator("rk4", check_every=CHECK_EVERY)
        warm = warm_up(sheet, integ, dt)
    r = simulate(sheet, integ, dt, t_end)
    r["warm"] = warm
    if r["status"] != "ok":
        raise RuntimeError(f"RK4 reference at dt = {dt:g} on {sheet.n}² failed: {r['note']}")
    return r


def reference(sheet: Sheet, s: Settings, name: str) -> dict:
    """RK4 at ref_dt (the reference) and 2 ref_dt (its check)."""
    fine = rk4_run(sheet, s.ref_dt, s.t_end)
    coarse = rk4_run(sheet, 2 * s.ref_dt, s.t_end)
    dmax, drms = errors(coarse["x"], fine["x"], sheet.free)
    disp = float(np.max(np.linalg.norm(fine["x"] - sheet.x0, axis=1)))
    log(
        f"[reference] {name} RK4 dt={s.ref_dt:g}: {fine['wall']:.1f} s; |x(2dt) - x(dt)| max {dmax:.2e} "
        f"rms {drms:.2e}; largest displacement {disp:.3f} m"
    )
    return {
        "x": fine["x"],
        "dt": s.ref_dt,
        "diff_max": dmax,
        "diff_rms": drms,
        "wall": fine["wall"] + coarse["wall"],
        "max_displacement": disp,
        "warm": fine["warm"],
    }


def sweep(sheet: Sheet, s: Settings, name: str, ref: dict) -> tuple[list, dict]:
    rows: list = []
    warm: dict = {}
    integ = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY)
    warm["symplectic_euler"] = warm_up(sheet, integ, s.sym_dts[0])
    for dt in s.sym_dts:
        r = simulate(sheet, integ, dt, s.t_end)
        rows.append(record(name, "symplectic Euler", None, r, sheet, ref))
        if r["status"] != "ok":
            break
    integ = ta.IntegratorImplicitEuler(
        linear_solver="pcg",
        tol=s.implicit_tols[0],
        max_iterations=IMPLICIT_MAX_ITERATIONS,
        warm_start=True,
        check_every=CHECK_EVERY,
    )
    warm["implicit Euler (PCG)"] = warm_up(sheet, integ, s.implicit_dts[0])
    for tol in s.implicit_tols:
        integ.linear_solver.tol = tol  # a kernel argument: no recompile
        for dt in s.implicit_dts:
            r = simulate(sheet, integ, dt, s.t_end, implicit=True)
            rows.append(record(name, "implicit Euler (PCG)", tol, r, sheet, ref))
    return rows, warm


def record(model: str, method: str, tol, r: dict, sheet: Sheet, ref: dict) -> dict:
    emax, erms = errors(r["x"], ref["x"], sheet.free) if r["status"] == "ok" else (math.nan, math.nan)
    row = {k: v for k, v in r.items() if k != "x"}
    row.update(model=model, method=method, tol=tol, err_max=emax, err_rms=erms, x=r["x"])
    its = f" its {r['iter_mean']:.1f}/{r['iter_max']}" if "iter_mean" in r else ""
    log(
        f"[speed] {model:8s} {method:20s} dt={fmt_dt(r['dt']):>8s} tol={tol or '':<6} "
        f"err={fmt_e(emax, 3):>9s} wall/sim-s={fmt_s(r['wall_per_sim_s']):>9s} {r['status']}{its} {r['note']}"
    )
    return row


def damping_note(s: Settings) -> dict:
    """Largest stable symplectic-Euler dt (doubling from half the sweep's first dt) of the membrane with
    FabricMaterial's
    default damping (FABRIC), against the matched-damping membrane of part 1 (its sweep rows)."""
    sheet = Sheet(FABRIC, s.n)
    integ = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY)
    dt = s.sym_dts[0] / 2
    warm_up(sheet, integ, dt)
    tried = []
    while dt <= 32 * s.sym_dts[0]:
        r = simulate(sheet, integ, dt, s.t_end)
        tried.append({"dt": dt, "status": r["status"], "note": r["note"]})
        log(f"[default damping] FABRIC symplectic dt={dt:g}: {r['status']} {r['note']}")
        if r["status"] != "ok":
            break
        dt *= 2.0
    return {"damping": FABRIC.damping, "bending_damping": FABRIC.bending_damping, "tried": tried}


def accelerations_ours(sheet: Sheet, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """f(x, v) / m of the engine (gravity removed), from one explicit Euler step of dt = 1 s."""
    integ = ta.make_integrator("explicit_euler", check_every=CHECK_EVERY)
    sheet.set(integ, x, v)
    integ.step(sheet.model, sheet.state, 1.0)
    a = sheet.state.particle_v.to_numpy().astype(np.float64) - v
    a[:, 1] += GRAVITY
    sheet.reset(integ)
    return a


def force_configs(x0: np.ndarray) -> dict:
    """Perturbed positions for the mapping check, zero at the pinned edge: an in-plane displacement (the
    membrane's forces; bending stays flat) and an out-of-plane one (for the bending-only cloths: with a
    membrane, f32 round-off of Newton's membrane forces, ~0.5 m/s² per vertex at 32², would swamp the
    bending forces of any out-of-plane displacement small enough to keep the membrane's own part
    negligible)."""
    u, w = x0[:, 0] / SIDE, x0[:, 2] / SIDE
    out = {}
    a = FORCE_AMPLITUDE[IN_PLANE]
    d = np.zeros_like(x0)
    d[:, 0] = a * np.sin(math.pi * w) * np.cos(2 * math.pi * u)
    d[:, 2] = a * np.sin(math.pi * w) * np.sin(math.pi * u)
    out[IN_PLANE] = x0 + d
    a = FORCE_AMPLITUDE[OUT_OF_PLANE]
    d = np.zeros_like(x0)
    d[:, 1] = a * np.sin(1.5 * math.pi * w) * np.sin(1.5 * math.pi * u) * w
    out[OUT_OF_PLANE] = x0 + d
    return out


# The bending-only fabric of the mapping check: the membrane switched off (E > 0 is required).
BENDING_ONLY = dataclasses.replace(MEMBRANE, youngs_modulus=1e-9, damping=0.0, bending_damping=0.0)


def force_check_ours(sheet: Sheet) -> dict:
    """Our accelerations at the mapping-check positions (f64): the in-plane configuration on `sheet`
    (the membrane), the out-of-plane one on a bending-only cloth; each minus the same cloth's at rest."""
    out = {}
    zero = np.zeros_like(sheet.x0)
    configs = force_configs(sheet.x0)
    rest = accelerations_ours(sheet, sheet.x0, zero)
    out[IN_PLANE] = accelerations_ours(sheet, configs[IN_PLANE], zero) - rest
    bend = Sheet(BENDING_ONLY, sheet.n)
    rest = accelerations_ours(bend, bend.x0, zero)
    out[OUT_OF_PLANE] = accelerations_ours(bend, configs[OUT_OF_PLANE], zero) - rest
    return out


def interior(n: int, margin: int = 2) -> np.ndarray:
    j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    keep = (i >= margin) & (i < n - margin) & (j >= margin) & (j < n - margin)
    return keep.ravel()


def continuum(s: Settings) -> dict:
    """The membrane (and springs) on refined meshes, RK4, sampled at the coarse vertices."""
    out = {"membrane": [], "springs": []}
    for factor, dt in s.refine:
        nf = (s.n - 1) * factor + 1
        sheet = Sheet(MEMBRANE, nf)
        idx = coarse_index(s.n, factor)
        r = rk4_run(sheet, dt, s.t_end)
        entry = {"factor": factor, "n": nf, "dt": dt, "wall": r["wall"], "x": r["x"][idx], "check": None}
        log(f"[continuum] membrane {nf}² RK4 dt={dt:g}: {r['wall']:.1f} s")
        if factor == s.refine_check:
            c = rk4_run(sheet, dt / 2, s.t_end)
            dmax, drms = errors(r["x"], c["x"], sheet.free)
            entry["check"] = {"dt": dt / 2, "diff_max": dmax, "diff_rms": drms, "wall": c["wall"]}
            log(f"[continuum] membrane {nf}² RK4 dt={dt / 2:g}: |x(dt) - x(dt/2)| max {dmax:.2e}")
        out["membrane"].append(entry)
    for factor, dt in s.springs_refine:
        nf = (s.n - 1) * factor + 1
        sheet = Sheet(SPRINGS, nf)
        r = rk4_run(sheet, dt, s.t_end)
        log(f"[continuum] springs {nf}² RK4 dt={dt:g}: {r['wall']:.1f} s")
        out["springs"].append(
            {"factor": factor, "n": nf, "dt": dt, "wall": r["wall"], "x": r["x"][coarse_index(s.n, factor)]}
        )
    return out


# ---------------------------------------------------------------------------------------------------------
# part 2: implicit steps/s, f32


def part2(s: Settings) -> list:
    rows = []
    for n in s.sizes2:
        for name in ("membrane", "springs"):
            sheet = Sheet(MATERIALS[name], n, pins="corners")
            integ = ta.IntegratorImplicitEuler(
                linear_solver="pcg",
                tol=s.tols2[0],
                max_iterations=IMPLICIT_MAX_ITERATIONS,
                warm_start=True,
                check_every=STEPS2_CHECK_EVERY,
            )
            sheet.reset(integ)
            a = clock()
            integ.step(sheet.model, sheet.state, FRAME)
            first = clock() - a
            a = clock()
            integ.step(sheet.model, sheet.state, FRAME)
            second = clock() - a
            finals = {}
            for tol in s.tols2:
                integ.linear_solver.tol = tol
                sheet.reset(integ)
                times, its, res = [], [], []
                other = OtherLoad()
                c0 = sum(os.times()[:2])
                diverged = None
                try:
                    for _ in range(s.steps2):
                        a = clock()
                        integ.step(sheet.model, sheet.state, FRAME)
                        times.append(clock() - a)
                        its.append(int(integ.last_solve.iterations))
                        res.append(float(integ.last_solve.residual))
                        if sum(times) > RUN_BUDGET_S:
                            break
                    sheet.state.check_finite()
                except ta.DivergenceError as e:
                    diverged = str(e)[:80]
                wall = sum(times)
                x = sheet.state.particle_x.to_numpy().astype(np.float64)
                finals[tol] = x
                row = {
                    "model": name,
                    "n": n,
                    "tol": tol,
                    "steps": len(times),
                    "cut": len(times) < s.steps2 and diverged is None,
                    "rate": len(times) / wall if wall > 0 else math.nan,
                    "median_step": float(np.median(times)),
                    "max_step": float(np.max(times)),
                    "iter_mean": float(np.mean(its)),
                    "iter_max": int(np.max(its)),
                    "at_cap": int(sum(i >= IMPLICIT_MAX_ITERATIONS for i in its)),
                    "max_residual": float(np.max(res)),
                    "first_step": first,
                    "second_step": second,
                    "compile": max(first - second, 0.0),
                    "cores_busy": (sum(os.times()[:2]) - c0) / max(wall, 1e-9),
                    "other_load": other.cores(),
                    "diverged": diverged,
                    "finite": diverged is None and bool(np.isfinite(x).all()),
                    "vertices": n * n,
                }
                rows.append(row)
                log(
                    f"[implicit f32] {name:8s} {n}² tol {tol:g}: {row['rate']:.2f} steps/s, iterations "
                    f"{row['iter_mean']:.1f}/{row['iter_max']}, first step {fmt_s(first)}"
                    + (" CUT" if row["cut"] else "")
                    + (f" DIVERGED {diverged}" if diverged else "")
                )
            tols = list(finals)
            if len(tols) > 1 and all(r["steps"] == s.steps2 for r in rows[-len(tols) :]):
                dmax, drms = errors(finals[tols[0]], finals[tols[-1]], sheet.free)
                for r in rows[-len(tols) :]:
                    r["tol_diff_max"], r["tol_diff_rms"] = dmax, drms
    return rows


# ---------------------------------------------------------------------------------------------------------
# part 3: ours against Newton, f32


MEMBRANE_UNDAMPED = dataclasses.replace(MEMBRANE, damping=0.0, bending_damping=0.0)


def ours_frames(s: Settings, material) -> dict:
    """taichi_anim symplectic Euler on the part-1 scene with `material` at Newton's dt, f32, frames
    timed (first frame, with the compile, apart); the residual acceleration at the rest state."""
    sheet = Sheet(material, s.n)
    integ = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY)
    dt = FRAME / s.newton_substeps
    frames = round(s.t_end / FRAME)

    def frame():
        for _ in range(s.newton_substeps):
            integ.step(sheet.model, sheet.state, dt)
        return sheet.state.particle_x.to_numpy()

    sheet.reset(integ)
    a = clock()
    frame()
    first = clock() - a
    sheet.reset(integ)
    times = []
    c0 = sum(os.times()[:2])
    for _ in range(frames):
        a = clock()
        x = frame()
        times.append(clock() - a)
    cores = (sum(os.times()[:2]) - c0) / sum(times)
    sheet.state.check_finite()
    rest = accelerations_ours(sheet, sheet.x0, np.zeros_like(sheet.x0))
    return {
        "rest_residual": float(np.max(np.linalg.norm(rest[sheet.free], axis=1))),
        "first_frame": first,
        "frame_times": times,
        "x": x.astype(np.float64),
        "cores_busy": cores,
        "sheet": sheet,
        "dt": dt,
        "frames": frames,
    }


def newton_part(
    s: Settings, ours: dict, ours_undamped: dict, ref_membrane: dict, ref_springs: dict, acc_ours: dict
) -> dict:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from peers import newton_fem

    reason = newton_fem.available()
    if reason is not None:
        log(f"[newton] not run: {reason}")
        return {"ran": False, "reason": reason}
    cache = tempfile.mkdtemp(prefix="newton_kernel_cache_")
    try:
        winit = newton_fem.init_warp(cache)
        sheet = ours["sheet"]
        cell = SIDE / (s.n - 1)
        m = MEMBRANE
        out = {"ran": True, "versions": newton_fem.versions(), "warp_init_s": winit["init_s"], "variants": []}
        for label, damped in (("damping mapped", True), ("no damping", False)):
            params = newton_fem.mapping(
                youngs=m.youngs_modulus,
                poisson=m.poisson_ratio,
                bending=m.bending_stiffness,
                damping=m.damping,
                bending_damping=m.bending_damping,
                cell=cell,
                damped=damped,
            )
            cloth = newton_fem.NewtonCloth(
                sheet.x0, sheet.triangles, sheet.pinned, density=m.density, params=params, gravity=GRAVITY
            )
            mass_diff = float(np.max(np.abs(cloth.mass - sheet.mass)) / np.max(sheet.mass))
            c0 = sum(os.times()[:2])
            r = newton_fem.timed_frames(cloth, ours["dt"], s.newton_substeps, ours["frames"], clock)
            cores = (sum(os.times()[:2]) - c0) / (r["first_frame"] + sum(r["frame_times"]))
            x = r["x"]
            v = {
                "label": label,
                "params": params,
                "mapping_text": newton_fem.describe_mapping(params, cell),
                "counts": cloth.counts,
                "build_s": cloth.build_s,
                "finalize_s": cloth.finalize_s,
                "mass_rel_diff": mass_diff,
                "first_frame": r["first_frame"],
                "frame_times": r["frame_times"],
                "cores_busy": cores,
                "finite": r["finite"],
                "vs_ours": errors(x, ours["x"], sheet.free),
                "vs_ours_undamped": errors(x, ours_undamped["x"], sheet.free),
                "vs_ref": errors(x, ref_membrane["x"], sheet.free),
                "vs_springs_ref": errors(x, ref_springs["x"], sheet.free),
                "x_corner": x[-1].tolist(),
            }
            if damped:
                v["linearisation_check"] = newton_fem.linearisation_check(params)
                checks = {}
                inner = interior(s.n)
                zero = np.zeros_like(sheet.x0)
                configs = force_configs(sheet.x0)
                bend_params = dict(params, tri_ke=0.0, tri_ka=0.0, tri_kd=0.0, edge_kd=0.0)
                bend = newton_fem.NewtonCloth(
                    sheet.x0,
                    sheet.triangles,
                    sheet.pinned,
                    density=m.density,
                    params=bend_params,
                    gravity=GRAVITY,
                )
                for cname, c, comp in ((IN_PLANE, cloth, slice(None)), (OUT_OF_PLANE, bend, slice(1, 2))):
                    # The rest state is not force-free in f32 (positions rounded to f32, rest shape from
                    # the f64 grid): each cloth's acceleration there is subtracted.
                    rest_n = c.accelerations(sheet.x0, zero, GRAVITY)
                    if c is cloth:
                        v["rest_residual"] = float(np.max(np.linalg.norm(rest_n[sheet.free], axis=1)))
                    an = c.accelerations(configs[cname], zero, GRAVITY) - rest_n
                    at = acc_ours[cname]
                    d = an[inner][:, comp] - at[inner][:, comp]
                    ref_norm = np.linalg.norm(at[inner][:, comp], axis=1)
                    checks[cname] = {
                        "rel_max": float(np.max(np.linalg.norm(d, axis=1)) / np.max(ref_norm)),
                        "rel_rms": float(
                            np.sqrt(np.mean(np.sum(d * d, axis=1))) / np.sqrt(np.mean(ref_norm**2))
                        ),
                        "norm_ratio": float(
                            np.linalg.norm(an[inner][:, comp]) / np.linalg.norm(at[inner][:, comp])
                        ),
                        "scale": float(np.max(ref_norm)),
                        "component": "all" if c is cloth else "y (normal)",
                    }
                    log(
                        f"[newton] force check {cname}: relative difference max "
                        f"{checks[cname]['rel_max']:.2e} rms {checks[cname]['rel_rms']:.2e}, |a_Newton| / "
                        f"|a_ours| = {checks[cname]['norm_ratio']:.3f} (largest |a_ours| "
                        f"{checks[cname]['scale']:.2e} m/s²)"
                    )
                v["force_check"] = checks
                cloth.reset()
            out["variants"].append(v)
            log(
                f"[newton] {label}: {np.median(r['frame_times']) * 1e3:.1f} ms/frame (median), first frame "
                f"{fmt_s(r['first_frame'])}, finalize {fmt_s(cloth.finalize_s)}; vs ours max "
                f"{v['vs_ours'][0]:.2e} m, vs f64 reference max {v['vs_ref'][0]:.2e} m"
            )
        return out
    finally:
        shutil.rmtree(cache, ignore_errors=True)


# ---------------------------------------------------------------------------------------------------------
# report


def pareto(rows: list, key: str) -> list:
    ok = sorted(
        (r for r in rows if r["status"] == "ok" and math.isfinite(r[key])),
        key=lambda r: (r["wall_per_sim_s"], r[key]),
    )
    front, best = [], math.inf
    for r in ok:
        if r[key] < best:
            front.append(r)
            best = r[key]
    return front


def plot(rows: list, cont: dict, rows2: list, path, s: Settings) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(1, 3, figsize=(18, 6.4))
    colours = {"springs": "C0", "membrane": "C3"}
    markers = {("symplectic Euler", None): "o"}
    for k, tol in enumerate(s.implicit_tols):
        markers[("implicit Euler (PCG)", tol)] = "s^v"[k % 3]
    for ax, key, title in (
        (axes[0], "err_max", "error against the model's own converged answer"),
        (axes[1], "cont_max", f"error against the continuum answer ({cont['finest']}² membrane)"),
    ):
        for model in MATERIALS:
            for (method, tol), mk in markers.items():
                sel = [r for r in rows if r["model"] == model and r["method"] == method and r["tol"] == tol]
                ok = [r for r in sel if r["status"] == "ok"]
                bad = [r for r in sel if r["status"] != "ok"]
                label = f"{model}: {method}" + (f" tol {tol:g}" if tol else "")
                if ok:
                    ax.plot(
                        [r["wall_per_sim_s"] for r in ok],
                        [r[key] for r in ok],
                        mk + "-",
                        color=colours[model],
                        mfc="none" if method.startswith("implicit") else colours[model],
                        label=label,
                        lw=0.8,
                    )
                    for r in ok:
                        ax.annotate(fmt_dt(r["dt"]), (r["wall_per_sim_s"], r[key]), fontsize=6, alpha=0.7)
                for r in bad:
                    ax.plot([r["wall_per_sim_s"]], [1.0], "x", color=colours[model], ms=9)
        if key == "cont_max":
            for model in MATERIALS:
                ax.axhline(
                    cont["model_error"][model][0],
                    color=colours[model],
                    ls="--",
                    lw=1,
                    label=f"{model}: converged {s.n}² answer vs continuum",
                )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("wall time per simulated second [s] (f64, 2 threads)")
        ax.set_ylabel(f"max vertex error at T = {s.t_end:g} s [m]")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", lw=0.3)
    handles, labels = axes[1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    ax = axes[2]
    for model in MATERIALS:
        for k, tol in enumerate(s.tols2):
            sel = [r for r in rows2 if r["model"] == model and r["tol"] == tol]
            if sel:
                ax.plot(
                    [r["n"] for r in sel],
                    [r["rate"] for r in sel],
                    "os"[k % 2] + ("-" if k == 0 else "--"),
                    color=colours[model],
                    label=f"{model}, PCG tol {tol:g}",
                )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xticks(list(s.sizes2))
    ax.set_xticklabels([f"{n}²" for n in s.sizes2])
    ax.set_xlabel("grid")
    ax.set_ylabel("implicit steps per second at dt = 1/60 s (f32)")
    ax.set_title("implicit Euler, one step per frame, two corners pinned", fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    fig.suptitle(
        f"Springs vs membrane + bending, {s.n}² cloth swinging from one edge (crosses: unstable runs)",
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def speed_rows(rows: list, front_own: set, front_cont: set) -> list:
    out = []
    for r in rows:
        mark = ("◆" if id(r) in front_own else "") + ("●" if id(r) in front_cont else "")
        its = f"{r['iter_mean']:.1f} / {r['iter_max']}" if "iter_mean" in r else "–"
        status = "ok" if r["status"] == "ok" else f"**{r['status'].upper()}** ({r['note']})"
        out.append(
            [
                r["model"],
                f"{r['method']} {mark}".strip(),
                fmt_dt(r["dt"]),
                f"{r['tol']:g}" if r["tol"] else "–",
                r["steps"],
                fmt_s(r["wall_per_sim_s"]),
                its,
                f"{fmt_e(r['err_max'])} / {fmt_e(r['err_rms'])}",
                f"{fmt_e(r['cont_max'])} / {fmt_e(r['cont_rms'])}",
                status,
            ]
        )
    return out


def best_rows(rows: list, targets=(1e-1, 1e-2, 1e-3)) -> list:
    out = []
    for model in MATERIALS:
        for method in ("symplectic Euler", "implicit Euler (PCG)"):
            sel = [r for r in rows if r["model"] == model and r["method"] == method and r["status"] == "ok"]
            cells = []
            for t in targets:
                ok = [r for r in sel if r["err_max"] <= t]
                if ok:
                    b = min(ok, key=lambda r: r["wall_per_sim_s"])
                    tol = f", tol {b['tol']:g}" if b["tol"] else ""
                    cells.append(f"{fmt_s(b['wall_per_sim_s'])} ({fmt_dt(b['dt'])}{tol})")
                else:
                    cells.append("–")
            low = min(sel, key=lambda r: r["err_max"]) if sel else None
            cells.append(
                "–"
                if low is None
                else f"{fmt_e(low['err_max'])} ({fmt_dt(low['dt'])}, {fmt_s(low['wall_per_sim_s'])})"
            )
            cont = min(sel, key=lambda r: r["cont_max"]) if sel else None
            cells.append(
                "–"
                if cont is None
                else f"{fmt_e(cont['cont_max'])} ({fmt_dt(cont['dt'])}, {fmt_s(cont['wall_per_sim_s'])})"
            )
            out.append([model, method, *cells])
    return out


def stable_limit_text(rows: list) -> str:
    parts = []
    for model in MATERIALS:
        sel = [r for r in rows if r["model"] == model and r["method"] == "symplectic Euler"]
        ok = [r["dt"] for r in sel if r["status"] == "ok"]
        bad = [r["dt"] for r in sel if r["status"] != "ok"]
        parts.append(
            f"{model}: stable up to {max(ok):.3g} s" + (f", unstable at {min(bad):.3g} s" if bad else "")
            if ok
            else f"{model}: no stable run"
        )
    return "; ".join(parts)


def summary(
    s: Settings, rows: list, cont: dict, rows2: list, newton: dict, ours: dict, undamped: dict
) -> str:
    """Bullet points of the main figures, every number taken from the tables below."""

    def sym(model):
        sel = [
            r
            for r in rows
            if r["model"] == model and r["method"] == "symplectic Euler" and r["status"] == "ok"
        ]
        return max(sel, key=lambda r: r["dt"]) if sel else None

    out = []
    a, b = sym("springs"), sym("membrane")
    same = [
        (ra, rb)
        for ra in rows
        for rb in rows
        if ra["model"] == "springs"
        and rb["model"] == "membrane"
        and ra["method"] == rb["method"] == "symplectic Euler"
        and ra["dt"] == rb["dt"]
        and ra["status"] == rb["status"] == "ok"
    ]
    if a and b and same:
        ratio = float(np.median([rb["wall_per_sim_s"] / ra["wall_per_sim_s"] for ra, rb in same]))
        out.append(
            f"Symplectic Euler: the membrane + bending step costs {ratio:.1f}x the springs' step (median "
            f"over the {len(same)} common dt, f64); both are stable up to dt = {fmt_dt(a['dt'])} s "
            f"(springs) and {fmt_dt(b['dt'])} s (membrane), where the error against the own converged "
            f"answer is {fmt_e(a['err_max'])} m (springs, {fmt_s(a['wall_per_sim_s'])} per simulated s) and "
            f"{fmt_e(b['err_max'])} m (membrane, {fmt_s(b['wall_per_sim_s'])})."
        )
    imp = {
        m: min(
            (
                r
                for r in rows
                if r["model"] == m and r["method"].startswith("implicit") and r["status"] == "ok"
            ),
            key=lambda r: r["err_max"],
            default=None,
        )
        for m in MATERIALS
    }
    coarse = [
        r
        for r in rows
        if r["method"].startswith("implicit") and r["status"] == "ok" and r["dt"] == max(s.implicit_dts)
    ]
    if all(imp.values()) and coarse:
        lo, hi = min(r["err_max"] for r in coarse), max(r["err_max"] for r in coarse)
        best = "; ".join(
            f"{m} {fmt_e(r['err_max'])} m at dt = {fmt_dt(r['dt'])} s, tol {r['tol']:g} "
            f"({fmt_s(r['wall_per_sim_s'])} per simulated s)"
            for m, r in imp.items()
        )
        text = (
            f"Implicit Euler (PCG), first order and dissipative: at dt = {fmt_dt(max(s.implicit_dts))} s its "
            f"positions at T are {fmt_e(lo)}–{fmt_e(hi)} m off the converged answers; its most accurate "
            f"runs: {best}."
        )
        beats = all(
            sym(m) is not None
            and sym(m)["err_max"] < imp[m]["err_max"]
            and sym(m)["wall_per_sim_s"] < imp[m]["wall_per_sim_s"]
            for m in MATERIALS
        )
        if beats:
            text += (
                " For both models symplectic Euler at its largest stable dt is both cheaper and more "
                "accurate than that."
            )
        out.append(text)
    parts = [f"{label}: {fmt_e(e[0])} m max, {fmt_e(e[1])} m RMS" for label, e, _ in cont["rows"]]
    out.append(
        f"Distance from the continuum answer ({cont['finest']}² membrane) at T: " + "; ".join(parts) + "."
    )
    by = {(r["model"], r["n"], r["tol"]): r for r in rows2}
    cells = []
    for n in s.sizes2:
        for m in ("membrane", "springs"):
            r = by.get((m, n, s.tols2[0]))
            if r:
                cells.append(
                    f"{m} {n}²: {r['rate']:.3g} steps/s ({r['iter_mean']:.0f} iterations/step"
                    + (", cut" if r["cut"] else "")
                    + ")"
                )
    if cells:
        out.append(f"Implicit Euler at dt = 1/60 s, f32, PCG tol {s.tols2[0]:g}: " + "; ".join(cells) + ".")
    if newton.get("ran"):
        ours_ms = float(np.median(ours["frame_times"])) * 1e3
        v = {x["label"]: x for x in newton["variants"]}
        d, u = v.get("damping mapped"), v.get("no damping")
        if d and u:
            out.append(
                f"Newton (Warp CPU, one thread): {np.median(d['frame_times']) * 1e3:.1f} ms per frame "
                f"against our {ours_ms:.1f} ms ({np.median(d['frame_times']) * 1e3 / ours_ms:.2f}x) at "
                f"{s.newton_substeps} substeps; final shape: with the mapped damping "
                f"{fmt_e(d['vs_ours'][0])} m from ours (max; Newton's triangle damping also brakes the "
                f"swing), undamped {fmt_e(u['vs_ours_undamped'][0])} m from our undamped run "
                f"(ours damped vs undamped: {fmt_e(ours['vs_undamped'][0])} m)."
            )
    return "\n".join(f"- {t}" for t in out)


def json_clean(obj):
    if isinstance(obj, dict):
        return {str(k): json_clean(v) for k, v in obj.items() if k not in ("x", "sheet")}
    if isinstance(obj, list | tuple):
        return [json_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_clean(obj.tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, np.floating | np.integer):
        return json_clean(obj.item())
    return obj


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    _, out_dir = output_paths(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    s = QUICK if args.quick else FULL
    load_start = load_average()
    engine = engine_fingerprint()
    other = OtherLoad()
    date = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()
    phase = {}

    # ---- part 1 (f64)
    t0 = time.perf_counter()
    init("f64")
    refs, rows, warms, acc_ours = {}, [], {}, {}
    for name, material in MATERIALS.items():
        sheet = Sheet(material, s.n)
        refs[name] = reference(sheet, s, name)
        r, warms[name] = sweep(sheet, s, name, refs[name])
        rows += r
        if name == "membrane":
            acc_ours = force_check_ours(sheet)
        free = sheet.free
    phase["part 1: references and sweeps"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    note = damping_note(s)
    phase["part 1: default-damping stability"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fine = continuum(s)
    phase["part 1: refined meshes"] = time.perf_counter() - t0
    finest = fine["membrane"][-1]
    cont = {"finest": finest["n"], "model_error": {}, "refined": [], "springs_refined": []}
    cont["rows"] = []
    for name in MATERIALS:
        cont["model_error"][name] = errors(refs[name]["x"], finest["x"], free)
        where = worst_vertex(refs[name]["x"], finest["x"], free, s.n)
        cont["rows"].append((f"{name}, converged {s.n}² answer", cont["model_error"][name], where))
    for e in fine["membrane"][:-1]:
        cont["refined"].append({"n": e["n"], "err": errors(e["x"], finest["x"], free), "dt": e["dt"]})
        where = worst_vertex(e["x"], finest["x"], free, s.n)
        cont["rows"].append(
            (f"membrane, {e['n']}² (RK4 dt = {fmt_dt(e['dt'])} s)", cont["refined"][-1]["err"], where)
        )
    for e in fine["springs"]:
        cont["springs_refined"].append({"n": e["n"], "err": errors(e["x"], finest["x"], free), "dt": e["dt"]})
        where = worst_vertex(e["x"], finest["x"], free, s.n)
        cont["rows"].append(
            (
                f"springs on the {e['n']}² mesh (RK4 dt = {fmt_dt(e['dt'])} s)",
                cont["springs_refined"][-1]["err"],
                where,
            )
        )
    for r in rows:
        r["cont_max"], r["cont_rms"] = (
            errors(r["x"], finest["x"], free) if r["status"] == "ok" else (math.nan, math.nan)
        )
    model_gap = errors(refs["springs"]["x"], refs["membrane"]["x"], free)

    # ---- part 3 ours + Newton (f32), then part 2 (f32)
    t0 = time.perf_counter()
    init("f32")
    ours = ours_frames(s, MEMBRANE)
    ours_undamped = ours_frames(s, MEMBRANE_UNDAMPED)
    ours_vs_ref = errors(ours["x"], refs["membrane"]["x"], free)
    ours["vs_undamped"] = errors(ours["x"], ours_undamped["x"], free)
    ours_undamped["vs_ref"] = errors(ours_undamped["x"], refs["membrane"]["x"], free)
    newton = newton_part(s, ours, ours_undamped, refs["membrane"], refs["springs"], acc_ours)
    phase["part 3: ours and Newton"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    rows2 = part2(s)
    phase["part 2: implicit steps/s"] = time.perf_counter() - t0
    total = time.perf_counter() - started
    load_end = load_average()

    # ---- report
    report(
        args,
        s,
        out_dir,
        {
            "rows": rows,
            "cont": cont,
            "rows2": rows2,
            "refs": refs,
            "fine": fine,
            "note": note,
            "warms": warms,
            "finest": finest,
            "free": free,
            "ours": ours,
            "ours_undamped": ours_undamped,
            "ours_vs_ref": ours_vs_ref,
            "newton": newton,
            "model_gap": model_gap,
            "total": total,
            "phase": phase,
            "load_start": load_start,
            "load_end": load_end,
            "date": date,
            "engine": engine,
            "other": other,
        },
    )


def report(args, s: Settings, out_dir, data: dict) -> None:
    """Write cloth_continuum_speed.{md,json,png} from the measurements of main()."""
    rows = data["rows"]
    cont = data["cont"]
    rows2 = data["rows2"]
    refs = data["refs"]
    fine = data["fine"]
    note = data["note"]
    warms = data["warms"]
    finest = data["finest"]
    free = data["free"]
    ours = data["ours"]
    ours_undamped = data["ours_undamped"]
    ours_vs_ref = data["ours_vs_ref"]
    newton = data["newton"]
    model_gap = data["model_gap"]
    total = data["total"]
    phase = data["phase"]
    load_start = data["load_start"]
    load_end = data["load_end"]
    date = data["date"]
    engine = data["engine"]
    other = data["other"]
    front_own = {id(r) for r in pareto(rows, "err_max")}
    front_cont = {id(r) for r in pareto(rows, "cont_max")}
    png = out_dir / "cloth_continuum_speed.png"
    plot(rows, cont, rows2, png, s)
    machine = machine_table(
        machine_info(), load_start=load_start, load_end=load_end, date=date, engine=engine, other=other
    )
    others = other.cores()
    timing_note = (
        f"Other processes used {others:.2f} cores on average during the run (other engineers' jobs on this "
        "shared 2-core machine"
        + (
            "): the timings are lower bounds for an idle machine; read them as orders of magnitude and "
            "compare ratios measured in the same run"
            if others >= LOADED_CORES
            else ", so it was close to idle)"
        )
        + ". Errors, iteration counts and shape differences do not depend on the load."
    )
    n, nf = s.n, finest["n"]
    scene = (
        f"{n}² vertices, {SIDE:g} m square, {0.2:g} kg/m² lumped by triangle area, edge j = 0 pinned "
        f"({n} vertices), gravity {GRAVITY:g} m/s², starts flat and at rest at y = {HEIGHT:g} m, T = "
        f"{s.t_end:g} s; no drag, no colliders."
    )
    ref_rows = [
        [
            name,
            material_text(name),
            f"RK4, dt = {fmt_dt(refs[name]['dt'])} s",
            f"{fmt_e(refs[name]['diff_max'])} / {fmt_e(refs[name]['diff_rms'])}",
            f"{refs[name]['max_displacement']:.3f}",
            fmt_s(refs[name]["wall"]),
        ]
        for name in MATERIALS
    ]
    cont_rows = [[label, f"{fmt_e(e[0])} / {fmt_e(e[1])}", where] for label, e, where in cont["rows"]]
    cont_rows.append(
        [
            f"(scale) springs vs membrane, both converged at {n}²",
            f"{fmt_e(model_gap[0])} / {fmt_e(model_gap[1])}",
            worst_vertex(refs["springs"]["x"], refs["membrane"]["x"], free, n),
        ]
    )
    fine_rows = []
    for kind, e in [("membrane", e) for e in fine["membrane"]] + [("springs", e) for e in fine["springs"]]:
        chk = e.get("check")
        fine_rows.append(
            [
                kind,
                f"{e['n']}²",
                fmt_dt(e["dt"]),
                fmt_s(e["wall"]),
                "–"
                if not chk
                else f"RK4 at dt = {fmt_dt(chk['dt'])} s: |x(dt) - x(dt/2)| max "
                f"{fmt_e(chk['diff_max'])}, RMS "
                f"{fmt_e(chk['diff_rms'])} ({fmt_s(chk['wall'])})",
            ]
        )
    tried = ", ".join(f"{t['dt']:.3g} s {t['status']}" for t in note["tried"])
    warm_rows = [
        [name, method, fmt_s(w["first"]), fmt_s(w["steady"]), fmt_s(w["compile"])]
        for name in MATERIALS
        for method, w in list(warms[name].items()) + [("RK4 (reference)", refs[name]["warm"])]
    ]
    speed_headers = [
        "model",
        "method",
        "dt",
        "tol",
        "steps",
        "wall / sim-s",
        "PCG iterations mean / max",
        "error vs own reference max / RMS [m]",
        f"error vs continuum ({nf}² membrane) max / RMS [m]",
        "status",
    ]
    targets = (1e-1, 1e-2, 1e-3)
    best_headers = [
        "model",
        "method",
        *[f"cheapest with error ≤ {t:g} m" for t in targets],
        "smallest error vs own reference",
        "smallest error vs continuum",
    ]
    rows2_md = [
        [
            r["model"],
            f"{r['n']}²",
            r["vertices"],
            f"{r['tol']:g}",
            f"**{r['rate']:.3g}**"
            + (" (cut)" if r["cut"] else "")
            + (" DIVERGED" if not r["finite"] else ""),
            f"{r['median_step'] * 1e3:.1f}",
            f"{r['iter_mean']:.1f} / {r['iter_max']}",
            r["at_cap"],
            fmt_e(r["max_residual"]),
            "–" if "tol_diff_max" not in r else f"{fmt_e(r['tol_diff_max'])} / {fmt_e(r['tol_diff_rms'])}",
            fmt_s(r["first_step"]),
            fmt_s(r["compile"]),
            f"{r['cores_busy']:.2f}",
            f"{r['other_load']:.2f}",
        ]
        for r in rows2
    ]
    rows2_headers = [
        "model",
        "grid",
        "vertices",
        "PCG tol",
        "steps/s",
        "median step [ms]",
        "iterations mean / max",
        f"steps at cap ({IMPLICIT_MAX_ITERATIONS})",
        "largest residual",
        f"|x(tol {s.tols2[0]:g}) - x(tol {s.tols2[-1]:g})| at t = {s.steps2 * FRAME:.3g} s, max / RMS [m]",
        "first step (compile)",
        "compile = first - second step",
        "cores busy",
        "other load",
    ]
    ours_ms = float(np.median(ours["frame_times"])) * 1e3
    newton_md = ""
    if newton["ran"]:
        vrows, frows = [], []
        for label, o in (("damped", ours), ("no damping", ours_undamped)):
            med = float(np.median(o["frame_times"])) * 1e3
            frows.append(
                [
                    f"taichi_anim membrane, {label} (symplectic Euler, f32, Taichi threads)",
                    f"{med:.1f}",
                    f"{np.mean(o['frame_times']) * 1e3:.1f}",
                    f"{med / s.newton_substeps * 1e3:.0f}",
                    fmt_s(o["first_frame"]),
                    f"{o['cores_busy']:.2f}",
                    f"{med / ours_ms:.2f}",
                ]
            )
        for v in newton["variants"]:
            med = float(np.median(v["frame_times"])) * 1e3
            frows.append(
                [
                    f"Newton SolverSemiImplicit, {v['label']} (f32, Warp CPU)",
                    f"{med:.1f}",
                    f"{np.mean(v['frame_times']) * 1e3:.1f}",
                    f"{med / s.newton_substeps * 1e3:.0f}",
                    fmt_s(v["first_frame"]),
                    f"{v['cores_busy']:.2f}",
                    f"{med / ours_ms:.2f}",
                ]
            )
            vrows.append(
                [
                    f"Newton, {v['label']}",
                    f"{fmt_e(v['vs_ours'][0])} / {fmt_e(v['vs_ours'][1])}",
                    f"{fmt_e(v['vs_ours_undamped'][0])} / {fmt_e(v['vs_ours_undamped'][1])}",
                    f"{fmt_e(v['vs_ref'][0])} / {fmt_e(v['vs_ref'][1])}",
                    f"{fmt_e(v['vs_springs_ref'][0])} / {fmt_e(v['vs_springs_ref'][1])}",
                    "yes" if v["finite"] else "**no**",
                ]
            )
        vrows.append(
            [
                "taichi_anim membrane, damped, same dt, f32 (scale: our own step and round-off error)",
                "0",
                f"{fmt_e(ours['vs_undamped'][0])} / {fmt_e(ours['vs_undamped'][1])}",
                f"{fmt_e(ours_vs_ref[0])} / {fmt_e(ours_vs_ref[1])}",
                "–",
                "yes",
            ]
        )
        vrows.append(
            [
                "taichi_anim membrane, no damping, same dt, f32",
                f"{fmt_e(ours['vs_undamped'][0])} / {fmt_e(ours['vs_undamped'][1])}",
                "0",
                f"{fmt_e(ours_undamped['vs_ref'][0])} / {fmt_e(ours_undamped['vs_ref'][1])}",
                "–",
                "yes",
            ]
        )
        vrows.append(
            [
                "(scale) springs vs membrane, both converged (f64)",
                f"{fmt_e(model_gap[0])} / {fmt_e(model_gap[1])}",
                "",
                "",
                "",
                "",
            ]
        )
        damped = newton["variants"][0]
        fc = damped.get("force_check", {})
        fc_rows = [
            [
                k,
                c["component"],
                f"{FORCE_AMPLITUDE[k]:g}",
                fmt_e(c["scale"]),
                fmt_e(c["rel_max"]),
                fmt_e(c["rel_rms"]),
                f"{c['norm_ratio']:.3f}",
            ]
            for k, c in fc.items()
        ]
        first_newton = newton["variants"][0]
        newton_compile = first_newton["first_frame"] - float(np.median(first_newton["frame_times"]))
        newton_md = (
            "## 3. Newton's semi-implicit triangle FEM, same scene\n\n"
            f"Newton {newton['versions']['newton']} on warp-lang {newton['versions']['warp-lang']}, CPU "
            f'(`wp.set_device("cpu")`), `SolverSemiImplicit(model, enable_tri_contact=False)`, '
            "`model.particle_grid = None` (no contacts, as in our scene); the cloth built with "
            "`ModelBuilder(up_axis=Y, gravity=(0, -9.81, 0)).add_cloth_mesh` from our grid's vertices and "
            f"triangles ({', '.join(f'{k}: {v}' for k, v in first_newton['counts'].items())}); vertex masses "
            f"equal ours to {first_newton['mass_rel_diff']:.1e} (relative); {n} pinned vertices with mass 0 "
            "and "
            f"not ACTIVE. Frame 1/60 s × {s.newton_substeps} substeps (dt = {ours['dt']:.4g} s), "
            f"{ours['frames']} frames (T = {s.t_end:g} s), positions copied to NumPy each frame. Ours: "
            "`symplectic_euler` on the same scene and dt, f32, `check_every` = 10^9, positions read each "
            "frame, with the membrane's damping and with none (damping = bending_damping = 0), the "
            "counterpart of Newton's undamped run.\n\n"
            "**Mapping** (derivation in `benchmarks/peers/newton_fem.py`): Newton's triangle is a 2D stable "
            "neo-Hookean (psi = k_mu/2 (tr FᵀF - 2) + k_lambda/2 (J - 1 - k_mu/k_lambda)² per rest area), "
            "whose linearisation has Lamé parameters mu_L = tri_ke, lambda_L = tri_ka - tri_ke; ours "
            f"(StVK, plane stress) has mu_L = E/(2(1+nu)), lambda_L = E nu/(1-nu²). Damped run: "
            f"{damped['mapping_text']}. Undamped run: tri_kd = edge_kd = 0. The NumPy check of that "
            f"linearisation (random in-plane H ~ 1e-4): largest relative difference "
            f"{damped.get('linearisation_check', math.nan):.1e}.\n\n"
            "**Mapping check: accelerations f/m of both engines at the same positions** (zero velocity; "
            f"interior vertices, 2 rows from every edge; ours f64, Newton f32; relative = |a_Newton - "
            "a_ours| / |a_ours|, max over vertices of each divided by the largest |a_ours|, and RMS over "
            "RMS). In-plane: the full membrane cloths (a sinusoidal in-plane displacement, bending stays "
            "flat). Out-of-plane: a sinusoidal bump on bending-only cloths (ours: E = 1e-9 N/m; Newton: "
            "tri_ke = tri_ka = tri_kd = 0), normal component; the mapping is exact only for bending about "
            "the grid axes (on the diagonal hinges Newton's stiffness is 1/√2 of ours). Why bending-only: "
            "with the membrane on, f32 round-off of Newton's membrane forces swamps the bending forces of "
            "any bump small enough to keep the membrane's own second-order forces negligible. The rest "
            "state itself is not force-free in f32 (positions rounded to f32, rest shapes computed from "
            "the f64 grid): each cloth's acceleration there is subtracted. Its largest value over the free "
            f"vertices of the membrane cloth: {damped.get('rest_residual', math.nan):.1e} m/s² in Newton, "
            f"{ours['rest_residual']:.1e} m/s² in ours (f32), against 9.81 m/s² for gravity: both "
            "simulations start with this round-off in their forces.\n\n"
            + md_table(
                [
                    "configuration",
                    "component",
                    "amplitude [m]",
                    "largest |a_ours| [m/s²]",
                    "relative max",
                    "relative RMS",
                    "\\|a_Newton\\| / \\|a_ours\\| (2-norms over the vertices)",
                ],
                fc_rows,
            )
            + "\n\n**Time per frame** (median and mean over the frames after a first frame; Newton's first "
            f"frame holds the cold compile of its solver modules, Warp's kernel cache in a fresh folder: "
            f"{fmt_s(newton_compile)}; `finalize` of the first model, which compiles Newton's mesh and BVH "
            f"modules, took {fmt_s(first_newton['finalize_s'])}; Warp init {fmt_s(newton['warp_init_s'])}). "
            "Cores busy = process CPU time / wall time over the frames (Warp runs CPU kernels on one "
            "thread, Taichi on its default thread count):\n\n"
            + md_table(
                [
                    "engine",
                    "median ms / frame",
                    "mean ms / frame",
                    "µs / substep",
                    "first frame",
                    "cores busy",
                    "time / ours",
                ],
                frows,
            )
            + f"\n\n**Final shape at T = {s.t_end:g} s** (max / RMS over the {int(free.sum())} free vertices "
            "of "
            "the distance between positions [m]):\n\n"
            + md_table(
                [
                    "run",
                    "vs our membrane run (same dt, f32)",
                    "vs our undamped membrane run (same dt, f32)",
                    "vs our converged membrane (RK4, f64)",
                    "vs our converged springs (RK4, f64)",
                    "finite",
                ],
                vrows,
            )
            + "\n"
        )
    else:
        newton_md = (
            "## 3. Newton's semi-implicit triangle FEM\n\n"
            f"**Not run**: `{newton['reason']}`. Install the optional extra (`.venv/bin/pip install -e "
            "'.[newton]'`: newton==1.8.0 with warp-lang==1.19.0, the `bench` pin) and run again.\n"
        )
    phase_text = ", ".join(f"{k} {v:.0f} s" for k, v in phase.items())
    page = (
        "# Springs vs membrane + bending: speed against error, the continuum answer, Newton's FEM\n\n"
        f"Regenerate: `{command_line(args, 'cloth_continuum_speed.py')}` (took {total / 60:.1f} min: "
        f"{phase_text}). The module docstring of `benchmarks/cloth_continuum_speed.py` describes the method; "
        "the Newton peer and its parameter mapping are in `benchmarks/peers/newton_fem.py`.\n\n"
        f"{timing_note}\n\n{machine}\n\n"
        "## Summary\n\n"
        + summary(s, rows, cont, rows2, newton, ours, ours_undamped)
        + "\n\n## Scene and materials\n\n"
        f"{scene}\n\n"
        f"- **springs**: {material_text('springs')};\n"
        f"- **membrane**: {material_text('membrane')}. Same stretch stiffness (the areal Young's modulus of "
        "a "
        "grid of stretch springs k is about k) and the same stiffness-proportional damping of stretching "
        f"(beta = {BETA:g} s; FabricMaterial's default is {FABRIC.damping:g} s, see below).\n\n"
        "## 1. Speed against error (f64)\n\n"
        f"Each model against its own converged answer (RK4 at dt = {s.ref_dt:g} s, checked against RK4 at "
        f"{2 * s.ref_dt:g} s: RK4's error falls ~16x per halving, so the reference's own error is ~1/15 of "
        "the check difference), and against the continuum answer: the membrane on the "
        f"{nf}² mesh ({finest['factor']}x refined: every {n}² vertex is a vertex of it), RK4 at dt = "
        f"{finest['dt']:.3g} s. Symplectic Euler at dt = {', '.join(fmt_dt(d) for d in s.sym_dts)} s in that "
        "order until a run fails; implicit "
        f"Euler (PCG, warm start, max {IMPLICIT_MAX_ITERATIONS} iterations) at dt = "
        f"{', '.join(fmt_dt(d) for d in s.implicit_dts)} s and tol "
        f"{', '.join(f'{t:g}' for t in s.implicit_tols)}. "
        f"Errors: max and RMS over the {int(free.sum())} free vertices of |x(T) - x_ref(T)|. Wall time per "
        "simulated second, f64, Taichi's default thread count; positions read back "
        f"{SNAPSHOTS} times per run outside the timed segments; runs under {MIN_RUN_TIME} s repeated up to "
        f"{MAX_REPEATS} times (fastest kept).\n\n"
        f"![speed against error]({png.name})\n\n"
        f"**Symplectic Euler's stability limit.** {stable_limit_text(rows)}.\n\n"
        "**Cheapest run for each error target** (against the model's own converged answer; wall time per "
        "simulated second, dt, tol), and the smallest errors reached:\n\n"
        + md_table(best_headers, best_rows(rows, targets))
        + "\n\n**How far each model's cloth is from the continuum answer** (positions at T of the "
        f"{n}² coarse vertices against the {nf}² membrane at the same material points, max / RMS [m]):\n\n"
        + md_table(
            [
                "answer",
                "distance from the continuum answer, max / RMS [m]",
                "largest at grid vertex (i, j) (j = 0: pinned edge)",
            ],
            cont_rows,
        )
        + "\n\nReferences (converged answers at the coarse mesh):\n\n"
        + md_table(
            [
                "model",
                "material",
                "reference",
                "|x(2dt) - x(dt)| max / RMS [m]",
                "largest displacement [m]",
                "wall (both runs)",
            ],
            ref_rows,
        )
        + "\n\nRefined meshes (RK4, f64):\n\n"
        + md_table(["model", "grid", "dt [s]", "wall", "time-step check"], fine_rows)
        + "\n\nEvery run (◆: on the Pareto front of all runs of both models, error against the own "
        "reference; ●: on the joint front of error against the continuum answer):\n\n"
        + md_table(speed_headers, speed_rows(rows, front_own, front_cont))
        + "\n\n**Default membrane damping.** FabricMaterial's default Rayleigh damping "
        f"({note['damping']:g} s, "
        f"bending {note['bending_damping']:g} s; the demos' FABRIC) on the same {n}² scene, symplectic Euler "
        f"from dt = {s.sym_dts[0] / 2:g} s doubling: {tried}. The matched-damping membrane above runs up to "
        f'the dt given under "Symplectic Euler\'s stability limit". Implicit Euler is not limited by it.\n\n'
        "**JIT compile** (first "
        f"{WARM_STEPS} steps, compile included, against the same steps again):\n\n"
        + md_table(["model", "integrator", "first steps", "again", "compile"], warm_rows)
        + "\n\n## 2. Implicit steps per second at dt = 1/60 s (f32)\n\n"
        f"Implicit Euler, one step per frame, PCG (block Jacobi), warm start, max {IMPLICIT_MAX_ITERATIONS} "
        f"iterations, `check_every` = {STEPS2_CHECK_EVERY}; the same fabrics on a 1 m square pinned at the "
        "two "
        f"corners of one edge; {s.steps2} steps timed one by one after two warm-up steps (the first holds "
        f"the compile); runs past {RUN_BUDGET_S:g} s of timed steps are cut. The last column pair "
        "compares the final positions of the two tolerances (an estimate of the looser one's solver "
        "error).\n\n" + md_table(rows2_headers, rows2_md) + "\n\n" + newton_md
    )
    (out_dir / "cloth_continuum_speed.md").write_text(page)
    (out_dir / "cloth_continuum_speed.json").write_text(
        json.dumps(
            json_clean(
                {
                    "settings": dataclasses.asdict(s),
                    "materials": {k: dataclasses.asdict(v) for k, v in MATERIALS.items()},
                    "references": refs,
                    "runs": rows,
                    "continuum": {
                        **cont,
                        "fine": {
                            k: [{kk: vv for kk, vv in e.items() if kk != "x"} for e in v]
                            for k, v in fine.items()
                        },
                    },
                    "model_gap": model_gap,
                    "default_damping": note,
                    "implicit_f32": rows2,
                    "ours_frames": {k: v for k, v in ours.items() if k not in ("x", "sheet")},
                    "ours_frames_undamped": {
                        k: v for k, v in ours_undamped.items() if k not in ("x", "sheet")
                    },
                    "ours_vs_ref": ours_vs_ref,
                    "newton": newton,
                    "machine": machine_info(),
                    "load": [load_start, load_end],
                    "other_load_cores": others,
                    "phases_s": phase,
                    "total_s": total,
                }
            ),
            indent=1,
        )
    )
    log(f"wrote {out_dir}/cloth_continuum_speed.{{md,json,png}} in {total / 60:.1f} min")


if __name__ == "__main__":
    main()
