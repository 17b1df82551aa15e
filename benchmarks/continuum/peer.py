"""Part 3 (f32): our symplectic Euler on the part-1 scene at Newton's substep, and Newton's
semi-implicit triangle FEM (benchmarks/peers/newton_fem.py) on the same cloth, with the mapped damping and
without; the accelerations of both engines compared at the same positions."""

from __future__ import annotations

import shutil
import tempfile

import numpy as np
from common import clock, fmt_s, log
from peers import newton_fem

import taichi_anim as ta

from .config import CHECK_EVERY, FRAME, GRAVITY, IN_PLANE, MEMBRANE, OUT_OF_PLANE, SIDE, Settings
from .measure import accelerations_ours, cpu_seconds
from .scene import Sheet, errors, force_configs, interior

# ---------------------------------------------------------------------------------------------------------
# ours


def _timed_frames(sheet: Sheet, integ, dt: float, substeps: int, frames: int) -> dict:
    """A first frame (compile included) apart, then `frames` frames from rest, each timed and each
    ending with the positions copied to NumPy."""

    def frame():
        for _ in range(substeps):
            integ.step(sheet.model, sheet.state, dt)
        return sheet.state.particle_x.to_numpy()

    sheet.reset(integ)
    a = clock()
    frame()
    first = clock() - a
    sheet.reset(integ)
    times = []
    c0 = cpu_seconds()
    for _ in range(frames):
        a = clock()
        x = frame()
        times.append(clock() - a)
    return {"first": first, "times": times, "x": x, "cores": (cpu_seconds() - c0) / sum(times)}


def ours_frames(s: Settings, material) -> dict:
    """taichi_anim symplectic Euler on the part-1 scene with `material` at Newton's dt, f32, frames
    timed (first frame, with the compile, apart); the residual acceleration at the rest state."""
    sheet = Sheet(material, s.n)
    integ = ta.make_integrator("symplectic_euler", check_every=CHECK_EVERY)
    dt = FRAME / s.newton_substeps
    frames = round(s.t_end / FRAME)
    run = _timed_frames(sheet, integ, dt, s.newton_substeps, frames)
    sheet.state.check_finite()
    rest = accelerations_ours(sheet, sheet.x0, np.zeros_like(sheet.x0))
    return {
        "rest_residual": float(np.max(np.linalg.norm(rest[sheet.free], axis=1))),
        "first_frame": run["first"],
        "frame_times": run["times"],
        "x": run["x"].astype(np.float64),
        "cores_busy": run["cores"],
        "sheet": sheet,
        "dt": dt,
        "frames": frames,
    }


# ---------------------------------------------------------------------------------------------------------
# Newton


def _cloth(sheet: Sheet, params: dict):
    return newton_fem.NewtonCloth(
        sheet.x0, sheet.triangles, sheet.pinned, density=MEMBRANE.density, params=params, gravity=GRAVITY
    )


def _compare(an: np.ndarray, at: np.ndarray, inner: np.ndarray, comp: slice, component: str) -> dict:
    """Newton's accelerations `an` against ours `at` over the interior vertices, components `comp`."""
    d = an[inner][:, comp] - at[inner][:, comp]
    ref_norm = np.linalg.norm(at[inner][:, comp], axis=1)
    return {
        "rel_max": float(np.max(np.linalg.norm(d, axis=1)) / np.max(ref_norm)),
        "rel_rms": float(np.sqrt(np.mean(np.sum(d * d, axis=1))) / np.sqrt(np.mean(ref_norm**2))),
        "norm_ratio": float(np.linalg.norm(an[inner][:, comp]) / np.linalg.norm(at[inner][:, comp])),
        "scale": float(np.max(ref_norm)),
        "component": component,
    }


def _force_check(sheet: Sheet, cloth, params: dict, acc_ours: dict) -> tuple[float, dict]:
    """(Newton's largest rest-state acceleration over the free vertices of `cloth`, the checks): the
    in-plane configuration on `cloth`, the out-of-plane one on a bending-only Newton cloth."""
    inner, zero, configs = interior(sheet.n), np.zeros_like(sheet.x0), force_configs(sheet.x0)
    bend = _cloth(sheet, dict(params, tri_ke=0.0, tri_ka=0.0, tri_kd=0.0, edge_kd=0.0))
    checks, rest_residual = {}, None
    for cname, c, comp in ((IN_PLANE, cloth, slice(None)), (OUT_OF_PLANE, bend, slice(1, 2))):
        # The rest state is not force-free in f32 (positions rounded to f32, rest shape from the f64
        # grid): each cloth's acceleration there is subtracted.
        rest_n = c.accelerations(sheet.x0, zero, GRAVITY)
        if c is cloth:
            rest_residual = float(np.max(np.linalg.norm(rest_n[sheet.free], axis=1)))
        an = c.accelerations(configs[cname], zero, GRAVITY) - rest_n
        checks[cname] = _compare(an, acc_ours[cname], inner, comp, "all" if c is cloth else "y (normal)")
        log(
            f"[newton] force check {cname}: relative difference max "
            f"{checks[cname]['rel_max']:.2e} rms {checks[cname]['rel_rms']:.2e}, |a_Newton| / "
            f"|a_ours| = {checks[cname]['norm_ratio']:.3f} (largest |a_ours| "
            f"{checks[cname]['scale']:.2e} m/s²)"
        )
    return rest_residual, checks


def _variant(s: Settings, ours: dict, ours_undamped: dict, refs: dict, label: str, damped: bool) -> tuple:
    """Newton with (damped) or without the mapped damping, timed over the frames of `ours`:
    (the variant's record, the Newton cloth, the timed frames)."""
    sheet, cell, m = ours["sheet"], SIDE / (s.n - 1), MEMBRANE
    params = newton_fem.mapping(
        youngs=m.youngs_modulus,
        poisson=m.poisson_ratio,
        bending=m.bending_stiffness,
        damping=m.damping,
        bending_damping=m.bending_damping,
        cell=cell,
        damped=damped,
    )
    cloth = _cloth(sheet, params)
    mass_diff = float(np.max(np.abs(cloth.mass - sheet.mass)) / np.max(sheet.mass))
    c0 = cpu_seconds()
    r = newton_fem.timed_frames(cloth, ours["dt"], s.newton_substeps, ours["frames"], clock)
    cores = (cpu_seconds() - c0) / (r["first_frame"] + sum(r["frame_times"]))
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
        "vs_ref": errors(x, refs["membrane"]["x"], sheet.free),
        "vs_springs_ref": errors(x, refs["springs"]["x"], sheet.free),
        "x_corner": x[-1].tolist(),
    }
    return v, cloth, r


def _log_variant(v: dict, cloth, r: dict) -> None:
    log(
        f"[newton] {v['label']}: {np.median(r['frame_times']) * 1e3:.1f} ms/frame (median), first frame "
        f"{fmt_s(r['first_frame'])}, finalize {fmt_s(cloth.finalize_s)}; vs ours max "
        f"{v['vs_ours'][0]:.2e} m, vs f64 reference max {v['vs_ref'][0]:.2e} m"
    )


def newton_part(s: Settings, ours: dict, ours_undamped: dict, refs: dict, acc_ours: dict) -> dict:
    """Newton on the cloth of `ours` (Warp's kernel cache in a fresh folder), or why it did not run."""
    reason = newton_fem.available()
    if reason is not None:
        log(f"[newton] not run: {reason}")
        return {"ran": False, "reason": reason}
    cache = tempfile.mkdtemp(prefix="newton_kernel_cache_")
    try:
        winit = newton_fem.init_warp(cache)
        out = {"ran": True, "versions": newton_fem.versions(), "warp_init_s": winit["init_s"], "variants": []}
        for label, damped in (("damping mapped", True), ("no damping", False)):
            v, cloth, r = _variant(s, ours, ours_undamped, refs, label, damped)
            if damped:
                v["linearisation_check"] = newton_fem.linearisation_check(v["params"])
                v["rest_residual"], v["force_check"] = _force_check(
                    ours["sheet"], cloth, v["params"], acc_ours
                )
                cloth.reset()
            out["variants"].append(v)
            _log_variant(v, cloth, r)
        return out
    finally:
        shutil.rmtree(cache, ignore_errors=True)
