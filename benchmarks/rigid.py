"""Rigid bodies against MuJoCo and PyBullet on the same scenes in the same run: a 20-box tower, a pyramid
of 20 boxes per side (210 boxes), a row of 30 dominoes and 1000 boxes poured into a bin, Y up.

The engines step the same boxes (sizes, densities, friction 0.6 box-box and box-floor) at the same time
step DT, for T_END simulated seconds (dominoes 4 s, bin 3 s). Ours: semi-implicit Euler, sequential
impulses (8 iterations + 4 relaxation sweeps, the defaults, and 4 + 1, also with 4-point manifolds), f32.
MuJoCo: its CG and Newton solvers (soft contacts, its defaults otherwise; peers/mujoco_boxes.py).
PyBullet: its defaults (10 solver iterations; peers/pybullet_boxes.py). Per engine and scene: ms per step
(median of STEP_BATCH-step batches after the first second, compile reported apart for ours: the first
step), contacts at the end, the largest drift of a box from its start (tower, pyramid), the deepest
penetration at the end, the kinetic energy at the end; for the dominoes, how many are down (tilted past 45
degrees) and when the last fell.

    .venv/bin/python benchmarks/rigid.py [--quick]
"""

import statistics
import time

import numpy as np
from harness import Page, clock, host_clock, init, log, parse_args, peer

import taichi_anim as ta
from taichi_anim.bodies.rigid.quaternion import quat_to_matrix

DT = 0.002  # [s]: MuJoCo's default step
FRICTION = 0.6
STEP_BATCH = 50
# (label, iterations, relaxation sweeps, manifold_points) of our runs
OURS = (
    ("taichi_anim", 8, 4, 0),
    ("taichi_anim 4+1 sweeps", 4, 1, 0),
    ("taichi_anim 4+1, 4-point manifolds", 4, 1, 4),
)


def tower():
    return [((0.2, 0.1, 0.2), (0.0, 0.1 + 0.2 * k, 0.0), (0, 0, 0), (0, 0, 0), 1000.0) for k in range(20)]


def pyramid(side=20, h=0.1):
    boxes = []
    for row in range(side):
        for i in range(side - row):
            x = (i - (side - row - 1) / 2) * 2.05 * h
            boxes.append(((h, h, h), (x, h + 2 * h * row, 0.0), (0, 0, 0), (0, 0, 0), 1000.0))
    return boxes


def bin_of_boxes(count=1000, half=0.05, bin_half=0.75):
    """`count` cubes on a jittered lattice above a square bin (the walls are planes, added by each engine
    from BIN_HALF), falling in."""
    rng = np.random.default_rng(0)
    per = int(np.ceil(np.sqrt(count / 10)))  # ten layers
    spacing = 2 * bin_half / per
    boxes = []
    for k in range(count):
        i, j, layer = k % per, (k // per) % per, k // (per * per)
        pos = (-bin_half + (i + 0.5) * spacing, 0.2 + layer * 3 * half, -bin_half + (j + 0.5) * spacing)
        boxes.append(
            (
                (half, half, half),
                tuple(np.add(pos, rng.uniform(-0.01, 0.01, 3))),
                (0, 0, 0),
                (0, 0, 0),
                1000.0,
            )
        )
    return boxes


BIN_HALF = 0.75


def dominoes(count=30, spacing=0.22, height=0.4, width=0.2, thickness=0.04, push=1.5):
    half = (thickness / 2, height / 2, width / 2)
    boxes = []
    for k in range(count):
        w = (0.0, 0.0, -push) if k == 0 else (0.0, 0.0, 0.0)
        v = tuple(np.cross(w, (thickness / 2, height / 2, 0.0))) if k == 0 else (0, 0, 0)
        boxes.append((half, (k * spacing, height / 2, 0.0), v, w, 700.0))
    return boxes


class Ours:
    """Our engine on the boxes: positions(), orientations(), step(n), contacts(), penetration()."""

    def __init__(self, boxes, walls=None, iterations=8, relax=4, manifold=0):
        b = ta.Builder()
        b.add_force_gravity()
        b.add_collider_plane((0, 1, 0), 0.0, friction=FRICTION, restitution=0.0)
        for normal in () if walls is None else ((-1, 0, 0), (1, 0, 0), (0, 0, -1), (0, 0, 1)):
            b.add_collider_plane(normal, -walls, friction=FRICTION, restitution=0.0)
        b.set_rigid_contacts(iterations=iterations, relax_iterations=relax, manifold_points=manifold)
        for half, pos, v, w, rho in boxes:
            b.add_rigid_body(ta.shapes.Box(half), position=pos, velocity=v, angular_velocity=w, density=rho,
                             friction=FRICTION)  # fmt: skip
        self.model = b.finalize()
        self.state = self.model.state()
        self.integ = ta.make_integrator("symplectic_euler")
        self.stepper = self.integ.stepper_for(self.model)

    def step(self, n=1):
        # n steps as one frame of substeps, as a scene's frame is run (a launch for all of them where
        # the Stepper's frame_mode allows: "solver_frame")
        self.stepper.step(self.state, n * DT, substeps=n)

    def positions(self):
        return self.state.rigid_snapshot().position

    def orientations(self):
        return self.state.rigid_snapshot().orientation

    def kinetic_energy(self):
        snap, m = self.state.rigid_snapshot(), self.model
        r = quat_to_matrix(snap.orientation)
        inertia = np.einsum("bij,bjk,blk->bil", r, m.rigid_inertia, r)
        w = snap.angular_velocity
        return float(
            0.5 * (m.rigid_mass * (snap.velocity**2).sum(1)).sum()
            + 0.5 * np.einsum("bi,bij,bj->", w, inertia, w)
        )

    def contacts(self):
        return int(self.stepper.solver("rigid bodies").contacts.count[None])

    def penetration(self):
        c = self.stepper.solver("rigid bodies").contacts
        n = c.count[None]
        return float(max(0.0, -c.sep.to_numpy()[:n].min())) if n else 0.0


def measure(engine, boxes, t_end, sync, fallen=None):
    """Run `engine` for t_end seconds; per-step time of batches after the first second."""
    start = np.array([p for _h, p, *_ in boxes])
    steps = round(t_end / DT)
    a = sync()
    engine.step(1)
    first = sync() - a
    batches, down_at = [], None
    done = 1
    warm = round(1.0 / DT)
    while done < steps:
        n = min(STEP_BATCH, steps - done)
        a = sync()
        engine.step(n)
        if done >= warm:
            batches.append((sync() - a) / n)
        done += n
        if fallen is not None and down_at is None and fallen(engine).all():
            down_at = done * DT
    pos = engine.positions()
    out = {
        "ms_per_step": statistics.median(batches) * 1e3,
        "first_step_s": first,
        "contacts": engine.contacts(),
        "drift_m": float(np.linalg.norm(pos - start, axis=1).max()),
        "penetration_m": engine.penetration(),
        "kinetic_J": engine.kinetic_energy(),
    }
    if fallen is not None:
        out["down"] = int(fallen(engine).sum())
        out["all_down_s"] = down_at
    return out


def tilted(engine):
    up = quat_to_matrix(engine.orientations())[:, :, 1]
    return up[:, 1] < np.cos(np.radians(45.0))


def main():
    args = parse_args(__doc__)
    mj = peer("mujoco_boxes")
    bullet = peer("pybullet_boxes")
    t_end = 2.0 if args.quick else 10.0
    side = 8 if args.quick else 20
    count = 200 if args.quick else 1000
    scenes = [
        ("tower (20 boxes)", tower(), None, None),
        (f"pyramid ({side * (side + 1) // 2} boxes)", pyramid(side), None, None),
        ("dominoes (30)", dominoes(), tilted, None),
        (f"bin ({count} boxes)", bin_of_boxes(count), None, BIN_HALF),
    ]
    rows, data = [], {}
    for name, boxes, fallen, walls in scenes:
        log(name)
        seconds = 4.0 if fallen is not None else (3.0 if walls else t_end)
        results = {}
        for label, iterations, relax, manifold in OURS:
            init("f32")
            t0 = time.perf_counter()
            ours = Ours(boxes, walls, iterations, relax, manifold)
            build = time.perf_counter() - t0
            results[label] = {**measure(ours, boxes, seconds, clock, fallen), "build_s": build}
        if mj is not None:
            for solver in ("CG", "Newton"):
                scene = mj.Scene(boxes, dt=DT, friction=FRICTION, solver=solver, walls=walls)
                results[f"mujoco {solver}"] = measure(scene, boxes, seconds, host_clock, fallen)
        if bullet is not None:
            scene = bullet.Scene(boxes, dt=DT, friction=FRICTION, walls=walls)
            results["pybullet"] = measure(scene, boxes, seconds, host_clock, fallen)
        data[name] = results
        for engine, r in results.items():
            log(f"  {engine}: {r['ms_per_step']:.3f} ms/step, drift {r['drift_m']:.4f} m")
            rows.append([
                name, engine, f"{r['ms_per_step']:.3f}", r["contacts"],
                "–" if fallen or walls else f"{r['drift_m'] * 1e3:.1f}", f"{r['penetration_m'] * 1e3:.2f}",
                f"{r['kinetic_J']:.3g}",
                f"{r['down']}/{len(boxes)} by {r['all_down_s']}" if fallen else "–",
            ])  # fmt: skip
    page = Page(
        "rigid" if not args.quick else "rigid_quick",
        "Rigid bodies against MuJoCo and PyBullet: a tower, a pyramid, dominoes and a bin of boxes",
        args,
        {"dt": f"{DT} s (both engines)", "simulated": f"{t_end} s (dominoes 4 s, bin 3 s)",
         "friction": FRICTION,
         "ours": "f32, symplectic_euler (semi-implicit), 8 iterations + 4 relaxation sweeps (the defaults; "
                 "and 4 + 1, also with manifold_points=4), margin 2 cm",
         "mujoco": f"{getattr(mj, 'VERSION', 'absent')}, solvers CG and Newton, defaults otherwise",
         "pybullet": f"API {getattr(bullet, 'VERSION', 'absent')}, defaults (10 iterations)"},
    )  # fmt: skip
    page.table(
        "Per scene",
        [
            "scene",
            "engine",
            "ms/step",
            "contacts",
            "max drift mm",
            "penetration mm",
            "kinetic J",
            "dominoes down",
        ],
        rows,
        "ms/step: median over batches of steps after the first simulated second; drift: the largest "
        "distance of a box from its start at the end; penetration: the deepest contact at the end; "
        "bin: 3 s of the pour, timed from the first second.",
    )
    page.write(data)


if __name__ == "__main__":
    main()
