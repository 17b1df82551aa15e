"""Launch overhead of `runtime.data_oriented`: the descriptor fast path against Taichi's own
`ti.data_oriented` (TAICHI_ANIM_PLAIN_DATA_ORIENTED=1), on launch-bound steps where the Python side of a
launch is most of the cost.

Scenes (f32, CPU, 2 threads): 100 free particles with gravity (one kernel per step), and an 8 x 8 cloth
(springs, and membrane + bending) stepped by symplectic Euler (one kernel per step) and by implicit Euler
with PCG (assemble + solver launches). Each figure: median microseconds per step over STEPS steps after a
warm-up of WARMUP steps, in a fresh process per path, ROUNDS rounds alternating the paths.

    .venv/bin/python benchmarks/launch_overhead.py [--quick]
"""

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from harness import Page, parse_args  # noqa: E402

CHILD = r"""
import json, sys, time
import numpy as np, taichi as ti, taichi_anim as ta
from taichi_anim import runtime
scene, method, warmup, steps = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
ta.init("cpu", precision="f32")
b = ta.Builder()
b.add_force_gravity()
if scene == "particles":
    b.add_particles(np.random.default_rng(0).uniform(0, 1, (100, 3)))
else:
    mat = ta.ClothMaterial() if scene == "cloth_springs" else ta.FabricMaterial()
    b.add_cloth_grid(origin=(0, 1, 0), size=(0.3, 0.3), resolution=(8, 8), pinned=[0, 7], material=mat)
model = b.finalize()
state = model.state()
integ = ta.make_integrator(method, check_every=1000) if method != "implicit_euler" else ta.make_integrator(
    method, tol=1e-3, max_iterations=8, check_every=1000)
for _ in range(warmup):
    integ.step(model, state, 1e-4)
times = []
for _ in range(steps):
    ti.sync(); t0 = time.perf_counter(); integ.step(model, state, 1e-4); ti.sync()
    times.append(time.perf_counter() - t0)
print(json.dumps({"us": 1e6 * float(np.median(times)), "fast": runtime.FAST_DATA_ORIENTED}))
"""

CASES = [
    ("particles", "symplectic_euler"),
    ("cloth_springs", "symplectic_euler"),
    ("cloth_membrane", "symplectic_euler"),
    ("cloth_springs", "implicit_euler"),
    ("cloth_membrane", "implicit_euler"),
]


def child(scene: str, method: str, plain: bool, warmup: int, steps: int) -> dict:
    env = dict(os.environ)
    env.pop("TAICHI_ANIM_PLAIN_DATA_ORIENTED", None)
    if plain:
        env["TAICHI_ANIM_PLAIN_DATA_ORIENTED"] = "1"
    out = subprocess.run(
        [sys.executable, "-c", CHILD, scene, method, str(warmup), str(steps)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["fast"] == (not plain)
    return result


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    rounds, warmup, steps = (1, 20, 200) if args.quick else (3, 100, 2000)
    res: dict = {}
    for r in range(rounds):
        for scene, method in CASES:
            for plain in (False, True) if r % 2 == 0 else (True, False):
                us = child(scene, method, plain, warmup, steps)["us"]
                res.setdefault((scene, method, plain), []).append(us)
                print(
                    f"round {r} {scene} {method} {'plain' if plain else 'fast'}: {us:.1f} us/step", flush=True
                )
    rows = []
    for scene, method in CASES:
        fast = statistics.median(res[(scene, method, False)])
        plain = statistics.median(res[(scene, method, True)])
        rows.append(
            [scene, method, f"{fast:.1f}", f"{plain:.1f}", f"{plain - fast:+.1f}", f"{plain / fast:.2f}"]
        )
    page = Page(
        "launch_overhead",
        "Launch overhead: descriptor-bound kernels against `ti.data_oriented`",
        args,
        {
            "steps": f"median µs per step over {steps} steps after {warmup}, dt = 1e-4 s, f32, CPU",
            "rounds": f"{rounds}, alternating the paths, a fresh process each",
            "implicit": "PCG tol 1e-3, at most 8 iterations",
        },
    )
    page.table(
        "µs per step",
        ["scene", "method", "fast path", "plain ti.data_oriented", "difference", "plain / fast"],
        rows,
    )
    page.write({f"{k[0]} {k[1]} {'plain' if k[2] else 'fast'}": v for k, v in res.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
