"""The course's collision cascade, measured (bodies/rigid/contacts.py): per level, how many pairs of bodies
reach it and what one test there costs, the cost model T = N_v C_v + N_p C_p summed over the levels
(bounding spheres, AABBs, OBBs, the exact test), and the exact tests the OBB level saves against AABBs
alone.

Scenes, each settled first (semi-implicit Euler, f32, DT = 2 ms, the contact defaults): the 210-box
pyramid, 1000 boxes poured into a bin (2 s), a heap of 300 sticks (thin boxes 0.5 x 0.02 x 0.02 m,
turned at random, dropped into the same bin, 2 s): long bodies turned off the world axes, about which an
AABB is loose, the course's case for OBBs; and a chain of 20 interlocked rings dropped on the floor (1 s),
the tori as CoACD's convex parts (`Mesh(contact="parts")`, 12 each) and as their 576 triangles
(`Mesh(contact="triangles")`), where the cascade goes on down each body's tree of OBBs over its parts
(a pair of nodes: bounding spheres, then OBBs; a pair of leaves: then the exact test) and "exact tests"
counts pairs of parts.

Per level, `RigidContacts.cascade_pairs(stop)` runs the cascade over every pair of bodies up to that
level, timed (median of REPEATS runs after a warm-up); C at a level is the time added by that level
divided by the pairs that reach it. "AABB alone" runs the exact test on every pair that passes the
AABBs, skipping the OBB level (inside bodies too: the trees' nodes by bounding spheres and world AABBs,
the boxes projected on the world axes), and is
timed the same way.

    .venv/bin/python benchmarks/rigid_cascade.py [--quick]
"""

import statistics

import numpy as np
from harness import Page, clock, init, log, parse_args
from rigid import BIN_HALF, DT, FRICTION, Ours, bin_of_boxes, pyramid

import taichi_anim as ta

REPEATS = 21
LEVELS = ("pairs", "spheres", "aabb", "obb", "exact")


def sticks(count=300, half=(0.25, 0.01, 0.01)):
    """`count` thin boxes turned at random on a jittered lattice above the bin, falling in."""
    rng = np.random.default_rng(1)
    per = 6
    spacing = 2 * BIN_HALF / per
    boxes = []
    for k in range(count):
        i, j, layer = k % per, (k // per) % per, k // (per * per)
        pos = (-BIN_HALF + (i + 0.5) * spacing, 0.1 + layer * 0.12, -BIN_HALF + (j + 0.5) * spacing)
        w = rng.normal(size=3) * 6.0  # spinning as they fall: they land turned every way
        boxes.append((half, tuple(np.add(pos, rng.uniform(-0.02, 0.02, 3))), (0, 0, 0), tuple(w), 700.0))
    return boxes


class Chain:
    """`count` rings (tori, radius 0.3 m, tube 0.08 m, 576 triangles; as convex parts, or as their
    triangles with contact="triangles") interlocked along x, every other one turned upright, 1 m above the
    floor: what benchmarks read of an engine (model, state, stepper, step(n))."""

    def __init__(self, count=20, spacing=0.42, contact="parts"):
        import open3d as o3d

        torus = o3d.geometry.TriangleMesh.create_torus(
            torus_radius=0.3, tube_radius=0.08, radial_resolution=24, tubular_resolution=12
        )
        ring = ta.shapes.Mesh(np.asarray(torus.vertices), np.asarray(torus.triangles), contact=contact)
        upright = (np.sin(np.pi / 4), 0.0, 0.0, np.cos(np.pi / 4))  # its axis along y: in the xz plane
        b = ta.Builder()
        b.add_force_gravity()
        b.add_collider_plane((0, 1, 0), 0.0, friction=FRICTION, restitution=0.0)
        for k in range(count):
            turn = upright if k % 2 else (0.0, 0.0, 0.0, 1.0)
            b.add_rigid_body(ring, position=(k * spacing - count * spacing / 2, 1.0, 0.0), orientation=turn,
                             friction=FRICTION)  # fmt: skip
        self.model = b.finalize()
        self.state = self.model.state()
        self.stepper = ta.make_integrator("symplectic_euler").stepper_for(self.model)
        self.parts = len(ring.contact_parts() or ring.contact_prisms())

    def step(self, n=1):
        for _ in range(n):
            self.stepper.step(self.state, DT)


def timed(run):
    """Median seconds of `run()` over REPEATS calls after one warm-up (compile) call, and its result."""
    result = run()
    times = []
    for _ in range(REPEATS):
        a = clock()
        run()
        times.append(clock() - a)
    return statistics.median(times), result


def measure(engine):
    contacts = engine.stepper.solver("rigid bodies").contacts
    model, state = engine.model, engine.state
    t, n = {}, {}
    for stop, level in enumerate(LEVELS):
        t[level], n[level] = timed(lambda s=stop: contacts.cascade_pairs(model, state, DT, s, False))
    n["exact tests"] = contacts.cascade()["exact_tests"]  # of the last run, up to the exact test
    t["aabb alone"], n["aabb alone"] = timed(lambda: contacts.cascade_pairs(model, state, DT, 4, True))
    n["exact tests, aabb alone"] = contacts.cascade()["exact_tests"]
    # the cost of one test at each level: the time the level adds over the pairs that reach it
    cost = {}
    for before, level in zip(LEVELS, LEVELS[1:], strict=False):
        cost[level] = (t[level] - t[before]) / max(n[before], 1)
    cost["exact"] = (t["exact"] - t["obb"]) / max(n["obb"], 1)
    cost["exact, aabb alone"] = (t["aabb alone"] - t["aabb"]) / max(n["aabb"], 1)
    return t, n, cost


def main():
    args = parse_args(__doc__)
    full = not args.quick
    pyramid_side, bin_count, stick_count = (20, 1000, 300) if full else (8, 200, 60)
    chain_count = 20 if full else 6
    scenes = [
        (f"pyramid ({len(pyramid(pyramid_side))} boxes)", lambda: Ours(pyramid(pyramid_side)), 1.0),
        (f"bin ({bin_count} boxes)", lambda: Ours(bin_of_boxes(bin_count), BIN_HALF), 2.0),
        (f"sticks ({stick_count})", lambda: Ours(sticks(stick_count), BIN_HALF), 2.0),
        (f"chain ({chain_count} rings as convex parts)", lambda: Chain(chain_count), 1.0),
        (f"chain ({chain_count} rings as triangles)", lambda: Chain(chain_count, contact="triangles"), 1.0),
    ]
    rows, exact_rows, data = [], [], {}
    for name, make, settle in scenes:
        log(name)
        init("f32")
        engine = make()
        engine.step(round(settle / DT))
        t, n, cost = measure(engine)
        data[name] = dict(seconds=t, pairs=n, cost_s=cost)
        for level in LEVELS:
            c = cost.get(level)
            rows.append(
                [name, level, n[level], "–" if c is None else f"{c * 1e9:.0f}", f"{t[level] * 1e3:.3f}"]
            )
        rows.append([name, "exact, AABB alone", n["aabb alone"], f"{cost['exact, aabb alone'] * 1e9:.0f}",
                     f"{t['aabb alone'] * 1e3:.3f}"])  # fmt: skip
        tests, alone = n["exact tests"], n["exact tests, aabb alone"]
        exact_rows.append([name, tests, alone, f"{alone / max(tests, 1):.2f}",
                           f"{t['exact'] * 1e3:.3f}", f"{t['aabb alone'] * 1e3:.3f}"])  # fmt: skip
        log(f"  exact tests: {tests} after OBBs, {alone} after AABBs alone ({alone / max(tests, 1):.2f}x); "
            f"T {t['exact'] * 1e3:.3f} ms vs {t['aabb alone'] * 1e3:.3f} ms")  # fmt: skip
    page = Page(
        "rigid_cascade" if not args.quick else "rigid_cascade_quick",
        "The collision cascade: pairs and cost per level (spheres, AABB, OBB, exact)",
        args,
        {"dt": f"{DT} s", "ours": "f32, symplectic_euler, contact defaults, margin 2 cm", "repeats": REPEATS},
    )
    page.table(
        "Per scene and level",
        ["scene", "level", "pairs passing", "C per test reaching it [ns]", "T up to here [ms]"],
        rows,
        "pairs passing: how many pairs of bodies pass that level's test (pairs: those with a dynamic body); "
        "C: the time the level adds, per pair that reaches it (the pairs passing the level above); T: the "
        "cascade run over every pair up to and including that level, serial, median of the repeats. "
        "'exact, AABB alone' skips the OBB level: the exact test runs on every pair the AABBs pass.",
    )
    page.table(
        "Exact tests with the OBB level and without it",
        ["scene", "exact tests", "exact tests, AABB alone", "ratio", "T [ms]", "T, AABB alone [ms]"],
        exact_rows,
        "exact tests: pairs of convex parts given the exact test (one per pair of bodies for simple "
        "shapes); with the OBB level, between bodies and between parts; AABB alone: no OBB test at either "
        "level (bodies and the nodes of their trees: spheres, AABBs).",
    )
    page.write(data)


if __name__ == "__main__":
    main()
