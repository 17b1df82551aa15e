"""Speed against error of the integrators on the `cloth` demo, as one parameter sweep: a study is a scene,
a parameter grid and a metric.

The cloth sheet (resolution 24, FRAMES frames of 1/60 s, f64, no export) for every integrator and steps per
frame of the grid, each run in its own process (`taichi_anim.sweep.sweep`), against a reference run
(rk4 at REFERENCE_SUBSTEPS steps per frame): RMS distance of the final vertex positions [m] beside the
wall milliseconds per frame. Too few steps for an explicit method are the point too: those runs diverge,
the watchdog stops them, and they are rows with their status (accuracy is not stability).

    .venv/bin/python benchmarks/integrator_sweep.py [--quick]
"""

import math
import sys
import tempfile
from pathlib import Path

from harness import Page, parse_args

from taichi_anim.sweep import sweep

INTEGRATORS = ["symplectic_euler", "midpoint", "rk4", "implicit_euler"]
SUBSTEPS = [8, 32, 128, 512]
REFERENCE_SUBSTEPS = 2048
FRAMES = 30
RESOLUTION = 24
PRECISION = (
    "f64"  # in f32 the reference's own round-off (~5e-4 m after 60,000 steps) hid every error below it
)


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    integrators = INTEGRATORS[::3] if args.quick else INTEGRATORS
    substeps = SUBSTEPS[1:3] if args.quick else SUBSTEPS
    frames = 3 if args.quick else FRAMES
    reference = {"integrator": "rk4", "substeps": 256 if args.quick else REFERENCE_SUBSTEPS}
    with tempfile.TemporaryDirectory() as tmp:
        result = sweep(
            "cloth",
            {"integrator": integrators, "substeps": substeps},
            out=Path(tmp) / "sweep",
            reference=reference,
            frames=frames,
            resolution=RESOLUTION,
            precision=PRECISION,
            export=False,
            progress=False,
        )
        rows = []
        for r in sorted(result.rows, key=lambda r: (r["integrator"], r["substeps"])):
            error = r.get("error")
            rows.append(
                [
                    r["integrator"],
                    r["substeps"],
                    r["status"],
                    f"{r['wall_ms_per_frame']:.2f}" if r["status"] == "complete" else "-",
                    "-" if error is None or not math.isfinite(error) else f"{error:.3g}",
                    (r.get("message") or "")[:80],
                ]
            )
        page = Page(
            "integrator_sweep",
            "Integrators on the cloth demo: speed against error, one sweep",
            args,
            {
                "scene": f"cloth demo, resolution {RESOLUTION}, {frames} frames of 1/60 s, {PRECISION}",
                "grid": f"integrator {integrators} x steps per frame {substeps}",
                "reference": f"{reference} (in the table too)",
                "error": "RMS distance of the final vertex positions to the reference run's [m]",
                "runs": "taichi_anim.sweep.sweep: a process per run, one per core, 1 thread each",
            },
        )
        page.table(
            "Per run", ["integrator", "steps/frame", "status", "ms/frame", "error [m]", "message"], rows
        )
        if result.plot is not None:
            args.dir.mkdir(parents=True, exist_ok=True)
            (args.dir / "integrator_sweep.png").write_bytes(result.plot.read_bytes())
            page.text("The sweep's speed-against-error plot: `integrator_sweep.png` beside this page.")
        page.write({"rows": result.rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
