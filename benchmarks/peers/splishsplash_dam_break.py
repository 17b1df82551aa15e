"""SPlisHSPlasH (pysplishsplash) on its own DamBreakModel scene, run in a child process: the wheel needs
the system's libGLdispatch preloaded, and its simulator crashes at interpreter exit after a run, so
fluid_dam_break.py starts this file with LD_PRELOAD set and reads the JSON it writes before exiting.

Usage: python splishsplash_dam_break.py OUT.json SECONDS SAMPLE_EVERY

Records per step: the wall and CPU clocks at the step's end (the time-step callback), simulated time,
step size, density and divergence iterations; every SAMPLE_EVERY steps the particles' densities (their
mean compression, max(rho / rho0 - 1, 0), the metric fluid_dam_break.py applies to both engines) and
at the first step the particles' positions and velocities (the particle set the engine is given)."""

import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def scene_file() -> Path:
    """DamBreakModel.json from the wheel's data folder (installed under the environment's bin/)."""
    return Path(sys.prefix) / "bin" / "data" / "Scenes" / "DamBreakModel.json"


def main(out: str, seconds: float, sample_every: int) -> None:
    import pysplishsplash as sph

    scene = scene_file()
    base = sph.Exec.SimulatorBase()
    base.init(useGui=False, sceneFile=str(scene), outputDir=str(Path(out).parent / "splishsplash_out"))
    base.setValueFloat(base.STOP_AT, float(seconds))
    steps, samples, first = [], [], {}
    started = {"wall": time.perf_counter()}

    def on_step():
        sim = sph.Simulation.getCurrent()
        ts, tm, fm = sim.getTimeStep(), sph.TimeManager.getCurrent(), sim.getFluidModel(0)
        iterations = (ts.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS),
                      ts.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS_V))  # fmt: skip
        clocks = (time.perf_counter(), time.process_time())
        steps.append([*clocks, float(tm.getTime()), float(tm.getTimeStepSize()), *iterations])
        n = fm.numActiveParticles()
        if len(steps) == 1:
            first["x"] = [[float(c) for c in fm.getPosition(i)] for i in range(n)]
            first["v"] = [[float(c) for c in fm.getVelocity(i)] for i in range(n)]
            first["radius"] = float(sim.getParticleRadius())
            first["density0"] = float(fm.getDensity0())
        if len(steps) % sample_every == 0:
            rho = np.array([fm.getDensity(i) for i in range(n)]) / fm.getDensity0()
            samples.append([len(steps) - 1, float(np.maximum(rho - 1.0, 0.0).mean()), float(rho.max() - 1.0)])
            steps[-1].append("sampled")  # this step's clock includes the sampling: not timed

    base.setTimeStepCB(on_step)
    base.run()
    record = {"steps": steps, "samples": samples, "first": first, "scene": str(scene),
              "threads": os.environ.get("OMP_NUM_THREADS"),
              "total_wall_s": time.perf_counter() - started["wall"]}  # fmt: skip
    Path(out).write_text(json.dumps(record))
    sys.stdout.flush()
    os._exit(0)  # skip the simulator's teardown, which crashes after a run


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), int(sys.argv[3]))
