"""Before/after: the engine at another commit against this working tree, on the explicit cloth benchmark's
scene and on particles.py's scene, in one run, alternating the two engines per size and round.

Cloth (the taichi_anim side of cloth_warp.py, Warp's benchmark scene): a dim x dim grid in the XZ plane,
spacing 0.1 m, 0.1 kg per vertex, the two corners of the row z = 0 pinned, structural, shear and bend
springs of 1000 N/m and 10 kg/s, gravity; frames of 16 symplectic Euler substeps of 1/960 s (one
`step(model, state, 1/60, 16)` call where the engine has that frame API, else 16 calls) with the
divergence counter read once per frame and the positions copied to NumPy each frame; f32. Figure: median
ms per frame over FRAMES frames after WARMUP frames.
Particles (particles.py's scene, written out so older engines run it): emitter + gravity + container box,
symplectic Euler at dt = 1/600 s, f32, after the pool has filled. Figure: particle-steps/s over STEPS steps.

Each figure is measured in a fresh process of its engine (PYTHONPATH set to a `git archive` copy of the
other commit, or this tree), ROUNDS rounds alternating the engines; the table gives the median over
rounds and the ratio after/before (> 1 is faster for particle-steps/s, < 1 faster for ms/frame).

    .venv/bin/python benchmarks/regression.py --before 826e10e      # writes results/regression.md
    .venv/bin/python benchmarks/regression.py --before 826e10e --quick
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from harness import Page, parse_args  # noqa: E402

CLOTH = r"""
import json, sys, time
import numpy as np, taichi as ti, taichi_anim as ta
dim, warmup, frames = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
ta.init("cpu", precision="f32")
i, j = np.meshgrid(np.arange(dim), np.arange(dim), indexing="xy")
x = np.stack([i.ravel() * 0.1, np.zeros(dim * dim), j.ravel() * 0.1], axis=1)
pairs = []
for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1), (2, 0), (0, 2)):
    ok = (i + di < dim) & (j + dj >= 0) & (j + dj < dim)
    pairs.append(np.stack([(j * dim + i)[ok], ((j + dj) * dim + i + di)[ok]], axis=1))
pairs = np.concatenate(pairs)
mass = np.full(dim * dim, 0.1)
mass[[0, dim - 1]] = 0.0
bld = ta.Builder()
bld.add_particles(x, mass=mass)
bld.add_springs(pairs, stiffness=1000.0, damping=10.0)
bld.add_force_gravity((0.0, -9.81, 0.0))
model = bld.finalize()
state = model.state()
integ = ta.make_integrator("symplectic_euler", check_every=16)
import inspect
fused = "substeps" in inspect.signature(integ.step).parameters  # engines with the frame API use it
def frame():
    if fused:
        integ.step(model, state, 1.0 / 60.0, 16)
    else:
        for _ in range(16):
            integ.step(model, state, 1.0 / 960.0)
    state.particle_x.to_numpy()
for _ in range(warmup):
    frame()
times = []
for _ in range(frames):
    ti.sync(); t0 = time.perf_counter(); frame(); ti.sync(); times.append(time.perf_counter() - t0)
ms = 1e3 * float(np.median(times))
print(json.dumps({"ms_per_frame": ms, "springs": len(pairs), "engine": ta.__file__, "frame_api": fused}))
"""

PARTICLES = r"""
import json, sys, time
import numpy as np, taichi as ti, taichi_anim as ta
n, steps = int(sys.argv[1]), int(sys.argv[2])
ta.init("cpu", precision="f32")
b = ta.Builder()
b.add_particle_emitter(capacity=n, rate=n / 0.5, shape="disc", center=(0, 0.25, 0), radius=0.25,
    direction=(0, 1, 0), speed=4.0, speed_jitter=0.1, spread=0.5, lifetime=0.5, lifetime_jitter=0.2)
b.add_force_gravity((0.0, -9.81, 0.0))
b.add_collider_box((-1, 0, -1), (1, 2, 1), restitution=0.5, friction=0.0)
model = b.finalize(seed=0)
state, integ, dt = model.state(), ta.make_integrator("symplectic_euler", check_every=10), 1 / 600
for _ in range(380):  # the pool fills: the longest first lifetime (0.6 s) has run out
    integ.step(model, state, dt)
a = int(state.alive_mask().sum())
ti.sync(); t0 = time.perf_counter()
for _ in range(steps):
    integ.step(model, state, dt)
ti.sync(); wall = time.perf_counter() - t0
rate = 0.5 * (a + int(state.alive_mask().sum())) * steps / wall
print(json.dumps({"particle_steps_per_s": rate, "engine": ta.__file__}))
"""


def short_sha(rev: str) -> str:
    out = subprocess.run(["git", "rev-parse", "--short", rev], cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip() or rev


def run(tree: Path, code: str, *args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)], env=env, capture_output=True, text=True, cwd=tree
    )
    if out.returncode:
        raise RuntimeError(f"{tree}: {out.stderr[-2000:]}")
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert Path(result["engine"]).resolve().is_relative_to(tree.resolve()), result["engine"]
    return result


def main(argv=None) -> int:
    def options(p):
        p.add_argument("--before", required=True, help="commit of the engine before the change")
        p.add_argument("--rounds", type=int, default=3)
        p.add_argument("--cloth-sizes", type=int, nargs="*", default=None, help="default 32 64 128 256")
        p.add_argument("--particle-sizes", type=int, nargs="*", default=None, help="default 1e4 ... 1e7")

    args = parse_args(__doc__, argv, options)
    rounds = 1 if args.quick else args.rounds
    cloth_sizes = (32, 64) if args.quick else (32, 64, 128, 256)
    particle_sizes = (10_000,) if args.quick else (10_000, 100_000, 1_000_000, 10_000_000)
    if args.cloth_sizes is not None:
        cloth_sizes = tuple(args.cloth_sizes)
    if args.particle_sizes is not None:
        particle_sizes = tuple(args.particle_sizes)
    warmup, frames, steps = (3, 10, 100) if args.quick else (5, 40, 600)
    name = "regression" if args.cloth_sizes is None and args.particle_sizes is None else "regression_subset"
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp) / "before"
        # A copy of the other commit's files (git archive): nothing in the repository changes.
        old.mkdir()
        archive = subprocess.run(["git", "archive", args.before], cwd=ROOT, check=True, capture_output=True)
        subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
        trees = {"before": old, "after": ROOT}
        res: dict = {}
        for r in range(rounds):
            for dim in cloth_sizes:
                for engine, tree in trees.items() if r % 2 == 0 else reversed(trees.items()):
                    fig = run(tree, CLOTH, dim, warmup, frames)["ms_per_frame"]
                    res.setdefault(("cloth", dim, engine), []).append(fig)
                    print(f"round {r} cloth {dim}^2 {engine}: {fig:.3f} ms/frame", flush=True)
            for n in particle_sizes:
                for engine, tree in trees.items() if r % 2 == 0 else reversed(trees.items()):
                    fig = run(tree, PARTICLES, n, steps)["particle_steps_per_s"]
                    res.setdefault(("particles", n, engine), []).append(fig)
                    print(f"round {r} particles {n} {engine}: {fig:.3e} particle-steps/s", flush=True)
    rows = []
    for kind, sizes, unit in (
        ("cloth", cloth_sizes, "ms/frame"),
        ("particles", particle_sizes, "particle-steps/s"),
    ):
        for s in sizes:
            b = statistics.median(res[(kind, s, "before")])
            a = statistics.median(res[(kind, s, "after")])
            change = (b / a - 1.0) if kind == "cloth" else (a / b - 1.0)  # > 0: faster after
            label = f"{s}²" if kind == "cloth" else f"{s:.0e}"
            rows.append(
                [
                    kind,
                    label,
                    unit,
                    f"{b:.4g}",
                    f"{a:.4g}",
                    f"{100 * change:+.1f}%",
                    " / ".join(f"{x:.4g}" for x in res[(kind, s, "after")]),
                ]
            )
    page = Page(
        name,
        "Before/after: explicit cloth and particles",
        args,
        {
            "before": args.before + f" ({sha})" if (sha := short_sha(args.before)) != args.before else sha,
            "rounds": f"{rounds}, engines alternating, each figure in a fresh process",
            "cloth": f"Warp's cloth scene, median of {frames} frames after {warmup}",
            "particles": f"{steps} steps after the pool filled",
        },
    )
    page.table(
        "Speed",
        [
            "scene",
            "size",
            "unit",
            f"before ({args.before})",
            "after (this tree)",
            "speed change (+ faster)",
            "after, each round",
        ],
        rows,
    )
    page.write({f"{k[0]} {k[1]} {k[2]}": v for k, v in res.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
