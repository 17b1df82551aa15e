"""Constants, materials and run sizes of benchmarks/cloth_continuum_speed.py."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import taichi_anim as ta
from taichi_anim.scenes.cloth import FABRIC

GRAVITY = 9.81  # [m/s^2]
SIDE = 1.0  # [m]
HEIGHT = 1.0  # [m] the cloth starts in the plane y = HEIGHT
FRAME = 1.0 / 60.0  # [s]
SPRINGS = ta.ClothMaterial()
BETA = SPRINGS.stretch_damping / SPRINGS.stretch_stiffness  # [s] 5e-5
MEMBRANE = dataclasses.replace(FABRIC, damping=BETA)
MATERIALS = {"springs": SPRINGS, "membrane": MEMBRANE}
# The bending-only fabric of the mapping check: the membrane switched off (E > 0 is required).
BENDING_ONLY = dataclasses.replace(MEMBRANE, youngs_modulus=1e-9, damping=0.0, bending_damping=0.0)
MEMBRANE_UNDAMPED = dataclasses.replace(MEMBRANE, damping=0.0, bending_damping=0.0)
CHECK_EVERY = 10**9  # the divergence counter is read only where the benchmark reads positions
MAX_SPEED = 50.0  # [m/s]
SNAPSHOTS = 5
WARM_STEPS = 3
MIN_RUN_TIME = 0.3  # [s]
MAX_REPEATS = 3
IMPLICIT_MAX_ITERATIONS = 1000
STEPS2_CHECK_EVERY = 10
RUN_BUDGET_S = 15.0  # [s] of timed steps per part-2 run at most
IN_PLANE, OUT_OF_PLANE = "in-plane (membrane)", "out-of-plane (bending only)"
FORCE_AMPLITUDE = {IN_PLANE: 1e-3, OUT_OF_PLANE: 1e-2}  # [m]
LOADED_CORES = 0.1
SYMPLECTIC, IMPLICIT = "symplectic Euler", "implicit Euler (PCG)"


@dataclass(frozen=True)
class Settings:
    n: int
    t_end: float
    ref_dt: float  # RK4 reference step (checked at 2 ref_dt)
    sym_dts: tuple  # symplectic Euler steps, tried in order until one fails
    implicit_dts: tuple
    implicit_tols: tuple
    refine: tuple  # (factor, RK4 dt) of the membrane on refined meshes; the last is the continuum answer
    refine_check: int  # this factor runs again at half its dt
    springs_refine: tuple  # (factor, RK4 dt) of springs on a refined mesh
    sizes2: tuple
    tols2: tuple
    steps2: int
    newton_substeps: int


FULL = Settings(
    n=32,
    t_end=0.5,
    ref_dt=5e-5,
    sym_dts=tuple(1.0 / k for k in (20000, 10000, 5000, 4000, 3000, 2500, 2000, 1000)),
    implicit_dts=(1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 960),
    implicit_tols=(1e-4, 1e-6),
    refine=((2, 1e-4), (3, 1.0 / 15000)),
    refine_check=2,
    springs_refine=((2, 1e-4),),
    sizes2=(64, 128),
    tols2=(1e-3, 1e-4),
    steps2=60,
    newton_substeps=128,
)
QUICK = Settings(
    n=8,
    t_end=0.1,
    ref_dt=1e-4,
    sym_dts=tuple(1.0 / k for k in (10000, 5000, 2500, 1000, 500)),
    implicit_dts=(1 / 60, 1 / 120),
    implicit_tols=(1e-4,),
    refine=((2, 1e-4),),
    refine_check=0,
    springs_refine=(),
    sizes2=(16,),
    tols2=(1e-3, 1e-4),
    steps2=10,
    newton_substeps=32,
)
