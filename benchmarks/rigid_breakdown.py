"""Where a rigid step goes: the benchmark's tower and pyramid (rigid.py), settled for 1 s, then each part
of the contact step alone in a kernel of its own (detection, preparation with the collision phase, the
impulses' store, kick and drift), and whole steps at 1 + 1 to 32 + 16 sweeps, whose slope is one sweep.
Medians of 20-step launches after a warm-up; f32, 2 ms steps, as rigid.py."""

import taichi as ti
from harness import Page, init, log, median_time, parse_args
from rigid import DT, Ours, pyramid, tower

SWEEPS = ((1, 1), (4, 1), (8, 4), (16, 8), (32, 16))


def per_step(fn, steps: int, repeats: int) -> float:
    """Median seconds per step of fn(steps), after one warm-up call."""
    return median_time(lambda: fn(steps), repeats=repeats, warmup=1) / steps


def parts(engine) -> dict:
    """Seconds per step of each part of the contact step, run alone from the settled state."""
    dyn = engine.stepper.solver("rigid bodies")
    c, m, s = dyn.contacts, engine.model, engine.state

    @ti.kernel
    def detect(n: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(n):
            c.run_detect(m, s, 0.0, DT)

    @ti.kernel
    def prepare(n: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(n):
            c.run_prepare(m, s, DT, c.collision_sweeps)

    @ti.kernel
    def store(n: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(n):
            c.run_solve(m, s, 0, 1)

    @ti.kernel
    def kick_drift(n: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(n):
            dyn._kick_bodies(m, s, DT)
            dyn._drift_bodies(m, s, 0.0)

    return {
        name: per_step(k, 20, 10)
        for name, k in (("detection", detect), ("preparation", prepare), ("store", store),
                        ("kick and drift", kick_drift))
    }  # fmt: skip


def main():
    args = parse_args(__doc__)
    rows, data = [], {}
    for name, boxes in (("tower (20 boxes)", tower()), ("pyramid (210 boxes)", pyramid(20))):
        steps = {}
        for it, relax in SWEEPS:
            init("f32")
            engine = Ours(boxes, None, it, relax, 0)
            engine.step(500)
            steps[f"{it}+{relax}"] = per_step(engine.step, 50, 15)
            if (it, relax) == (4, 1):
                split = parts(engine)
                contacts = engine.contacts()
        # one sweep: the slope from 1 + 1 to 32 + 16 (46 sweeps more)
        sweep = (steps["32+16"] - steps["1+1"]) / 46
        data[name] = {"steps_s": steps, "parts_s": split, "sweep_s": sweep, "contacts": contacts}
        us = {k: f"{v * 1e6:.1f}" for k, v in {**steps, **split}.items()}
        log(name, us, f"sweep {sweep * 1e6:.1f} us")
        rows.append([name, contacts, *us.values(), f"{sweep * 1e6:.1f}", f"{sweep / contacts * 1e9:.0f}"])
    page = Page(
        "rigid_breakdown",
        "Where a rigid step goes: detection, preparation, sweeps",
        args,
        {"dt": f"{DT} s", "precision": "f32", "scenes": "rigid.py's tower and pyramid, settled 1 s",
         "parts": "each part alone in a serial kernel of its own, from the settled state of 4 + 1 sweeps"},
    )  # fmt: skip
    page.table(
        "Microseconds per step",
        ["scene", "contacts", *(f"step {k}" for k in (f"{i}+{r}" for i, r in SWEEPS)),
         "detection", "preparation", "store", "kick and drift", "one sweep", "ns per contact-sweep"],
        rows,
        "step i+r: a whole step at i biased and r relaxed sweeps, in frames of 50 steps; one sweep: the "
        "slope of those steps over the sweeps' count.",
    )  # fmt: skip
    page.write(data)


if __name__ == "__main__":
    main()
