"""The rigid benchmark's scenes in PyBullet (extra `bench`): boxes on a plane, Y up, the same sizes,
densities, friction and time step; Bullet's sequential-impulse solver at its defaults (10 iterations,
split impulse), one substep per step."""

import numpy as np
import pybullet as pb


class Scene:
    """A DIRECT-mode PyBullet world of `boxes` (see peers/mujoco_boxes.py for the tuple), walls: the
    half-width [m] of a square bin of four planes, or None; the same methods as the MuJoCo peer."""

    def __init__(self, boxes, *, dt: float, friction: float, walls=None):
        self.client = pb.connect(pb.DIRECT)
        c = self.client
        pb.setGravity(0, -9.81, 0, physicsClientId=c)
        pb.setPhysicsEngineParameter(fixedTimeStep=dt, numSubSteps=0, physicsClientId=c)
        planes = [((0, 1, 0), (0, 0, 0))]
        if walls is not None:
            planes += [((-1, 0, 0), (walls, 0, 0)), ((1, 0, 0), (-walls, 0, 0)),
                       ((0, 0, -1), (0, 0, walls)), ((0, 0, 1), (0, 0, -walls))]  # fmt: skip
        for normal, at in planes:
            shape = pb.createCollisionShape(pb.GEOM_PLANE, planeNormal=normal, physicsClientId=c)
            body = pb.createMultiBody(0, shape, basePosition=at, physicsClientId=c)
            pb.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=c)
        self.bodies, self.masses = [], []
        for half, pos, v, w, rho in boxes:
            shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
            mass = rho * 8.0 * float(np.prod(half))
            body = pb.createMultiBody(mass, shape, basePosition=pos, physicsClientId=c)
            pb.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=c)
            pb.resetBaseVelocity(body, v, w, physicsClientId=c)
            self.bodies.append(body)
            self.masses.append(mass)

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            pb.stepSimulation(physicsClientId=self.client)

    def _poses(self):
        return [pb.getBasePositionAndOrientation(b, physicsClientId=self.client) for b in self.bodies]

    def positions(self) -> np.ndarray:
        return np.array([p for p, _ in self._poses()])

    def orientations(self) -> np.ndarray:
        """(B,4) (x, y, z, w)."""
        return np.array([q for _, q in self._poses()])

    def kinetic_energy(self) -> float:
        e = 0.0
        for body, mass in zip(self.bodies, self.masses, strict=True):
            v, w = (np.array(a) for a in pb.getBaseVelocity(body, physicsClientId=self.client))
            inertia = np.array(pb.getDynamicsInfo(body, -1, physicsClientId=self.client)[2])  # principal
            q = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)[1]
            r = np.array(pb.getMatrixFromQuaternion(q)).reshape(3, 3)
            local = r.T @ w
            e += 0.5 * mass * v @ v + 0.5 * local @ (inertia * local)
        return float(e)

    def _contacts(self):
        return pb.getContactPoints(physicsClientId=self.client)

    def contacts(self) -> int:
        return len(self._contacts())

    def penetration(self) -> float:
        depths = [c[8] for c in self._contacts()]  # contactDistance: negative when penetrating
        return float(max(0.0, -min(depths))) if depths else 0.0


VERSION = pb.getAPIVersion()
