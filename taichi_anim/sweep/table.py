"""A sweep's results as one table: the error of each run against its reference run, written as CSV
(always) and Parquet (when pyarrow imports), a plot of speed against error (when matplotlib imports),
and a short text table for the terminal."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path


def rms_distance(final: dict, reference: dict) -> float:
    """Root mean square distance [m] between the final positions of the particles alive in both runs."""
    both = _common(final, reference)
    d = final["x"][both] - reference["x"][both]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1)))) if both.any() else math.nan


def max_distance(final: dict, reference: dict) -> float:
    """Largest distance [m] between the final positions of a particle alive in both runs."""
    both = _common(final, reference)
    d = final["x"][both] - reference["x"][both]
    return float(np.max(np.linalg.norm(d, axis=1))) if both.any() else math.nan


METRICS: dict[str, Callable[[dict, dict], float]] = {"rms": rms_distance, "max": max_distance}


def _common(final: dict, reference: dict) -> np.ndarray:
    if final["x"].shape != reference["x"].shape:
        raise ValueError(
            f"the runs have {len(final['x'])} and {len(reference['x'])} particles: their positions "
            "cannot be compared"
        )
    return np.asarray(final["alive"], bool) & np.asarray(reference["alive"], bool)


def add_errors(rows: list[dict], finals: list, references: list, metric: Callable) -> None:
    """Set rows[k]["error"] to metric(final k, final of run references[k]) (None without a reference or
    where either run has no final state; NaN with a note in "message" where they cannot be compared)."""
    for row, final, ref in zip(rows, finals, references, strict=True):
        row["reference"] = None if ref is None else rows[ref]["run_id"]
        row["error"] = None
        if ref is None or final is None or finals[ref] is None:
            continue
        try:
            row["error"] = float(metric(final, finals[ref]))
        except ValueError as e:
            row["error"] = math.nan
            row["message"] = (row["message"] + "; " if row["message"] else "") + f"error: {e}"


def columns(rows: list[dict]) -> list[str]:
    """Every key of the rows, in first-seen order."""
    names: dict[str, None] = {}
    for row in rows:
        names.update(dict.fromkeys(row))
    return list(names)


def _cell(value):
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    return "" if value is None else value


def write_csv(rows: list[dict], path: Path) -> Path:
    """The rows as CSV, one column per key (lists as JSON, None empty)."""
    names = columns(rows)
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=names)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(row.get(k)) for k in names})
    return path


def write_parquet(rows: list[dict], path: Path) -> Path | None:
    """The rows as Parquet, or None when pyarrow is missing. A column whose values differ in kind (4 and
    "auto") is written as text."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    data = {}
    for name in columns(rows):
        values = [row.get(name) for row in rows]
        kinds = {_kind(v) for v in values if v is not None}
        if kinds == {"int", "float"}:
            values = [None if v is None else float(v) for v in values]
        elif len(kinds) > 1 or kinds & {"list", "dict"}:
            values = [None if v is None else _text(v) for v in values]
        data[name] = values
    with atomic_path(path) as tmp:
        pq.write_table(pa.table(data), tmp)
    return path


def _kind(value) -> str:
    if isinstance(value, (list, tuple)):
        return "list"
    return type(value).__name__  # bool, int, float, str, dict


def _text(value) -> str:
    return json.dumps(value) if isinstance(value, (list, tuple, dict)) else str(value)


def plot_speed_error(rows: list[dict], path: Path, *, metric: str) -> Path | None:
    """A log-log plot of ms per frame (wall) against the error of each run with a positive error,
    labelled by run id; None when matplotlib is missing or no run has an error to show."""
    points = [
        (r["error"], r["wall_ms_per_frame"], r["run_id"])
        for r in rows
        if r.get("error") and math.isfinite(r["error"]) and r["error"] > 0 and r.get("wall_ms_per_frame")
    ]
    if not points:
        return None
    try:
        from matplotlib.figure import Figure  # no pyplot: the application's backend is left alone
    except ImportError:
        return None
    fig = Figure(figsize=(6.4, 4.4))
    ax = fig.add_subplot()
    err, ms, labels = zip(*points, strict=True)
    ax.loglog(err, ms, "o")
    for x, y, label in points:
        ax.annotate(label, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set(xlabel=f"error against the reference ({metric}) [m]", ylabel="wall time per frame [ms]")
    ax.grid(True, which="both", alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    return path


def format_table(rows: list[dict], *, width: int = 48) -> str:
    """A short text table: run, status, wall and CPU ms per frame, compile s, error, message."""
    head = ["run", "status", "ms/frame", "cpu ms/frame", "compile s", "error", "message"]
    lines = [head]
    for r in rows:
        status = r["status"] + (" (kept)" if r.get("skipped") else "")
        cells = [r["wall_ms_per_frame"], r["cpu_ms_per_frame"], r["compile_s"]]
        nums = ["-" if v is None else f"{v:.3g}" for v in cells]
        error = r.get("error")
        message = r.get("message") or ""
        cut = message if len(message) <= width else message[: width - 3] + "..."
        lines.append([r["run_id"], status, *nums, "-" if error is None else f"{error:.3g}", cut])
    widths = [max(len(str(line[k])) for line in lines) for k in range(len(head))]
    return "\n".join(
        "  ".join(str(c).ljust(w) for c, w in zip(line, widths, strict=True)).rstrip() for line in lines
    )
