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
        self.runtime_params = False  # compile-time constants unless bound to a bucketed model
        self.param = None

    def bind(self, model) -> None:
        """Under capacity buckets k and the wind are read from a field at run time: scenes often scale k
        with the vertex mass, which would make every size compile its own kernels."""
        self.runtime_params = model.size_buckets
        if self.runtime_params:
            self.param = model.new_field(self, "drag_param", float, (), (4,))
            self.param[None] = (self.k, *self.wind)

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
        k, wind = self._k_wind()
        return k * (wind - v)

    @ti.func
    def _k_wind(self):
        if ti.static(self.runtime_params):
            p = self.param[None]
            return p[0], ti.Vector([p[1], p[2], p[3]])
        else:
            return ti.cast(self.k, float), ti.Vector(self.wind, dt=float)

    @ti.func
    def jacobian(self, i, m, x, v, t):
        """(df/dx, df/dv) = (0, -k I) (3x3 each)."""
        k, _ = self._k_wind()
        return ti.Matrix.zero(float, 3, 3), -k * ti.Matrix.identity(float, 3)
