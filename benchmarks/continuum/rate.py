"""Part 2 (f32): implicit Euler steps per second at dt = 1/60 s, membrane and springs pinned at two
corners, one integrator per model and size, timed step by step at each PCG tolerance."""

from __future__ import annotations

import math

import numpy as np
from common import OtherLoad, clock, fmt_s, log

import taichi_anim as ta

from .config import FRAME, IMPLICIT_MAX_ITERATIONS, MATERIALS, RUN_BUDGET_S, STEPS2_CHECK_EVERY, Settings
from .measure import cpu_seconds, implicit_euler
from .scene import Sheet, errors


def _first_steps(sheet: Sheet, integ) -> tuple[float, float]:
    """Seconds of the first step (JIT compile included) and of the second."""
    sheet.reset(integ)
    times = []
    for _ in range(2):
        a = clock()
        integ.step(sheet.model, sheet.state, FRAME)
        times.append(clock() - a)
    return times[0], times[1]


def _timed_steps(sheet: Sheet, integ, steps: int) -> dict:
    """Up to `steps` steps from rest, each timed, until RUN_BUDGET_S of them; PCG iterations and
    residuals; the divergence error if one came."""
    sheet.reset(integ)
    run = {"times": [], "its": [], "res": [], "diverged": None, "other": OtherLoad(), "cpu0": cpu_seconds()}
    try:
        for _ in range(steps):
            a = clock()
            integ.step(sheet.model, sheet.state, FRAME)
            run["times"].append(clock() - a)
            run["its"].append(int(integ.last_solve.iterations))
            run["res"].append(float(integ.last_solve.residual))
            if sum(run["times"]) > RUN_BUDGET_S:
                break
        sheet.state.check_finite()
    except ta.DivergenceError as e:
        run["diverged"] = str(e)[:80]
    return run


def _row(key: tuple, s: Settings, run: dict, first_second: tuple, x: np.ndarray) -> dict:
    """The table row of one timed run; key = (model, n, tol)."""
    (name, n, tol), (first, second), times = key, first_second, run["times"]
    wall, diverged = sum(times), run["diverged"]
    return {
        "model": name,
        "n": n,
        "tol": tol,
        "steps": len(times),
        "cut": len(times) < s.steps2 and diverged is None,
        "rate": len(times) / wall if wall > 0 else math.nan,
        "median_step": float(np.median(times)),
        "max_step": float(np.max(times)),
        "iter_mean": float(np.mean(run["its"])),
        "iter_max": int(np.max(run["its"])),
        "at_cap": int(sum(i >= IMPLICIT_MAX_ITERATIONS for i in run["its"])),
        "max_residual": float(np.max(run["res"])),
        "first_step": first,
        "second_step": second,
        "compile": max(first - second, 0.0),
        "cores_busy": (cpu_seconds() - run["cpu0"]) / max(wall, 1e-9),
        "other_load": run["other"].cores(),
        "diverged": diverged,
        "finite": diverged is None and bool(np.isfinite(x).all()),
        "vertices": n * n,
    }


def _log(row: dict) -> None:
    log(
        f"[implicit f32] {row['model']:8s} {row['n']}² tol {row['tol']:g}: {row['rate']:.2f} steps/s, "
        f"iterations {row['iter_mean']:.1f}/{row['iter_max']}, first step {fmt_s(row['first_step'])}"
        + (" CUT" if row["cut"] else "")
        + (f" DIVERGED {row['diverged']}" if row["diverged"] else "")
    )


def _add_tol_diff(rows: list, finals: list, sheet: Sheet, steps: int) -> None:
    """The final positions of the loosest and the tightest tol compared (when every run is whole)."""
    if len(rows) > 1 and all(r["steps"] == steps for r in rows):
        dmax, drms = errors(finals[0], finals[-1], sheet.free)
        for r in rows:
            r["tol_diff_max"], r["tol_diff_rms"] = dmax, drms


def model_rows(name: str, n: int, s: Settings) -> list:
    """One model at one size: one integrator, each tol timed from rest."""
    sheet = Sheet(MATERIALS[name], n, pins="corners")
    integ = implicit_euler(s.tols2[0], STEPS2_CHECK_EVERY)
    first_second = _first_steps(sheet, integ)
    rows, finals = [], []
    for tol in s.tols2:
        integ.linear_solver.tol = tol
        run = _timed_steps(sheet, integ, s.steps2)
        finals.append(sheet.positions())
        rows.append(_row((name, n, tol), s, run, first_second, finals[-1]))
        _log(rows[-1])
    _add_tol_diff(rows, finals, sheet, s.steps2)
    return rows


def part2(s: Settings) -> list:
    return [r for n in s.sizes2 for name in ("membrane", "springs") for r in model_rows(name, n, s)]
