"""Damped spring from a particle to a fixed anchor point (Baraff & Witkin, "Large Steps in Cloth
Simulation", 1998, eq. 16 with one end fixed):
    f = -k (l - L0) n - c (v . n) n,   d = x - anchor, l = |d|, n = d / l
    df/dx = -k [n n^T + (1 - L0/l) (I - n n^T)],   df/dv = -c n n^T
The transverse part (1 - L0/l) is clamped at 0 under compression so the implicit system stays positive
definite (Choi & Ko, "Stable but Responsive Cloth", 2002); it is exact whenever the spring is stretched.
The x-derivative of the damping force (through n) is left out, as Baraff & Witkin do (sec. 5): it is
not symmetric and would break the symmetric solvers; it vanishes when the relative velocity does.
"""

import numpy as np
import taichi as ti

from ..runtime import data_oriented, np_float
from .base import PointTerm

_EPS = 1e-12


@data_oriented
class AnchorSpring(PointTerm):
    """Per-particle anchor springs; a particle without one has stiffness 0.

    anchor (N,3) [m], stiffness (N,) [N/m], rest_length (N,) [m], damping (N,) [kg/s].
    """

    def __init__(self, particle_count: int, springs: list[tuple[int, tuple, float, float, float]]):
        n = particle_count
        anchor = np.zeros((n, 3))
        params = np.zeros((n, 3))  # stiffness, rest length, damping
        for i, a, k, rest, c in springs:
            anchor[i] = a
            params[i] = (k, rest, c)
        self.anchor = ti.Vector.field(3, float, n)
        self.params = ti.Vector.field(3, float, n)
        self.anchor.from_numpy(anchor.astype(np_float()))
        self.params.from_numpy(params.astype(np_float()))
        self.count = len(springs)
        self._arrays = None  # (anchor, params) as the fields hold them, in float64 (read once)

    energy_kind = "potential"  # the spring's; its damping only removes energy

    def settings(self) -> dict:
        """The term's settings for run.json: type and spring count."""
        return {"type": "anchor_spring", "count": self.count}

    def _numpy(self):
        if self._arrays is None:
            self._arrays = (
                self.anchor.to_numpy().astype(np.float64),
                self.params.to_numpy().astype(np.float64),
            )
        return self._arrays

    def energy(self, x, masses=None) -> float:
        """Elastic energy sum k (|x - anchor| - L0)^2 / 2 [J] at positions x (N,3) [m]."""
        anchor, p = self._numpy()
        d = np.linalg.norm(np.asarray(x, dtype=np.float64) - anchor, axis=1)
        return 0.5 * float(np.sum(p[:, 0] * (d - p[:, 1]) ** 2))

    def point_blocks(self, x, v, t: float):
        """(-df/dx, -df/dv) (N,3,3): k [n n^T + max(1 - L0/l, 0) (I - n n^T)] and c n n^T."""
        anchor, p = self._numpy()
        stiff, rest, damp = p.T
        d = np.asarray(x, dtype=np.float64) - anchor
        length = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        nrm = d / length[:, None]
        nn = nrm[:, :, None] * nrm[:, None, :]
        tr = np.maximum(1.0 - rest / length, 0.0)
        return stiff[:, None, None] * (nn + tr[:, None, None] * (np.eye(3) - nn)), damp[:, None, None] * nn

    @ti.func
    def _frame(self, i, x):
        d = x - self.anchor[i]
        length = d.norm()
        n = d / ti.max(length, _EPS)
        return length, n

    @ti.func
    def force(self, i, m, x, v, t):
        """-k (|d| - L0) n - c (v . n) n [N] on particle i at x [m], v [m/s], d = x - anchor, n = d / |d|
        (parameters 0 for a particle without an anchor)."""
        p = self.params[i]
        length, n = self._frame(i, x)
        return -p[0] * (length - p[1]) * n - p[2] * v.dot(n) * n

    @ti.func
    def jacobian(self, i, m, x, v, t):
        """(df/dx [N/m], df/dv [kg/s]) of particle i's anchor spring (3x3 each), the transverse part clamped
        at 0 when compressed."""
        p = self.params[i]
        length, n = self._frame(i, x)
        nn = n.outer_product(n)
        transverse = ti.max(1.0 - p[1] / ti.max(length, _EPS), 0.0)
        eye = ti.Matrix.identity(float, 3)
        return -p[0] * (nn + transverse * (eye - nn)), -p[2] * nn
