"""Linear drag relative to the air, f = k (w - v); wind is a non-zero air velocity w
(Witkin & Baraff, "Physically Based Modeling", particle dynamics: viscous drag)."""

import numpy as np
import taichi as ti

from ..runtime import data_oriented
from .base import PointTerm


@data_oriented
class Drag(PointTerm):
    """Linear drag with coefficient `k` [kg/s] towards the air velocity `wind` [m/s]."""

    def __init__(self, k: float, wind=(0.0, 0.0, 0.0)):
        self.k = float(k)
        self.wind = tuple(float(c) for c in wind)

    def settings(self) -> dict:
        """The term's settings for run.json: type (drag or wind), k [kg/s], wind [m/s]."""
        return {"type": "wind" if any(self.wind) else "drag", "k": self.k, "wind": self.wind}

    @property
    def energy_kind(self) -> str:
        """ "dissipative" in still air; "source" in wind (it drives particles towards the wind speed)."""
        return "source" if any(self.wind) else "dissipative"

    def speed_bound(self) -> float:
        """|wind| [m/s]."""
        return float(np.linalg.norm(self.wind))

    def static_potential(self, x, masses) -> float:
        """At v = 0 the force is the constant k w on each free particle: potential -sum k w.x [J]."""
        free = np.asarray(masses) > 0.0
        return -float(np.sum(np.asarray(x, dtype=np.float64)[free] @ (self.k * np.asarray(self.wind))))

    def point_blocks(self, x, v, t: float):
        """(-df/dx, -df/dv) = (0, k I) per particle (N,3,3)."""
        n = len(x)
        return np.zeros((n, 3, 3)), np.broadcast_to(self.k * np.eye(3), (n, 3, 3)).copy()

    @ti.func
    def force(self, i, m, x, v, t):
        """k (wind - v) [N] on particle i at velocity v [m/s]."""
        return self.k * (ti.Vector(self.wind, dt=float) - v)

    @ti.func
    def jacobian(self, i, m, x, v, t):
        """(df/dx, df/dv) = (0, -k I) (3x3 each)."""
        return ti.Matrix.zero(float, 3, 3), -self.k * ti.Matrix.identity(float, 3)
