"""The order of the benchmark: part 1 (f64), part 3 (f32: ours, then Newton), part 2 (f32), the report."""

from __future__ import annotations

import time

from common import OtherLoad, engine_fingerprint, init, load_average, output_paths, parse_args

from .config import FULL, MEMBRANE, MEMBRANE_UNDAMPED, QUICK, Settings
from .measure import add_continuum_errors, continuum, damping_note, distances, references_and_sweeps
from .peer import newton_part, ours_frames
from .rate import part2
from .report import report
from .scene import errors


def _timed(phase: dict, name: str, fn, *args):
    """fn(*args), its wall time recorded as phase[name]."""
    t0 = time.perf_counter()
    out = fn(*args)
    phase[name] = time.perf_counter() - t0
    return out


def _sweeps(s: Settings) -> dict:
    init("f64")
    return references_and_sweeps(s)


def part1(s: Settings, phase: dict) -> dict:
    """References, sweeps, default damping, refined meshes (f64); distances from the continuum answer."""
    d = _timed(phase, "part 1: references and sweeps", _sweeps, s)
    d["note"] = _timed(phase, "part 1: default-damping stability", damping_note, s)
    d["fine"] = _timed(phase, "part 1: refined meshes", continuum, s)
    d["finest"] = d["fine"]["membrane"][-1]
    d["cont"] = distances(s, d["refs"], d["fine"], d["free"])
    add_continuum_errors(d["rows"], d["finest"]["x"], d["free"])
    d["model_gap"] = errors(d["refs"]["springs"]["x"], d["refs"]["membrane"]["x"], d["free"])
    return d


def part3(s: Settings, d: dict) -> dict:
    """Our membrane, damped and undamped, at Newton's step (f32), then Newton on the same cloth."""
    init("f32")
    ours = ours_frames(s, MEMBRANE)
    undamped = ours_frames(s, MEMBRANE_UNDAMPED)
    membrane, free = d["refs"]["membrane"]["x"], d["free"]
    ours_vs_ref = errors(ours["x"], membrane, free)
    ours["vs_undamped"] = errors(ours["x"], undamped["x"], free)
    undamped["vs_ref"] = errors(undamped["x"], membrane, free)
    newton = newton_part(s, ours, undamped, d["refs"], d["acc_ours"])
    return {"ours": ours, "ours_undamped": undamped, "ours_vs_ref": ours_vs_ref, "newton": newton}


def main(doc: str) -> None:
    """The command line of benchmarks/cloth_continuum_speed.py (`doc`: its docstring)."""
    args = parse_args(doc.splitlines()[0])
    _, out_dir = output_paths(args)
    out_dir.mkdir(parents=True, exist_ok=True)
    s = QUICK if args.quick else FULL
    d = {"load_start": load_average(), "engine": engine_fingerprint(), "other": OtherLoad()}
    d["date"] = time.strftime("%Y-%m-%d %H:%M %Z")
    started = time.perf_counter()
    phase: dict = {}
    d.update(part1(s, phase))
    d.update(_timed(phase, "part 3: ours and Newton", part3, s, d))
    d["rows2"] = _timed(phase, "part 2: implicit steps/s", part2, s)
    d.update(total=time.perf_counter() - started, phase=phase, load_end=load_average())
    report(args, s, out_dir, d)
