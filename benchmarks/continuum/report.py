"""Write cloth_continuum_speed.{md,json,png} from the measurements (the plain dicts of run.measure)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
from common import command_line, fmt_dt, fmt_s, log, machine_info, machine_table, md_table

from taichi_anim.scenes.cloth import FABRIC

from . import tables as tb
from .config import (
    BETA,
    GRAVITY,
    HEIGHT,
    IMPLICIT_MAX_ITERATIONS,
    LOADED_CORES,
    MATERIALS,
    MAX_REPEATS,
    MIN_RUN_TIME,
    RUN_BUDGET_S,
    SIDE,
    SNAPSHOTS,
    STEPS2_CHECK_EVERY,
    WARM_STEPS,
    Settings,
)
from .plot import plot
from .summary import summary

NAME = "cloth_continuum_speed"


def _timing_note(others: float) -> str:
    return (
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


def _machine(d: dict) -> str:
    return machine_table(
        machine_info(),
        load_start=d["load_start"],
        load_end=d["load_end"],
        date=d["date"],
        engine=d["engine"],
        other=d["other"],
    )


def _header(args, d: dict) -> str:
    phase_text = ", ".join(f"{k} {v:.0f} s" for k, v in d["phase"].items())
    return (
        "# Springs vs membrane + bending: speed against error, the continuum answer, Newton's FEM\n\n"
        f"Regenerate: `{command_line(args, 'cloth_continuum_speed.py')}` (took {d['total'] / 60:.1f} min: "
        f"{phase_text}). The module docstring of `benchmarks/cloth_continuum_speed.py` describes the method; "
        "the Newton peer and its parameter mapping are in `benchmarks/peers/newton_fem.py`.\n\n"
        f"{_timing_note(d['other_cores'])}\n\n{d['machine_md']}\n\n"
    )


def _scene(s: Settings) -> str:
    n = s.n
    return (
        "## Scene and materials\n\n"
        f"{n}² vertices, {SIDE:g} m square, {0.2:g} kg/m² lumped by triangle area, edge j = 0 pinned "
        f"({n} vertices), gravity {GRAVITY:g} m/s², starts flat and at rest at y = {HEIGHT:g} m, T = "
        f"{s.t_end:g} s; no drag, no colliders.\n\n"
        f"- **springs**: {tb.material_text('springs')};\n"
        f"- **membrane**: {tb.material_text('membrane')}. Same stretch stiffness (the areal Young's "
        "modulus of a grid of stretch springs k is about k) and the same stiffness-proportional damping of "
        "stretching "
        f"(beta = {BETA:g} s; FabricMaterial's default is {FABRIC.damping:g} s, see below).\n\n"
    )


def _part1_method(s: Settings, d: dict, png: str) -> str:
    n, finest = s.n, d["finest"]
    return (
        "## 1. Speed against error (f64)\n\n"
        f"Each model against its own converged answer (RK4 at dt = {s.ref_dt:g} s, checked against RK4 at "
        f"{2 * s.ref_dt:g} s: RK4's error falls ~16x per halving, so the reference's own error is ~1/15 of "
        "the check difference), and against the continuum answer: the membrane on the "
        f"{finest['n']}² mesh ({finest['factor']}x refined: every {n}² vertex is a vertex of it), RK4 at "
        f"dt = {finest['dt']:.3g} s. Symplectic Euler at dt = {', '.join(fmt_dt(t) for t in s.sym_dts)} s "
        "in that order until a run fails; implicit "
        f"Euler (PCG, warm start, max {IMPLICIT_MAX_ITERATIONS} iterations) at dt = "
        f"{', '.join(fmt_dt(t) for t in s.implicit_dts)} s and tol "
        f"{', '.join(f'{t:g}' for t in s.implicit_tols)}. "
        f"Errors: max and RMS over the {int(d['free'].sum())} free vertices of |x(T) - x_ref(T)|. Wall time "
        "per simulated second, f64, Taichi's default thread count; positions read back "
        f"{SNAPSHOTS} times per run outside the timed segments; runs under {MIN_RUN_TIME} s repeated up to "
        f"{MAX_REPEATS} times (fastest kept).\n\n"
        f"![speed against error]({png})\n\n"
        f"**Symplectic Euler's stability limit.** {tb.stable_limit_text(d['rows'])}.\n\n"
    )


def _part1_tables(s: Settings, d: dict) -> str:
    n, nf = s.n, d["finest"]["n"]
    return (
        "**Cheapest run for each error target** (against the model's own converged answer; wall time per "
        "simulated second, dt, tol), and the smallest errors reached:\n\n"
        + md_table(tb.BEST_HEADERS, tb.best_rows(d["rows"]))
        + "\n\n**How far each model's cloth is from the continuum answer** (positions at T of the "
        f"{n}² coarse vertices against the {nf}² membrane at the same material points, max / RMS [m]):\n\n"
        + md_table(
            [
                "answer",
                "distance from the continuum answer, max / RMS [m]",
                "largest at grid vertex (i, j) (j = 0: pinned edge)",
            ],
            tb.continuum_rows(d, n),
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
            tb.reference_rows(d["refs"]),
        )
        + "\n\nRefined meshes (RK4, f64):\n\n"
        + md_table(["model", "grid", "dt [s]", "wall", "time-step check"], tb.fine_rows(d["fine"]))
        + "\n\nEvery run (◆: on the Pareto front of all runs of both models, error against the own "
        "reference; ●: on the joint front of error against the continuum answer):\n\n"
        + md_table(tb.speed_headers(nf), tb.speed_rows(d["rows"]))
        + "\n\n"
    )


def _part1_notes(s: Settings, d: dict) -> str:
    note = d["note"]
    tried = ", ".join(f"{t['dt']:.3g} s {t['status']}" for t in note["tried"])
    return (
        "**Default membrane damping.** FabricMaterial's default Rayleigh damping "
        f"({note['damping']:g} s, "
        f"bending {note['bending_damping']:g} s; the demos' FABRIC) on the same {s.n}² scene, symplectic "
        f"Euler from dt = {s.sym_dts[0] / 2:g} s doubling: {tried}. The matched-damping membrane above runs "
        'up to the dt given under "Symplectic Euler\'s stability limit". Implicit Euler is not limited by '
        "it.\n\n"
        "**JIT compile** (first "
        f"{WARM_STEPS} steps, compile included, against the same steps again):\n\n"
        + md_table(
            ["model", "integrator", "first steps", "again", "compile"], tb.warm_rows(d["warms"], d["refs"])
        )
        + "\n\n"
    )


def _part2(s: Settings, d: dict) -> str:
    return (
        "## 2. Implicit steps per second at dt = 1/60 s (f32)\n\n"
        f"Implicit Euler, one step per frame, PCG (block Jacobi), warm start, max {IMPLICIT_MAX_ITERATIONS} "
        f"iterations, `check_every` = {STEPS2_CHECK_EVERY}; the same fabrics on a 1 m square pinned at the "
        "two "
        f"corners of one edge; {s.steps2} steps timed one by one after two warm-up steps (the first holds "
        f"the compile); runs past {RUN_BUDGET_S:g} s of timed steps are cut. The last column pair "
        "compares the final positions of the two tolerances (an estimate of the looser one's solver "
        "error).\n\n" + md_table(tb.rate_headers(s), tb.rate_rows(d["rows2"])) + "\n\n"
    )


def _newton_setup(s: Settings, d: dict) -> str:
    newton, ours, first = d["newton"], d["ours"], d["newton"]["variants"][0]
    counts = ", ".join(f"{k}: {v}" for k, v in first["counts"].items())
    return (
        "## 3. Newton's semi-implicit triangle FEM, same scene\n\n"
        f"Newton {newton['versions']['newton']} on warp-lang {newton['versions']['warp-lang']}, CPU "
        f'(`wp.set_device("cpu")`), `SolverSemiImplicit(model, enable_tri_contact=False)`, '
        "`model.particle_grid = None` (no contacts, as in our scene); the cloth built with "
        "`ModelBuilder(up_axis=Y, gravity=(0, -9.81, 0)).add_cloth_mesh` from our grid's vertices and "
        f"triangles ({counts}); vertex masses "
        f"equal ours to {first['mass_rel_diff']:.1e} (relative); {s.n} pinned vertices with mass 0 and "
        f"not ACTIVE. Frame 1/60 s × {s.newton_substeps} substeps (dt = {ours['dt']:.4g} s), "
        f"{ours['frames']} frames (T = {s.t_end:g} s), positions copied to NumPy each frame. Ours: "
        "`symplectic_euler` on the same scene and dt, f32, `check_every` = 10^9, positions read each "
        "frame, with the membrane's damping and with none (damping = bending_damping = 0), the "
        "counterpart of Newton's undamped run.\n\n"
    )


def _newton_mapping(d: dict) -> str:
    damped = d["newton"]["variants"][0]
    return (
        "**Mapping** (derivation in `benchmarks/peers/newton_fem.py`): Newton's triangle is a 2D stable "
        "neo-Hookean (psi = k_mu/2 (tr FᵀF - 2) + k_lambda/2 (J - 1 - k_mu/k_lambda)² per rest area), "
        "whose linearisation has Lamé parameters mu_L = tri_ke, lambda_L = tri_ka - tri_ke; ours "
        "(StVK, plane stress) has mu_L = E/(2(1+nu)), lambda_L = E nu/(1-nu²). Damped run: "
        f"{damped['mapping_text']}. Undamped run: tri_kd = edge_kd = 0. The NumPy check of that "
        "linearisation (random in-plane H ~ 1e-4): largest relative difference "
        f"{damped.get('linearisation_check', math.nan):.1e}.\n\n"
    )


def _newton_check(d: dict) -> str:
    damped = d["newton"]["variants"][0]
    return (
        "**Mapping check: accelerations f/m of both engines at the same positions** (zero velocity; "
        "interior vertices, 2 rows from every edge; ours f64, Newton f32; relative = |a_Newton - "
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
        f"{d['ours']['rest_residual']:.1e} m/s² in ours (f32), against 9.81 m/s² for gravity: both "
        "simulations start with this round-off in their forces.\n\n"
        + md_table(tb.FORCE_HEADERS, tb.force_rows(damped.get("force_check", {})))
        + "\n\n"
    )


def _newton_results(s: Settings, d: dict) -> str:
    newton, first = d["newton"], d["newton"]["variants"][0]
    compile_s = first["first_frame"] - float(np.median(first["frame_times"]))
    return (
        "**Time per frame** (median and mean over the frames after a first frame; Newton's first "
        "frame holds the cold compile of its solver modules, Warp's kernel cache in a fresh folder: "
        f"{fmt_s(compile_s)}; `finalize` of the first model, which compiles Newton's mesh and BVH "
        f"modules, took {fmt_s(first['finalize_s'])}; Warp init {fmt_s(newton['warp_init_s'])}). "
        "Cores busy = process CPU time / wall time over the frames (Warp runs CPU kernels on one "
        "thread, Taichi on its default thread count):\n\n"
        + md_table(tb.FRAME_HEADERS, tb.frame_rows(d, s.newton_substeps))
        + f"\n\n**Final shape at T = {s.t_end:g} s** (max / RMS over the {int(d['free'].sum())} free "
        "vertices of the distance between positions [m]):\n\n"
        + md_table(tb.SHAPE_HEADERS, tb.shape_rows(d))
        + "\n"
    )


def _newton(s: Settings, d: dict) -> str:
    if not d["newton"]["ran"]:
        return (
            "## 3. Newton's semi-implicit triangle FEM\n\n"
            f"**Not run**: `{d['newton']['reason']}`. Install the optional extra (`.venv/bin/pip install -e "
            "'.[newton]'`: newton==1.8.0 with warp-lang==1.19.0, the `bench` pin) and run again.\n"
        )
    return _newton_setup(s, d) + _newton_mapping(d) + _newton_check(d) + _newton_results(s, d)


def page(args, s: Settings, d: dict, png: str) -> str:
    """The markdown page."""
    return "".join(
        [
            _header(args, d),
            "## Summary\n\n" + summary(s, d) + "\n\n",
            _scene(s),
            _part1_method(s, d, png),
            _part1_tables(s, d),
            _part1_notes(s, d),
            _part2(s, d),
            _newton(s, d),
        ]
    )


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


def raw(s: Settings, d: dict) -> dict:
    """Everything measured, for the JSON file (json_clean drops the positions)."""
    return {
        "settings": dataclasses.asdict(s),
        "materials": {k: dataclasses.asdict(v) for k, v in MATERIALS.items()},
        "references": d["refs"],
        "runs": d["rows"],
        "continuum": {**d["cont"], "fine": d["fine"]},
        "model_gap": d["model_gap"],
        "default_damping": d["note"],
        "implicit_f32": d["rows2"],
        "ours_frames": d["ours"],
        "ours_frames_undamped": d["ours_undamped"],
        "ours_vs_ref": d["ours_vs_ref"],
        "newton": d["newton"],
        "machine": machine_info(),
        "load": [d["load_start"], d["load_end"]],
        "other_load_cores": d["other_cores"],
        "phases_s": d["phase"],
        "total_s": d["total"],
    }


def report(args, s: Settings, out_dir, d: dict) -> None:
    """Write cloth_continuum_speed.{md,json,png} from the measurements of run.measure."""
    png = out_dir / f"{NAME}.png"
    plot(d["rows"], d["cont"], d["rows2"], png, s)
    machine = _machine(d)  # reads the other processes' load first, then the note and JSON read it again
    d = {**d, "machine_md": machine, "other_cores": d["other"].cores()}
    (out_dir / f"{NAME}.md").write_text(page(args, s, d, png.name))
    (out_dir / f"{NAME}.json").write_text(json.dumps(json_clean(raw(s, d)), indent=1))
    log(f"wrote {out_dir}/{NAME}.{{md,json,png}} in {d['total'] / 60:.1f} min")
