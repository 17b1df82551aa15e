"""Command line: `taichi-anim demo [NAME] --frames N --out DIR [--arch cpu|gpu|auto] [--seed S]
[--format ply|usd|both] [--video [PATH]] [--color-by speed|height|age|none]`, and
`taichi-anim sweep NAME --param NAME=V1,V2,... [--param ...] [run options]` (taichi_anim.sweep).

Exit codes: 0 the run completed; 2 a bad parameter, or a backend or viewer that is not available here
(argparse's own usage errors are 2 as well); 3 output could not be written (disk full, no permission,
`--out` is a file, another run is using the output folder); 4 the simulation stopped (diverged, or a
solver failed or a step was unstable under a "raise" policy); 128 + the signal's number when a signal
stopped the run: 130 SIGINT (Ctrl-C), 143 SIGTERM, 129 SIGHUP. Each failure prints one line on stderr,
and run.json in the output folder records it (status "failed", "diverged" or "interrupted").

Every option is checked (suffixes, writable places, a run already using the folder) before the scene
compiles and before the previous run's files are removed, so a rejected command changes nothing."""

import argparse
import sys
import warnings

# scenes, runner and viewer as modules, not names: a call looks its function up when it runs, so a test
# can replace it (as it could when these were imported inside the functions).
from . import rng, runtime, scenes, validate, viewer
from . import sweep as sweeps
from .errors import (
    ConvergenceError,
    DivergenceError,
    OutputError,
    ParameterError,
    RunInterrupted,
    StabilityError,
)
from .integrators import INTEGRATORS
from .io.manifest import check_run_folder
from .scenes import runner

AUTO_SCENES = ("cloth", "drape", "flag")  # demos that can choose their method (integrator="auto")

EXIT_PARAMETER = 2
EXIT_OUTPUT = 3
EXIT_SIMULATION = 4
EXIT_INTERRUPTED = 130  # SIGINT; any stop signal: 128 + its number (RunInterrupted.exit_code)


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """The options of one demo run, shared by `demo` and `sweep` (where each one given is fixed for every
    run)."""
    p.add_argument("--frames", type=int, default=None, help="frames to simulate (default: the scene's own)")
    p.add_argument("--arch", choices=runtime.ARCHS, default="cpu", help="Taichi backend (default cpu)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--integrator",
        choices=sorted([*INTEGRATORS, "auto"]),
        default=None,
        help="override the integrator ('auto', the cloth and drape demos' default, also for flag: the "
        "cheapest method stable at the frame's step)",
    )
    p.add_argument(
        "--material",
        choices=["springs", "membrane"],
        default=None,
        help="cloth demos: mass-spring cloth or a continuum membrane + bending (default: springs)",
    )
    p.add_argument(
        "--substeps",
        default=None,
        help="cloth demos: steps per frame, or 'auto' for the fewest within the method's stability limit",
    )
    p.add_argument("--no-export", action="store_true", help="do not write per-frame files")
    p.add_argument(
        "--format",
        choices=["ply", "usd", "both"],
        default="ply",
        help="export: PLY files per frame, one USD stage OUT/NAME.usd, or both (default ply)",
    )
    p.add_argument(
        "--video",
        nargs="?",
        const="",
        default=None,
        metavar="PATH",
        help="also write a video of the run at the demo's frame rate: MP4, or GIF if PATH ends in .gif "
        "(default PATH: OUT/NAME.mp4)",
    )
    p.add_argument(
        "--size-buckets",
        choices=["on", "off"],
        default=None,
        help="allocate arrays in power-of-two capacity buckets, so that another size of the scene reuses "
        "the compiled kernels (default: off for demo, on for sweep)",
    )
    p.add_argument(
        "--color-by",
        choices=["speed", "height", "age", "none"],
        default=None,
        help="colour particles and spheres in the pictures and video by this attribute, with a legend "
        "(default: the demo's choice; 'none': their own colours)",
    )


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="taichi-anim", description="taichi_anim: particle and cloth animation")
    sub = p.add_subparsers(dest="command")
    d = sub.add_parser(
        "demo",
        help=f"run a demo scene (default: {scenes.DEFAULT_SCENE})",
        epilog="exit codes: 0 complete, 2 bad parameter or unavailable backend, 3 output not written "
        "(or the folder is in use by another run), 4 simulation stopped (diverged or failed under a raise "
        "policy), 128+N stopped by signal N after saving the frames so far (130 SIGINT, 143 SIGTERM, "
        "129 SIGHUP)",
    )
    d.add_argument("name", nargs="?", default=scenes.DEFAULT_SCENE, help="demo to run (see --list)")
    d.add_argument("--list", action="store_true", help="list the demos and exit")
    d.add_argument(
        "--out",
        default=None,
        help="output folder (default out/NAME); the previous run's files there are replaced, others kept; "
        "one run at a time per folder",
    )
    _add_run_options(d)
    d.add_argument("--view", action="store_true", help="show a live GGUI window (needs a display and Vulkan)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_sweep_parser(sub)
    return p


def _add_sweep_parser(sub) -> None:
    w = sub.add_parser(
        "sweep",
        help="run a scene over parameter values, each run in its own process and folder, into one table",
        epilog="every run option given (--frames, --seed, ...) is fixed for all runs; --param NAME=V1,V2 "
        "sweeps any option of the scene's build or of a run. Exit codes: 0 the sweep ran (failed runs are "
        "rows of its table), 2 a bad parameter or an unreachable cluster, 3 the output folder cannot be "
        "written",
    )
    w.add_argument("name", help="a demo name (see `demo --list`) or module:function returning a Scene")
    w.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=V1,V2,...",
        help="values of one parameter (int, float, true/false, none or text; a JSON list for values "
        "with commas); repeat for more",
    )
    w.add_argument("--list-mode", action="store_true", help="zip the --param lists instead of their product")
    w.add_argument("--out", default="out/sweep", help="sweep folder: a folder per run, the tables")
    w.add_argument("--workers", type=int, default=None, help="runs at a time here (default: the cores)")
    w.add_argument("--threads", type=int, default=None, help="Taichi CPU threads per run")
    w.add_argument("--cluster", default=None, metavar="ADDR", help="Dask scheduler, e.g. tcp://host:8786")
    w.add_argument("--timeout", type=float, default=None, metavar="S", help="stop a run after S seconds")
    w.add_argument("--rerun", action="store_true", help="run again the runs already complete")
    w.add_argument(
        "--reference",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="the values of the run each run is compared with (e.g. substeps=64); repeat for more",
    )
    w.add_argument("--metric", choices=["rms", "max"], default=None, help="error against the reference")
    w.add_argument("--no-warmup", action="store_true", help="no short first run to fill the kernel cache")
    w.add_argument("--quiet", action="store_true", help="no line per finished run")
    _add_run_options(w)
    w.set_defaults(seed=None, arch=None, format=None)  # only the options given are fixed


SUBSTEP_SCENES = ("cloth", "drape", "flag")


def _int(name: str, text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ParameterError(f"{name} must be an integer or 'auto', got {text!r}") from None


def _demo(args) -> int:
    if args.list:
        for name, text in scenes.describe().items():
            print(f"{name:12s} {text}")
        return 0
    if args.frames is not None and args.frames < 1:
        raise ParameterError(f"--frames must be >= 1, got {args.frames}")
    out = args.out or f"out/{args.name}"
    # Before the backend starts and the scene compiles, and before anything is removed; creates nothing.
    check_run_folder(out)
    runner.video_target(args.video, out, args.name, option="--video")  # "" stays "": run_scene names it
    window = None
    if args.view:
        problem = viewer.vulkan_problem()
        if problem:
            print(f"taichi-anim: --view is not possible here: {problem}", file=sys.stderr)
            return 2
    validate.count("--seed", args.seed, 0, rng.SEED_LIMIT - 1)  # before a scene seeds NumPy with it
    try:
        with warnings.catch_warnings(record=True) as caught:  # e.g. "gpu" fell back to the CPU: one line
            warnings.simplefilter("always", RuntimeWarning)
            buckets = None if args.size_buckets is None else args.size_buckets == "on"  # None: environment
            runtime.init(args.arch, size_buckets=buckets)
    except RuntimeError as e:  # e.g. --arch cuda on a machine without CUDA
        print(f"taichi-anim: error: {e}", file=sys.stderr)
        return 2
    for w in caught:
        print(f"taichi-anim: {w.message}", file=sys.stderr)
    options = {"seed": args.seed}
    if args.integrator:
        if args.integrator == "auto" and args.name not in AUTO_SCENES:
            print(
                f"taichi-anim: --integrator auto applies to the {', '.join(AUTO_SCENES)} demos",
                file=sys.stderr,
            )
            return 2
        options["integrator"] = args.integrator
    if args.material:
        if args.name not in ("cloth", "drape"):
            print(
                f"taichi-anim: --material applies to the cloth and drape demos, not {args.name}",
                file=sys.stderr,
            )
            return 2
        options["material"] = args.material
    if args.substeps is not None:
        if args.name not in SUBSTEP_SCENES:
            print(
                f"taichi-anim: --substeps applies to the {', '.join(SUBSTEP_SCENES)} demos", file=sys.stderr
            )
            return 2
        options["substeps"] = args.substeps if args.substeps == "auto" else _int("--substeps", args.substeps)
    scene = scenes.make_scene(args.name, **options)
    if args.view:
        try:
            window = viewer.Viewer(f"taichi_anim: {args.name}")
        except viewer.ViewerUnavailable as e:
            print(f"taichi-anim: --view is not possible here: {e}", file=sys.stderr)
            return 2
    summary = runner.run_scene(
        scene,
        frames=args.frames or scene.frames,
        out_dir=out,
        export=not args.no_export,
        export_format=args.format,
        progress=not args.quiet,
        viewer=window,
        extra_settings={"seed": args.seed, "arch_requested": args.arch, "arch_choice": runtime.arch_choice()},
        video=args.video,
        color_by=args.color_by,
    )
    if window is not None:
        window.close()
    print(runner.summary_line(summary))
    return 0


def _sweep(args) -> int:
    params: dict = {}
    for text in args.param:
        name, values = sweeps.parse_param(text)
        if name in params:
            raise ParameterError(f"--param {name} is given twice")
        params[name] = values
    reference = {}
    for text in args.reference:
        name, values = sweeps.parse_param(text)
        if len(values) != 1:
            raise ParameterError(f"--reference {name} takes one value, got {len(values)}")
        reference[name] = values[0]
    fixed = {
        "frames": args.frames,
        "arch": args.arch,
        "seed": args.seed,
        "integrator": args.integrator,
        "material": args.material,
        "export_format": args.format,
        "video": args.video,
        "color_by": args.color_by,
    }
    if args.size_buckets is not None:  # unset: the worker's default (on), and the same runs as the API's
        fixed["size_buckets"] = args.size_buckets == "on"
    if args.substeps is not None:
        fixed["substeps"] = args.substeps if args.substeps == "auto" else _int("--substeps", args.substeps)
    if args.no_export:
        fixed["export"] = False
    result = sweeps.sweep(
        args.name,
        params,
        mode="list" if args.list_mode else "product",
        out=args.out,
        cluster=args.cluster,
        workers=args.workers,
        threads=args.threads,
        timeout=args.timeout,
        rerun=args.rerun,
        reference=reference or None,
        metric=args.metric,
        warmup=not args.no_warmup,
        progress=not args.quiet,
        **{k: v for k, v in fixed.items() if v is not None},
    )
    print(sweeps.format_table(result.rows))
    written = [result.csv, result.parquet, result.plot, result.manifest]
    print("wrote " + ", ".join(str(p) for p in written if p is not None))
    for note in result.notes:
        print(f"taichi-anim sweep: {note}", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    """Run the command line with `argv` (default sys.argv[1:]); returns the exit code (see above)."""
    args = _parser().parse_args(argv)
    if args.command is None:  # bare `taichi-anim` runs the default demo
        args = _parser().parse_args(["demo", *(argv or [])])
    try:
        return _sweep(args) if args.command == "sweep" else _demo(args)
    except ParameterError as e:
        return _fail(e, EXIT_PARAMETER)
    except OutputError as e:
        return _fail(e, EXIT_OUTPUT)
    except (DivergenceError, ConvergenceError, StabilityError) as e:
        return _fail(e, EXIT_SIMULATION)
    except RunInterrupted as e:  # run.json says "interrupted"; the frames before the signal are kept
        where = f"; the frames so far are in {e.summary['out_dir']}" if e.summary and e.frames_done else ""
        print(f"taichi-anim: {e}{where}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:  # Ctrl-C before the run started (e.g. while the scene compiled)
        print("taichi-anim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as e:  # output trouble a writer did not turn into an OutputError: say why, in one line
        lines = (e.strerror or str(e)).strip().splitlines()  # the first line: never a tool's command line
        where = f"{e.filename}: " if e.filename else ""
        return _fail(OutputError(where + (lines[0] if lines else type(e).__name__)), EXIT_OUTPUT)


def _fail(error: BaseException, code: int) -> int:
    message = " ".join(str(error).split())  # one line, whatever the message holds
    print(f"taichi-anim: error: {message}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
