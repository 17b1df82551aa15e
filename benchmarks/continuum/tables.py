"""Rows (and headers) of the page's tables, from the measurements' plain dicts."""

from __future__ import annotations

import math

import numpy as np
from common import fmt_dt, fmt_e, fmt_s

from .config import FORCE_AMPLITUDE, FRAME, IMPLICIT, IMPLICIT_MAX_ITERATIONS, MATERIALS, SYMPLECTIC, Settings
from .scene import worst_vertex

TARGETS = (1e-1, 1e-2, 1e-3)  # [m] error targets of the "cheapest run" table


def pair(e) -> str:
    """'max / RMS' of an (max, RMS) pair."""
    return f"{fmt_e(e[0])} / {fmt_e(e[1])}"


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


# ---------------------------------------------------------------------------------------------------------
# part 1


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


def speed_headers(nf: int) -> list:
    return [
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


def speed_rows(rows: list) -> list:
    """Every run; ◆ on the Pareto front against the own reference, ● against the continuum answer."""
    front_own = {id(r) for r in pareto(rows, "err_max")}
    front_cont = {id(r) for r in pareto(rows, "cont_max")}
    out = []
    for r in rows:
        mark = ("◆" if id(r) in front_own else "") + ("●" if id(r) in front_cont else "")
        its = f"{r['iter_mean']:.1f} / {r['iter_max']}" if "iter_mean" in r else "–"
        status = "ok" if r["status"] == "ok" else f"**{r['status'].upper()}** ({r['note']})"
        tol = f"{r['tol']:g}" if r["tol"] else "–"
        errs = [
            f"{fmt_e(r['err_max'])} / {fmt_e(r['err_rms'])}",
            f"{fmt_e(r['cont_max'])} / {fmt_e(r['cont_rms'])}",
        ]
        cells = [r["model"], f"{r['method']} {mark}".strip(), fmt_dt(r["dt"]), tol, r["steps"]]
        out.append([*cells, fmt_s(r["wall_per_sim_s"]), its, *errs, status])
    return out


BEST_HEADERS = [
    "model",
    "method",
    *[f"cheapest with error ≤ {t:g} m" for t in TARGETS],
    "smallest error vs own reference",
    "smallest error vs continuum",
]


def _cheapest(sel: list, target: float) -> str:
    ok = [r for r in sel if r["err_max"] <= target]
    if not ok:
        return "–"
    b = min(ok, key=lambda r: r["wall_per_sim_s"])
    tol = f", tol {b['tol']:g}" if b["tol"] else ""
    return f"{fmt_s(b['wall_per_sim_s'])} ({fmt_dt(b['dt'])}{tol})"


def _smallest(sel: list, key: str) -> str:
    if not sel:
        return "–"
    low = min(sel, key=lambda r: r[key])
    return f"{fmt_e(low[key])} ({fmt_dt(low['dt'])}, {fmt_s(low['wall_per_sim_s'])})"


def best_rows(rows: list) -> list:
    out = []
    for model in MATERIALS:
        for method in (SYMPLECTIC, IMPLICIT):
            sel = [r for r in rows if r["model"] == model and r["method"] == method and r["status"] == "ok"]
            cells = [_cheapest(sel, t) for t in TARGETS]
            out.append([model, method, *cells, _smallest(sel, "err_max"), _smallest(sel, "cont_max")])
    return out


def stable_limit_text(rows: list) -> str:
    parts = []
    for model in MATERIALS:
        sel = [r for r in rows if r["model"] == model and r["method"] == SYMPLECTIC]
        ok = [r["dt"] for r in sel if r["status"] == "ok"]
        bad = [r["dt"] for r in sel if r["status"] != "ok"]
        parts.append(
            f"{model}: stable up to {max(ok):.3g} s" + (f", unstable at {min(bad):.3g} s" if bad else "")
            if ok
            else f"{model}: no stable run"
        )
    return "; ".join(parts)


def reference_rows(refs: dict) -> list:
    return [
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


def continuum_rows(d: dict, n: int) -> list:
    """The distances from the continuum answer, and the springs-membrane gap for scale."""
    rows = [[label, pair(e), where] for label, e, where in d["cont"]["rows"]]
    gap = worst_vertex(d["refs"]["springs"]["x"], d["refs"]["membrane"]["x"], d["free"], n)
    rows.append([f"(scale) springs vs membrane, both converged at {n}²", pair(d["model_gap"]), gap])
    return rows


def fine_rows(fine: dict) -> list:
    rows = []
    for kind, e in [("membrane", e) for e in fine["membrane"]] + [("springs", e) for e in fine["springs"]]:
        chk = e.get("check")
        check = (
            "–"
            if not chk
            else f"RK4 at dt = {fmt_dt(chk['dt'])} s: |x(dt) - x(dt/2)| max {fmt_e(chk['diff_max'])}, RMS "
            f"{fmt_e(chk['diff_rms'])} ({fmt_s(chk['wall'])})"
        )
        rows.append([kind, f"{e['n']}²", fmt_dt(e["dt"]), fmt_s(e["wall"]), check])
    return rows


def warm_rows(warms: dict, refs: dict) -> list:
    return [
        [name, method, fmt_s(w["first"]), fmt_s(w["steady"]), fmt_s(w["compile"])]
        for name in MATERIALS
        for method, w in list(warms[name].items()) + [("RK4 (reference)", refs[name]["warm"])]
    ]


# ---------------------------------------------------------------------------------------------------------
# part 2


def rate_headers(s: Settings) -> list:
    return [
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


def rate_rows(rows2: list) -> list:
    out = []
    for r in rows2:
        rate = (
            f"**{r['rate']:.3g}**" + (" (cut)" if r["cut"] else "") + (" DIVERGED" if not r["finite"] else "")
        )
        diff = "–" if "tol_diff_max" not in r else f"{fmt_e(r['tol_diff_max'])} / {fmt_e(r['tol_diff_rms'])}"
        its = f"{r['iter_mean']:.1f} / {r['iter_max']}"
        cells = [
            r["model"],
            f"{r['n']}²",
            r["vertices"],
            f"{r['tol']:g}",
            rate,
            f"{r['median_step'] * 1e3:.1f}",
        ]
        timing = [
            fmt_s(r["first_step"]),
            fmt_s(r["compile"]),
            f"{r['cores_busy']:.2f}",
            f"{r['other_load']:.2f}",
        ]
        out.append([*cells, its, r["at_cap"], fmt_e(r["max_residual"]), diff, *timing])
    return out


# ---------------------------------------------------------------------------------------------------------
# part 3


FORCE_HEADERS = [
    "configuration",
    "component",
    "amplitude [m]",
    "largest |a_ours| [m/s²]",
    "relative max",
    "relative RMS",
    "\\|a_Newton\\| / \\|a_ours\\| (2-norms over the vertices)",
]
FRAME_HEADERS = [
    "engine",
    "median ms / frame",
    "mean ms / frame",
    "µs / substep",
    "first frame",
    "cores busy",
    "time / ours",
]
SHAPE_HEADERS = [
    "run",
    "vs our membrane run (same dt, f32)",
    "vs our undamped membrane run (same dt, f32)",
    "vs our converged membrane (RK4, f64)",
    "vs our converged springs (RK4, f64)",
    "finite",
]


def force_rows(checks: dict) -> list:
    return [
        [
            k,
            c["component"],
            f"{FORCE_AMPLITUDE[k]:g}",
            fmt_e(c["scale"]),
            fmt_e(c["rel_max"]),
            fmt_e(c["rel_rms"]),
            f"{c['norm_ratio']:.3f}",
        ]
        for k, c in checks.items()
    ]


def _frame_row(engine: str, run: dict, substeps: int, ours_ms: float) -> list:
    med = float(np.median(run["frame_times"])) * 1e3
    return [
        engine,
        f"{med:.1f}",
        f"{np.mean(run['frame_times']) * 1e3:.1f}",
        f"{med / substeps * 1e3:.0f}",
        fmt_s(run["first_frame"]),
        f"{run['cores_busy']:.2f}",
        f"{med / ours_ms:.2f}",
    ]


def frame_rows(d: dict, substeps: int) -> list:
    """ms per frame: our damped and undamped runs, then each Newton variant."""
    ours_ms = float(np.median(d["ours"]["frame_times"])) * 1e3
    runs = [
        (f"taichi_anim membrane, {label} (symplectic Euler, f32, Taichi threads)", o)
        for label, o in (("damped", d["ours"]), ("no damping", d["ours_undamped"]))
    ]
    runs += [(f"Newton SolverSemiImplicit, {v['label']} (f32, Warp CPU)", v) for v in d["newton"]["variants"]]
    return [_frame_row(engine, run, substeps, ours_ms) for engine, run in runs]


def shape_rows(d: dict) -> list:
    """Final shapes: each Newton variant, then ours, against our runs and converged answers."""
    ours, undamped = d["ours"], d["ours_undamped"]
    rows = [
        [
            f"Newton, {v['label']}",
            pair(v["vs_ours"]),
            pair(v["vs_ours_undamped"]),
            pair(v["vs_ref"]),
            pair(v["vs_springs_ref"]),
            "yes" if v["finite"] else "**no**",
        ]
        for v in d["newton"]["variants"]
    ]
    return rows + [
        [
            "taichi_anim membrane, damped, same dt, f32 (scale: our own step and round-off error)",
            "0",
            pair(ours["vs_undamped"]),
            pair(d["ours_vs_ref"]),
            "–",
            "yes",
        ],
        [
            "taichi_anim membrane, no damping, same dt, f32",
            pair(ours["vs_undamped"]),
            "0",
            pair(undamped["vs_ref"]),
            "–",
            "yes",
        ],
        ["(scale) springs vs membrane, both converged (f64)", pair(d["model_gap"]), "", "", "", ""],
    ]
