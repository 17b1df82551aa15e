"""Parameter sweeps: run a scene over a grid (or a list) of parameter values, each run in its own process
and folder, and gather the runs into one table.

    from taichi_anim.sweep import sweep
    result = sweep("cloth", {"substeps": [8, 16, 32]}, frames=30, export=False,
                   reference={"substeps": 128})

Every run writes OUT/<run id>/run.json (run_scene's manifest, with the sweep's parameters under
settings["sweep"]) and final_state.npz; the sweep writes OUT/sweep.csv, OUT/sweep.parquet (with
pyarrow), OUT/speed_error.png (with a reference and matplotlib) and OUT/sweep.json (settings, machine,
warm-up, every row). Runs run on any concurrent.futures executor, e.g. a Dask cluster's
(`cluster="tcp://host:8786"`, extra `sweep`). The guide page docs/guide/sweeps.md explains the columns.
"""

from .driver import SweepResult, sweep
from .params import RUN_OPTIONS, expand, parse_param, parse_value, run_id
from .table import METRICS, format_table, max_distance, rms_distance

__all__ = [
    "METRICS",
    "RUN_OPTIONS",
    "SweepResult",
    "expand",
    "format_table",
    "max_distance",
    "parse_param",
    "parse_value",
    "rms_distance",
    "run_id",
    "sweep",
]
