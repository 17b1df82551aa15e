"""sweep(): check every parameter, expand the runs, skip the complete ones, warm the kernel cache with a
short run, fan the rest out on an executor, and write the table and sweep.json."""

from __future__ import annotations

import concurrent.futures as cf
import importlib.util
import json
import os
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from .. import validate
from ..errors import ParameterError
from ..io.atomic import atomic_path
from ..io.manifest import check_output_folder, environment, jsonable
from . import params as P
from . import runs, table

SWEEP_MANIFEST = "sweep.json"
WARMUP_ID = ".warmup"  # hidden: the warm-up's folder is no run of the table


@dataclass(frozen=True)
class SweepResult:
    """What a sweep did: rows (one dict per run, the table's rows), out (its folder), the files written
    (manifest sweep.json, csv, parquet and plot, None where not written), the warm-up run's record
    and notes (what was skipped and why)."""

    out: Path
    rows: list[dict]
    manifest: Path
    csv: Path
    parquet: Path | None = None
    plot: Path | None = None
    warmup: dict | None = None
    notes: list[str] = field(default_factory=list)

    def row(self, run_id: str) -> dict:
        """The row of the run `run_id` (KeyError if there is none)."""
        for r in self.rows:
            if r["run_id"] == run_id:
                return r
        raise KeyError(run_id)


def sweep(
    scene,
    params: Mapping[str, list],
    *,
    mode: str = "product",
    out="out/sweep",
    executor: cf.Executor | None = None,
    cluster: str | None = None,
    workers: int | None = None,
    threads: int | None = None,
    timeout: float | None = None,
    rerun: bool = False,
    reference: Mapping | None = None,
    metric: str | Callable | None = None,
    warmup: bool = True,
    progress: bool = True,
    **options,
) -> SweepResult:
    """Run `scene` once per combination of `params` (mode "product") or per row of them (mode "list"),
    each run in its own process and its own folder out/<run id> with its own run.json.

    scene: a catalogue name (taichi_anim.scenes.SCENES), a top-level `build(**options) -> Scene`
    function, or "module:function". params: name -> list of values; a name is any option of the scene's
    build or of a run (params.RUN_OPTIONS: frames, export, export_format, video, color_by, arch,
    precision, size_buckets: on unless False, see capacity.py). options: values every run shares (e.g.
    frames=10, export=False).
    executor: any concurrent.futures.Executor (e.g. a Dask Client(...).get_executor()); cluster: a Dask
    scheduler address to make one from; default: `workers` (default os.cpu_count()) runs at a time here.
    threads: Taichi CPU threads per run (default 1 when the local runs fill the cores, else Taichi's).
    timeout [s]: a run still going after it is stopped and recorded as "timeout". rerun: run again
    the runs whose run.json says complete (otherwise they are kept). reference: values that, put over a
    run's own, give the run it is compared with (e.g. {"substeps": 64}; added if not in the sweep);
    metric: "rms" (default with a reference) or "max" distance of the final positions [m], or
    f(final, final_ref) -> float over {"x", "alive"} dicts. warmup: one short run first, so that the
    runs load their kernels from Taichi's offline cache instead of all compiling them at once.

    A failed, diverged or timed-out run is a row with its status and message; the sweep goes on.
    ParameterError (naming the parameter and the accepted names) before anything runs."""
    if not isinstance(params, Mapping):
        raise ParameterError(f"params must map parameter names to lists of values, got {params!r}")
    spec = P.scene_spec(scene)
    build_names = P.build_names(P.load_build(spec))
    P.check_names(params, build_names)
    P.check_names(options, build_names, "option")
    for name in set(params) & set(options):
        raise ParameterError(f"{name!r} is both swept (params) and fixed (options): give it once")
    for name, value in options.items():
        P.check_value(name, value)
    rows_values = P.expand(params, mode)
    metric_fn, metric_name, reference = _metric(metric, reference, build_names)
    if workers is not None:
        workers = validate.count("workers", workers, 1)
    if threads is not None:
        threads = validate.count("threads", threads, 1)
    if timeout is not None and (
        isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or timeout <= 0
    ):
        raise ParameterError(f"timeout must be a positive number of seconds, got {timeout!r}")
    if executor is not None and cluster is not None:
        raise ParameterError("give an executor or a cluster address, not both")
    out = check_output_folder(out).absolute()  # the same folder for workers started elsewhere
    configs, refs, ids = _plan(rows_values, options, reference, list(params))
    local = executor is None and cluster is None
    workers = workers or os.cpu_count() or 1
    if threads is None and local and workers >= (os.cpu_count() or 1):
        threads = 1  # as many runs as cores: one Taichi thread each, not cores x cores threads
    tasks = [
        runs.make_task(spec, i, out, c, build_names, threads=threads, timeout=timeout)
        for i, c in zip(ids, configs, strict=True)
    ]
    settings = {
        "scene": spec,
        "params": dict(params),
        "mode": mode,
        "options": options,
        "reference": reference,
        "metric": metric_name,
        "executor": "local" if local else cluster or type(executor).__name__,
        "workers": workers if local else None,
        "threads": threads,
        "timeout": timeout,
        "rerun": rerun,
    }
    t0 = time.perf_counter()
    executor, owned = _executor(executor, cluster, workers)
    try:
        done = _run_all(tasks, executor, rerun=rerun, warmup=warmup, progress=progress)
    finally:
        if isinstance(owned, cf.Executor):
            owned.shutdown(wait=True, cancel_futures=True)
        elif owned is not None:
            owned.close()  # our connection only: close, never shutdown, which would stop the cluster
    (rows, finals), warm = done
    for row, ref_of in zip(rows, refs, strict=True):
        row["is_reference"] = reference is not None and ref_of is not None and rows[ref_of] is row
    if metric_fn is not None:
        table.add_errors(rows, finals, refs, metric_fn)
    return _write(out, rows, settings, warm, metric_name, time.perf_counter() - t0)


def _metric(metric, reference, build_names):
    if reference is None:
        if metric is not None:
            raise ParameterError("metric needs a reference: the values of the run to compare with")
        return None, None, None
    if not isinstance(reference, Mapping):
        raise ParameterError(f"reference must map parameter names to values, got {reference!r}")
    P.check_names(reference, build_names, "reference parameter")
    for name, value in reference.items():
        P.check_value(name, value)
    metric = "rms" if metric is None else metric
    if callable(metric):
        return metric, getattr(metric, "__name__", "custom"), dict(reference)
    if metric not in table.METRICS:
        raise ParameterError(f"unknown metric {metric!r}; choose one of: {', '.join(table.METRICS)}")
    return table.METRICS[metric], metric, dict(reference)


def _plan(rows_values, options, reference, swept):
    """(every run's parameters, the index of each run's reference run or None, run ids): the sweep's
    runs first, then reference runs the sweep does not hold."""
    configs = [{**options, **r} for r in rows_values]
    id_values = [{k: r[k] for k in swept} for r in rows_values]
    refs: list[int | None] = [None] * len(configs)
    if reference is not None:
        index = {_key(c): k for k, c in enumerate(configs)}
        for k in range(len(rows_values)):
            ref = {**configs[k], **reference}
            if _key(ref) not in index:
                index[_key(ref)] = len(configs)
                configs.append(ref)
                extra = {
                    n: v
                    for n, v in reference.items()
                    if n not in swept and (n not in options or options[n] != v)
                }
                id_values.append({**{n: ref[n] for n in swept}, **extra})
                refs.append(len(configs) - 1)
            refs[k] = index[_key(ref)]
    return configs, refs, P.unique_ids(id_values)


def _key(config: dict) -> str:
    return json.dumps(config, sort_keys=True)


def _executor(executor, cluster, workers):
    """(the executor to use, what to shut down after: None for the caller's own)."""
    if executor is not None:
        return executor, None
    if cluster is not None:
        try:
            from distributed import Client
        except ImportError:
            raise ParameterError(
                "cluster needs Dask's distributed package: pip install 'taichi_anim[sweep]'"
            ) from None
        try:
            client = Client(cluster, timeout="20s")
        except (OSError, TimeoutError, ValueError) as e:
            raise ParameterError(f"cannot reach the Dask scheduler at cluster={cluster!r}: {e}") from None
        return client.get_executor(pure=False), client
    # Threads suffice here: each run is a process of its own (runs.run_one), the pool only waits on them.
    pool = cf.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="taichi-anim-sweep")
    return pool, pool


def _run_all(tasks, executor, *, rerun, warmup, progress):
    rows: list = [None] * len(tasks)
    finals: list = [None] * len(tasks)
    pending = []
    for k, task in enumerate(tasks):
        hit = None if rerun else runs.completed(task)
        if hit is None:
            pending.append(k)
        else:
            rows[k], finals[k] = hit
    warm, futures = None, {}
    try:
        if warmup and len(pending) > 1:
            warm = _warm_up(executor, tasks[pending[0]], progress)
        futures = {_submit(executor, tasks[k]): k for k in pending}
        for n, future in enumerate(cf.as_completed(futures), 1):
            k = futures[future]
            try:
                rows[k], finals[k] = future.result()
            except Exception as e:  # the executor lost the task (a worker died): a row, not a crash
                task = tasks[k]
                rows[k], finals[k] = runs.collect(task, rc=1, seconds=None, timed_out=False)
                rows[k].update(status="failed", message=f"the executor lost the run: {type(e).__name__}: {e}")
            _say(progress, f"[{n}/{len(pending)}] {rows[k]['run_id']}: {rows[k]['status']}")
    except BaseException:
        for future in futures:
            future.cancel()
        runs.stop_all()
        raise
    return (rows, finals), warm


def _warm_up(executor, first: dict, progress: bool) -> dict:
    """One frame of the first run, without export, in a folder of its own: it compiles the kernels
    once and leaves them in Taichi's offline cache for the runs that follow."""
    task = dict(first, run_id=WARMUP_ID, out_dir=str(Path(first["out_dir"]).parent / WARMUP_ID))
    task["run"] = {**first["run"], "frames": 1, "export": False, "video": None}
    row, _ = _submit(executor, task).result()
    warm = {"run_id": first["run_id"], "status": row["status"], "seconds": row["run_s"]}
    warm.update(compile_s=row["compile_s"], message=row["message"])
    _say(progress, f"warm-up ({first['run_id']}, 1 frame): {row['status']} in {row['run_s']:.1f} s")
    return warm


def _submit(executor, task):
    return executor.submit(runs.run_one, task)


def _say(progress: bool, text: str) -> None:
    if progress:
        print(f"taichi-anim sweep: {text}", file=sys.stderr, flush=True)


def _write(out: Path, rows, settings, warm, metric_name, seconds) -> SweepResult:
    notes = []
    csv = table.write_csv(rows, out / "sweep.csv")
    parquet = table.write_parquet(rows, out / "sweep.parquet")
    if parquet is None:
        notes.append("no Parquet table: pyarrow is not installed")
    plot = None
    if any(r.get("error") for r in rows):
        if importlib.util.find_spec("matplotlib") is None:
            notes.append("no speed-against-error plot: matplotlib is not installed")
        else:
            plot = table.plot_speed_error(rows, out / "speed_error.png", metric=metric_name)
    files = {"csv": csv.name, "parquet": parquet and parquet.name, "plot": plot and plot.name}
    doc = {
        "schema": 1,
        "settings": settings,
        "machine": environment(),
        "warmup": warm,
        "wall_s": seconds,
        "counts": {s: sum(r["status"] == s for r in rows) for s in sorted({r["status"] for r in rows})},
        "files": files,
        "notes": notes,
        "runs": rows,
    }
    manifest = out / SWEEP_MANIFEST
    with atomic_path(manifest) as tmp:
        tmp.write_text(json.dumps(jsonable(doc), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return SweepResult(out, rows, manifest, csv, parquet, plot, warm, notes)
