"""Particles before and after a change, alternating: the fountain of particles.py stepped by another
tree of the engine (extracted from git, e.g. `git archive REV | tar -x -C DIR`) and by this one, in
fresh processes taken in turn, each timing its frames interleaved with the NumPy step's in the same
process (so both see the same machine state). Per size and tree: the median over REPS processes of the
median frame, as particle-steps/s and as a ratio to NumPy.

A tree steps a frame the way its engine offers: `Stepper.advance(state, dt, 10)` where the Stepper has
it (a blocked launch in this tree), else ten `step` calls.

    git archive 1c44851 | tar -x -C /tmp/before
    .venv/bin/python benchmarks/particles_ab.py --before /tmp/before [--quick]
"""

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from harness import BENCH_DIR, Page, parse_args

CHILD = """
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
import taichi as ti
import taichi_anim
import particles as P
from harness import init
n = int(sys.argv[2])
init("f32")
model, state, integ = P.build(n)
stepper = integ.stepper_for(model)
advance = getattr(stepper, "advance", None)
def ours():
    if advance is not None:
        advance(state, P.DT, P.STEPS)
    else:
        for _ in range(P.STEPS):
            integ.step(model, state, P.DT)
sim = P.NumpyParticles(n)
def peer():
    for _ in range(P.STEPS):
        sim.step()
for _ in range(P.FILL_FRAMES):
    ours()
    peer()
a_t, b_t = [], []
for _ in range(max(10, min(300, int(3e7 / n)))):
    ti.sync()
    a = time.perf_counter()
    ours()
    ti.sync()
    a_t.append(time.perf_counter() - a)
    a = time.perf_counter()
    peer()
    b_t.append(time.perf_counter() - a)
alive = float(state.alive_mask().sum())
rate = lambda ts: alive * P.STEPS / statistics.median(ts)
print(json.dumps({"ours": rate(a_t), "numpy": rate(b_t), "engine": taichi_anim.__file__}))
"""


def one(tree: Path | None, n: int) -> dict:
    """One process of `tree` (None: this one) on n particles: particle-steps/s of ours and NumPy."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)  # its taichi_anim before the installed one
    bench = (tree / "benchmarks") if tree is not None else BENCH_DIR
    # Run from the tree's own root: `python -c` puts the working directory first on sys.path.
    cwd = tree if tree is not None else BENCH_DIR.parent
    cmd = [sys.executable, "-c", CHILD, str(bench), str(n)]
    out = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    args = parse_args(__doc__, argv, lambda p: p.add_argument("--before", type=Path, required=True))
    sizes, reps = ((10**4, 10**5), 2) if args.quick else ((10**4, 10**5, 10**6), 3)
    rows, data = [], {}
    for n in sizes:
        runs = {"before": [], "after": []}
        for _ in range(reps):
            for name, tree in (("before", args.before), ("after", None)):
                runs[name].append(one(tree, n))
                print(n, name, runs[name][-1], flush=True)
        med = {k: {q: statistics.median(r[q] for r in v) for q in ("ours", "numpy")} for k, v in runs.items()}
        ratio = {k: statistics.median(r["ours"] / r["numpy"] for r in v) for k, v in runs.items()}
        data[n] = {"runs": runs, "median": med, "ratio_to_numpy": ratio}
        rows.append(
            [f"{n:.0e}", f"{med['before']['ours']:.3g}", f"{med['after']['ours']:.3g}"]
            + [f"{ratio['before']:.2f}x", f"**{ratio['after']:.2f}x**"]
            + [f"{med['after']['ours'] / med['before']['ours']:.2f}x", f"{med['after']['numpy']:.3g}"]
        )
    page = Page(
        "particles_ab",
        "Particles: another tree against this one, alternating processes",
        args,
        {
            "scene": "particles.py's fountain (disc emitter, gravity, container box), f32, 10 steps a frame",
            "before": f"{args.before} (its own benchmarks/particles.py build and stepping)",
            "processes": f"{reps} per tree and size, before and after in turn",
            "frames": "per process: the fill frames, then up to 300 frames, each followed by a NumPy frame",
        },
    )
    page.table(
        "particle-steps/s (medians) and ratio to NumPy in the same process",
        ["N", "before", "after", "before / NumPy", "after / NumPy", "after / before", "NumPy"],
        rows,
    )
    page.write(data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
