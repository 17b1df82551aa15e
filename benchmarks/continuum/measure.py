"""Part 1 (f64): each model's converged reference, the symplectic and implicit sweeps against it,
FabricMaterial's default damping, the refined meshes and every answer's distance from the continuum
answer. Everything returned is a plain dict or list of dicts (positions under "x")."""

from __future__ import annotations

import math
import os

import numpy as np
from common import clock, fmt_dt, fmt_e, fmt_s, log

import taichi_anim as ta
from taichi_anim.scenes.cloth import FABRIC

from .config import (
    BENDING_ONLY,
    CHECK_EVERY,
    GRAVITY,
    IMPLICIT,
    IMPLICIT_MAX_ITERATIONS,
    IN_PLANE,
    MATERIALS,
    MAX_REPEATS,
    MAX_SPEED,
    MEMBRANE,
    MIN_RUN_TIME,
    OUT_OF_PLANE,
    SNAPSHOTS,
    SPRINGS,
    SYMPLECTIC,
    WARM_STEPS,
    Settings,
)
from .scene import Sheet, coarse_index, errors, force_configs, worst_vertex

# ---------------------------------------------------------------------------------------------------------
# one run


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


def cpu_seconds() -> float:
    """CPU time of this process, user + system [s]."""
    return sum(os.times()[:2])


def whole_steps(t_end: float, dt: float) -> int:
    steps = round(t_end / dt)
    if abs(steps * dt - t_end) > 1e-9 * t_end:
        raise ValueError(f"t_end = {t_end} is not a whole number of steps of {dt}")
    return steps


def _advance(sheet: Sheet, integ, dt: float, k: int, its: list | None) -> tuple[float, str, str]:
    """k timed steps (PCG iterations appended to `its` unless None): (wall, status, note)."""
    wall = 0.0
    t0 = clock()
    try:
        for _ in range(k):
            integ.step(sheet.model, sheet.state, dt)
            if its is not None:
                its.append(int(integ.last_solve.iterations))
        wall = clock() - t0
        sheet.state.check_finite()
    except ta.DivergenceError as e:
        # Unchanged from the single-file version: a divergence that check_finite reports adds the
        # segment's steps to the wall time a second time.
        return wall + clock() - t0, "diverged", str(e).split(":")[0][:60]
    return wall, "ok", ""


def _watch(x: np.ndarray, v: np.ndarray, t: float) -> tuple[str, str]:
    """(status, note) of positions and velocities read back at time t."""
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
        return "diverged", "non-finite positions"
    if float(np.max(np.linalg.norm(v, axis=1))) > MAX_SPEED:
        return "unstable", f"speed > {MAX_SPEED:g} m/s at t = {t:.3g} s"
    return "ok", ""


def _run_once(sheet: Sheet, integ, dt: float, steps: int, implicit: bool) -> dict:
    """From rest, SNAPSHOTS timed segments with the positions read between them; stops at the first
    failure."""
    sheet.reset(integ)
    seg = max(steps // SNAPSHOTS, 1)
    run = {"its": [], "status": "ok", "note": "", "wall": 0.0, "done": 0, "x": sheet.x0}
    while run["done"] < steps and run["status"] == "ok":
        k = min(seg, steps - run["done"])
        wall, run["status"], run["note"] = _advance(sheet, integ, dt, k, run["its"] if implicit else None)
        run["wall"] += wall
        run["done"] += k
        run["x"], v = sheet.read()
        if run["status"] == "ok":
            run["status"], run["note"] = _watch(run["x"], v, run["done"] * dt)
    return run


def simulate(sheet: Sheet, integ, dt: float, t_end: float, *, implicit: bool = False) -> dict:
    """0 -> t_end from rest; positions read SNAPSHOTS times outside the timed segments; stops at the
    first non-finite value, vertex speed above MAX_SPEED or divergence error. Runs shorter than
    MIN_RUN_TIME are repeated (up to MAX_REPEATS runs), the fastest kept."""
    steps = whole_steps(t_end, dt)
    walls: list[float] = []
    while True:
        run = _run_once(sheet, integ, dt, steps, implicit)
        walls.append(run["wall"])
        if run["status"] != "ok" or sum(walls) >= MIN_RUN_TIME or len(walls) >= MAX_REPEATS:
            break
    out = {
        "dt": dt,
        "steps": steps,
        "steps_run": run["done"],
        "status": run["status"],
        "note": run["note"],
        "x": run["x"],
        "wall": min(walls),
        "repeats": len(walls),
        "wall_per_sim_s": min(walls) / max(run["done"] * dt, 1e-300),
    }
    if implicit and run["its"]:
        a = np.asarray(run["its"])
        out.update(iter_mean=float(a.mean()), iter_max=int(a.max()))
    return out


# ---------------------------------------------------------------------------------------------------------
# references and sweeps


def rk4_run(sheet: Sheet, dt: float, t_end: float) -> dict:
    """RK4 from rest to t_end; one integrator per sheet (warmed up, compile apart, on first use)."""
    warm = None
    if sheet.rk4 is None:
        sheet.rk4 = ta.make_integrator("rk4", check_every=CHECK_EVERY)
        warm = warm_up(sheet, sheet.rk4, dt)
    r = simulate(sheet, sheet.rk4, dt, t_end)
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


def record(model: str, method: str, tol, r: dict, sheet: Sheet, ref: dict) -> dict:
    """A sweep row: the run without its positions, then model, method, tol, errors, positions."""
    emax, erms = errors(r["x"], ref["x"], sheet.free) if r["status"] == "ok" else (math.nan, math.nan)
    row = {k: v for k, v in r.items() if k != "x"}
    row.update(model=model, method=method, tol=tol, err_max=emax, err_rms=erms, x=r["x"])
    its = f" its {r['iter_mean']:.1f}/{r['iter_max']}" if "iter_mean" in r else ""
    log(
        f"[speed] {model:8s} {method:20s} dt={fmt_dt(r['dt']):>8s} tol={tol or '':<6} "
        f"err={fmt_e(emax, 3):>9s} wall/sim-s={fmt_s(r['wall_per_sim_s']):>9s} {r['status']}{its} {r['note']}"
    )
    return row


def _symplectic_sweep(sheet: Sheet, s: Settings, name: str, ref: dict, warm: dict) -> list:
    integ = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY)
    warm["symplectic_euler"] = warm_up(sheet, integ, s.sym_dts[0])
    rows = []
    for dt in s.sym_dts:
        r = simulate(sheet, integ, dt, s.t_end)
        rows.append(record(name, SYMPLECTIC, None, r, sheet, ref))
        if r["status"] != "ok":
            break
    return rows


def implicit_euler(tol: float, check_every: int):
    """Linearised backward Euler, block-Jacobi PCG, warm start, max IMPLICIT_MAX_ITERATIONS iterations."""
    return ta.IntegratorImplicitEuler(
        linear_solver="pcg",
        tol=tol,
        max_iterations=IMPLICIT_MAX_ITERATIONS,
        warm_start=True,
        check_every=check_every,
    )


def _implicit_sweep(sheet: Sheet, s: Settings, name: str, ref: dict, warm: dict) -> list:
    integ = implicit_euler(s.implicit_tols[0], CHECK_EVERY)
    warm[IMPLICIT] = warm_up(sheet, integ, s.implicit_dts[0])
    rows = []
    for tol in s.implicit_tols:
        integ.linear_solver.tol = tol  # a kernel argument: no recompile
        for dt in s.implicit_dts:
            r = simulate(sheet, integ, dt, s.t_end, implicit=True)
            rows.append(record(name, IMPLICIT, tol, r, sheet, ref))
    return rows


def sweep(sheet: Sheet, s: Settings, name: str, ref: dict) -> tuple[list, dict]:
    """Symplectic Euler until a run fails, then implicit Euler at every tol and dt: (rows, warm-ups)."""
    warm: dict = {}
    rows = _symplectic_sweep(sheet, s, name, ref, warm)
    rows += _implicit_sweep(sheet, s, name, ref, warm)
    return rows, warm


def references_and_sweeps(s: Settings) -> dict:
    """Both models on the s.n² sheet: references, sweeps, warm-ups; the membrane's accelerations for the
    Newton mapping check; the free vertices."""
    refs, rows, warms, acc_ours = {}, [], {}, {}
    for name, material in MATERIALS.items():
        sheet = Sheet(material, s.n)
        refs[name] = reference(sheet, s, name)
        r, warms[name] = sweep(sheet, s, name, refs[name])
        rows += r
        if name == "membrane":
            acc_ours = force_check_ours(sheet)
    return {"refs": refs, "rows": rows, "warms": warms, "acc_ours": acc_ours, "free": sheet.free}


def damping_note(s: Settings) -> dict:
    """Largest stable symplectic-Euler dt (doubling from half the sweep's first dt) of the membrane with
    FabricMaterial's default damping (FABRIC), against the matched-damping membrane of part 1 (its sweep
    rows)."""
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


# ---------------------------------------------------------------------------------------------------------
# accelerations for the Newton mapping check


def accelerations_ours(sheet: Sheet, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """f(x, v) / m of the engine (gravity removed), from one explicit Euler step of dt = 1 s."""
    integ = ta.make_integrator("explicit_euler", check_every=CHECK_EVERY)
    sheet.set(integ, x, v)
    integ.step(sheet.model, sheet.state, 1.0)
    a = sheet.state.particle_v.to_numpy().astype(np.float64) - v
    a[:, 1] += GRAVITY
    sheet.reset(integ)
    return a


def force_check_ours(sheet: Sheet) -> dict:
    """Our accelerations at the mapping-check positions (f64): the in-plane configuration on `sheet`
    (the membrane), the out-of-plane one on a bending-only cloth; each minus the same cloth's at rest."""
    zero = np.zeros_like(sheet.x0)
    configs = force_configs(sheet.x0)

    def change(cloth: Sheet, x: np.ndarray) -> np.ndarray:
        rest = accelerations_ours(cloth, cloth.x0, zero)
        return accelerations_ours(cloth, x, zero) - rest

    out = {IN_PLANE: change(sheet, configs[IN_PLANE])}
    out[OUT_OF_PLANE] = change(Sheet(BENDING_ONLY, sheet.n), configs[OUT_OF_PLANE])
    return out


# ---------------------------------------------------------------------------------------------------------
# the continuum answer


def _refined(material, label: str, s: Settings, factor: int, dt: float) -> tuple[Sheet, dict, dict]:
    """RK4 of `material` on the `factor`x refined mesh: (sheet, run, entry sampled at the coarse
    vertices)."""
    nf = (s.n - 1) * factor + 1
    sheet = Sheet(material, nf)
    r = rk4_run(sheet, dt, s.t_end)
    entry = {"factor": factor, "n": nf, "dt": dt, "wall": r["wall"], "x": r["x"][coarse_index(s.n, factor)]}
    log(f"[continuum] {label} {nf}² RK4 dt={dt:g}: {r['wall']:.1f} s")
    return sheet, r, entry


def _step_check(sheet: Sheet, r: dict, dt: float, t_end: float) -> dict:
    """The refined run again at dt / 2: how much its step contributes."""
    c = rk4_run(sheet, dt / 2, t_end)
    dmax, drms = errors(r["x"], c["x"], sheet.free)
    log(f"[continuum] membrane {sheet.n}² RK4 dt={dt / 2:g}: |x(dt) - x(dt/2)| max {dmax:.2e}")
    return {"dt": dt / 2, "diff_max": dmax, "diff_rms": drms, "wall": c["wall"]}


def continuum(s: Settings) -> dict:
    """The membrane (and springs) on refined meshes, RK4, sampled at the coarse vertices."""
    out = {"membrane": [], "springs": []}
    for factor, dt in s.refine:
        sheet, r, entry = _refined(MEMBRANE, "membrane", s, factor, dt)
        entry["check"] = _step_check(sheet, r, dt, s.t_end) if factor == s.refine_check else None
        out["membrane"].append(entry)
    for factor, dt in s.springs_refine:
        out["springs"].append(_refined(SPRINGS, "springs", s, factor, dt)[2])
    return out


def distances(s: Settings, refs: dict, fine: dict, free: np.ndarray) -> dict:
    """Each converged s.n² answer and each refined run against the finest membrane, at the coarse
    vertices; "rows": (label, (max, RMS), worst grid vertex) for the page."""
    target = fine["membrane"][-1]["x"]
    cont = {"finest": fine["membrane"][-1]["n"], "model_error": {}, "refined": [], "springs_refined": []}
    cont["rows"] = []

    def distance(label: str, x: np.ndarray) -> tuple[float, float]:
        err = errors(x, target, free)
        cont["rows"].append((label, err, worst_vertex(x, target, free, s.n)))
        return err

    for name in MATERIALS:
        cont["model_error"][name] = distance(f"{name}, converged {s.n}² answer", refs[name]["x"])
    for e in fine["membrane"][:-1]:
        err = distance(f"membrane, {e['n']}² (RK4 dt = {fmt_dt(e['dt'])} s)", e["x"])
        cont["refined"].append({"n": e["n"], "err": err, "dt": e["dt"]})
    for e in fine["springs"]:
        err = distance(f"springs on the {e['n']}² mesh (RK4 dt = {fmt_dt(e['dt'])} s)", e["x"])
        cont["springs_refined"].append({"n": e["n"], "err": err, "dt": e["dt"]})
    return cont


def add_continuum_errors(rows: list, target: np.ndarray, free: np.ndarray) -> None:
    """cont_max, cont_rms of every sweep row: its distance from the continuum answer (NaN if it failed)."""
    for r in rows:
        r["cont_max"], r["cont_rms"] = (
            errors(r["x"], target, free) if r["status"] == "ok" else (math.nan, math.nan)
        )
