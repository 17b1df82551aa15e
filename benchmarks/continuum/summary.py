"""The page's summary: bullet points of the main figures, every number taken from the tables."""

from __future__ import annotations

import numpy as np
from common import fmt_dt, fmt_e, fmt_s

from .config import MATERIALS, SYMPLECTIC, Settings


def _largest_stable(rows: list, model: str) -> dict | None:
    """The model's symplectic-Euler run at its largest stable dt."""
    sel = [r for r in rows if r["model"] == model and r["method"] == SYMPLECTIC and r["status"] == "ok"]
    return max(sel, key=lambda r: r["dt"]) if sel else None


def _most_accurate_implicit(rows: list, model: str) -> dict | None:
    sel = [
        r for r in rows if r["model"] == model and r["method"].startswith("implicit") and r["status"] == "ok"
    ]
    return min(sel, key=lambda r: r["err_max"], default=None)


def symplectic_text(rows: list) -> str | None:
    a, b = _largest_stable(rows, "springs"), _largest_stable(rows, "membrane")
    same = [
        (ra, rb)
        for ra in rows
        for rb in rows
        if ra["model"] == "springs"
        and rb["model"] == "membrane"
        and ra["method"] == rb["method"] == SYMPLECTIC
        and ra["dt"] == rb["dt"]
        and ra["status"] == rb["status"] == "ok"
    ]
    if not (a and b and same):
        return None
    ratio = float(np.median([rb["wall_per_sim_s"] / ra["wall_per_sim_s"] for ra, rb in same]))
    return (
        f"Symplectic Euler: the membrane + bending step costs {ratio:.1f}x the springs' step (median "
        f"over the {len(same)} common dt, f64); both are stable up to dt = {fmt_dt(a['dt'])} s "
        f"(springs) and {fmt_dt(b['dt'])} s (membrane), where the error against the own converged "
        f"answer is {fmt_e(a['err_max'])} m (springs, {fmt_s(a['wall_per_sim_s'])} per simulated s) and "
        f"{fmt_e(b['err_max'])} m (membrane, {fmt_s(b['wall_per_sim_s'])})."
    )


def implicit_text(s: Settings, rows: list) -> str | None:
    imp = {m: _most_accurate_implicit(rows, m) for m in MATERIALS}
    big = max(s.implicit_dts)
    coarse = [
        r for r in rows if r["method"].startswith("implicit") and r["status"] == "ok" and r["dt"] == big
    ]
    if not (all(imp.values()) and coarse):
        return None
    lo, hi = min(r["err_max"] for r in coarse), max(r["err_max"] for r in coarse)
    best = "; ".join(
        f"{m} {fmt_e(r['err_max'])} m at dt = {fmt_dt(r['dt'])} s, tol {r['tol']:g} "
        f"({fmt_s(r['wall_per_sim_s'])} per simulated s)"
        for m, r in imp.items()
    )
    text = (
        f"Implicit Euler (PCG), first order and dissipative: at dt = {fmt_dt(big)} s its "
        f"positions at T are {fmt_e(lo)}–{fmt_e(hi)} m off the converged answers; its most accurate "
        f"runs: {best}."
    )
    sym = {m: _largest_stable(rows, m) for m in MATERIALS}
    beats = all(
        sym[m] is not None
        and sym[m]["err_max"] < imp[m]["err_max"]
        and sym[m]["wall_per_sim_s"] < imp[m]["wall_per_sim_s"]
        for m in MATERIALS
    )
    if beats:
        text += (
            " For both models symplectic Euler at its largest stable dt is both cheaper and more "
            "accurate than that."
        )
    return text


def continuum_text(cont: dict) -> str:
    parts = [f"{label}: {fmt_e(e[0])} m max, {fmt_e(e[1])} m RMS" for label, e, _ in cont["rows"]]
    return f"Distance from the continuum answer ({cont['finest']}² membrane) at T: " + "; ".join(parts) + "."


def rate_text(s: Settings, rows2: list) -> str | None:
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
    if not cells:
        return None
    return f"Implicit Euler at dt = 1/60 s, f32, PCG tol {s.tols2[0]:g}: " + "; ".join(cells) + "."


def newton_text(s: Settings, newton: dict, ours: dict) -> str | None:
    if not newton.get("ran"):
        return None
    v = {x["label"]: x for x in newton["variants"]}
    d, u = v.get("damping mapped"), v.get("no damping")
    if not (d and u):
        return None
    ours_ms = float(np.median(ours["frame_times"])) * 1e3
    newton_ms = np.median(d["frame_times"]) * 1e3
    return (
        f"Newton (Warp CPU, one thread): {newton_ms:.1f} ms per frame "
        f"against our {ours_ms:.1f} ms ({newton_ms / ours_ms:.2f}x) at "
        f"{s.newton_substeps} substeps; final shape: with the mapped damping "
        f"{fmt_e(d['vs_ours'][0])} m from ours (max; Newton's triangle damping also brakes the "
        f"swing), undamped {fmt_e(u['vs_ours_undamped'][0])} m from our undamped run "
        f"(ours damped vs undamped: {fmt_e(ours['vs_undamped'][0])} m)."
    )


def summary(s: Settings, d: dict) -> str:
    """Bullet points of the main figures, every number taken from the tables below."""
    texts = [
        symplectic_text(d["rows"]),
        implicit_text(s, d["rows"]),
        continuum_text(d["cont"]),
        rate_text(s, d["rows2"]),
        newton_text(s, d["newton"], d["ours"]),
    ]
    return "\n".join(f"- {t}" for t in texts if t is not None)
