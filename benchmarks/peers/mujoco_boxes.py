"""The rigid benchmark's scenes in MuJoCo (extra `bench`): boxes as free bodies on a plane, Y up, the same
sizes, densities, friction and time step; MuJoCo's own solver (CG or Newton) and soft contacts."""

import mujoco
import numpy as np


def model_xml(boxes, *, dt: float, friction: float, solver: str, walls=None) -> str:
    """boxes: [(half extents (3,), position (3,), velocity (3,), angular velocity (3,), density)]; walls:
    the half-width [m] of a square bin of four planes around the origin, or None."""
    bodies = []
    for k, (half, pos, _v, _w, rho) in enumerate(boxes):
        h = " ".join(f"{c:.9g}" for c in half)
        p = " ".join(f"{c:.9g}" for c in pos)
        bodies.append(
            f'<body name="b{k}" pos="{p}"><freejoint/>'
            f'<geom type="box" size="{h}" density="{rho:.9g}" friction="{friction} 0.005 0.0001"/></body>'
        )
    return (
        f'<mujoco><option timestep="{dt}" solver="{solver}" gravity="0 -9.81 0"/>'
        f'<worldbody><geom type="plane" size="0 0 1" zaxis="0 1 0" friction="{friction} 0.005 0.0001"/>'
        + "".join(
            f'<geom type="plane" size="0 0 1" pos="{-walls * nx} 0 {-walls * nz}" zaxis="{nx} 0 {nz}" '
            f'friction="{friction} 0.005 0.0001"/>'
            for nx, nz in (() if walls is None else ((-1, 0), (1, 0), (0, -1), (0, 1)))
        )
        + "".join(bodies)
        + "</worldbody></mujoco>"
    )


class Scene:
    """A MuJoCo model and data of `boxes`; step(n) advances n steps; positions() (B,3) [m], speeds,
    penetration: the deepest contact's depth [m] now, contacts: their count now."""

    def __init__(self, boxes, *, dt: float, friction: float, solver: str = "CG", walls=None):
        xml = model_xml(boxes, dt=dt, friction=friction, solver=solver, walls=walls)
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        for k, (_h, _p, v, w, _rho) in enumerate(boxes):
            # a free joint's qvel: linear velocity (world), then angular velocity in the body's frame
            self.data.qvel[6 * k : 6 * k + 3] = v
            self.data.qvel[6 * k + 3 : 6 * k + 6] = w
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        mujoco.mj_step(self.model, self.data, nstep=n)  # n steps in one call, as ours take a frame

    def positions(self) -> np.ndarray:
        return self.data.xpos[1:].copy()

    def orientations(self) -> np.ndarray:
        """(B,4) (x, y, z, w)."""
        q = self.data.xquat[1:]  # (w, x, y, z)
        return np.column_stack([q[:, 1:], q[:, :1]])

    def kinetic_energy(self) -> float:
        mujoco.mj_energyVel(self.model, self.data)
        return float(self.data.energy[1])

    def contacts(self) -> int:
        return int(self.data.ncon)

    def penetration(self) -> float:
        n = self.data.ncon
        return float(max(0.0, -self.data.contact.dist[:n].min())) if n else 0.0


VERSION = mujoco.__version__
