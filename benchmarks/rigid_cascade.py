"""The course's collision cascade, measured (bodies/rigid/contacts.py): per level, how many pairs of bodies
reach it and what one test there costs, the cost model T = N_v C_v + N_p C_p summed over the levels
(bounding spheres, AABBs, OBBs, the exact test), and the exact tests the OBB level saves against AABBs
alone.

Scenes, each settled first (semi-implicit Euler, f32, DT = 2 ms, the contact defaults): the 210-box
pyramid, 1000 boxes poured into a bin (2 s), and a heap of 300 sticks (thin boxes 0.5 x 0.02 x 0.02 m,
turned at random, dropped into the same bin, 2 s): long bodies turned off the world axes, about which an
AABB is loose, the course's case for OBBs. Per level, `RigidContacts.cascade_pairs(stop)` runs the
cascade over every pair of bodies up to that level, timed (median of REPEATS runs after a warm-up);
C at a level is the time added by that level divided by the pairs that reach it. "AABB alone" runs the
exact test on every pair that passes the AABBs, skipping the OBB level, and is timed the same way.

    .venv/bin/python benchmarks/rigid_cascade.py [--quick]
"""

import statistics

import numpy as np
from harness import Page, clock, init, log, parse_args
from rigid import BIN_HALF, DT, Ours, bin_of_boxes, pyramid

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
    t["aabb alone"], n["aabb alone"] = timed(lambda: contacts.cascade_pairs(model, state, DT, 4, True))
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
    scenes = [
        (f"pyramid ({len(pyramid(pyramid_side))} boxes)", pyramid(pyramid_side), None, 1.0),
        (f"bin ({bin_count} boxes)", bin_of_boxes(bin_count), BIN_HALF, 2.0),
        (f"sticks ({stick_count})", sticks(stick_count), BIN_HALF, 2.0),
    ]
    rows, data = [], {}
    for name, boxes, walls, settle in scenes:
        log(name)
        init("f32")
        engine = Ours(boxes, walls)
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
        ratio = n["aabb"] / max(n["obb"], 1)
        log(f"  exact tests: {n['obb']} after OBBs, {n['aabb']} after AABBs alone ({ratio:.2f}x); "
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
    page.write(data)


if __name__ == "__main__":
    main()
