"""Aerodynamic drag and lift on cloth triangles: each triangle is a flat plate in a uniform wind
(Hoerner, "Fluid-Dynamic Drag", 1965: flat plates normal and inclined to the flow; the per-triangle
model of cloth simulators: Keckeisen et al., "Modelling Effects of Wind Fields in Cloth Animations",
WSCG 2004; NVIDIA Warp's `eval_triangles`, k_drag and k_lift).
With the current vertices x_a and velocities v_a (a = 0, 1, 2):
    c = (x1 - x0) x (x2 - x0),  A = |c| / 2,  n = c / |c|
    u = w(t) - (v0 + v1 + v2) / 3   (air velocity relative to the panel),  s = |u|,  u_n = n . u
    w(t) = wind (1 + gust_amplitude sin(2 pi gust_frequency t))
    drag  f_d = 1/2 rho C_d A |u_n| u                      along the flow, on the area facing it
    lift  f_l = 1/2 rho C_l A u_n (s n - u_n u / s)        perpendicular to u, in the plane of u and n
and each vertex gets (f_d + f_l) / 3. With a the angle of attack (u_n = s sin a), |f_d| = 1/2 rho C_d A
s^2 sin a and |f_l| = 1/2 rho C_l A s^2 sin a cos a, the flat-plate lift; both are even in n, so the
winding of a triangle does not matter. Warp's drag is the same; its lift points along n with magnitude
k_lift A (pi/2 - acos(n . u/s)) s^2 and so also pushes on the plate normal to it (drag-like); here lift
is perpendicular to the flow, as the aerodynamic lift is.

Not conservative: no energy (has_energy = False). Linearisation for implicit steps: the force is explicit
except for the normal component of the drag, f_n = 1/2 rho C_d A |u_n| u_n, whose exact derivative is
d f_n / d u_n = rho C_d A |u_n| with d u_n / d v_b = -n^T / 3, so per vertex pair (a, b)
    K_v(a, b) = -(1/9) rho C_d A |u_n| n n^T,    S_ab = -h K_v(a, b)   (KV = 0)
S = (h rho C_d A |u_n| / 9) (1 1^T) (x) n n^T is symmetric positive semi-definite (rank one, stored as its
factor: rank_one.py): damping of the cloth's motion normal to itself, which is what keeps a fluttering
sheet stable at large steps. A and n are held fixed over the step (explicit in position, K_x = 0); the
tangential drag and the lift are explicit. Degenerate triangles (|c| = 0) and still air (s = 0) give
exactly zero force, not NaN.
"""

import math

import numpy as np
import taichi as ti

from .. import validate
from ..errors import ParameterError
from ..runtime import data_oriented
from .base import ElementTerm
from .rank_one import RankOneLinear

# Guards the two divisions (|c| for n, s for u / s): below it the force is zero or O(eps) anyway,
# since A = |c| / 2 multiplies everything and |u_n u / s| <= s.
_EPS = 1e-12


@data_oriented
class AeroTriangles(RankOneLinear, ElementTerm):
    """Flat-plate drag and lift on triangles (F,3) of particle indices, in a uniform wind [m/s] of
    air density [kg/m^3], with drag and lift coefficients (dimensionless) and an optional sinusoidal
    gust: wind (1 + gust_amplitude sin(2 pi gust_frequency t)), amplitude in [0, 1], frequency [Hz]."""

    arity = 3
    has_energy = False
    energy_kind = "source"  # the wind does work on the cloth

    def __init__(
        self,
        particle_count: int,
        triangles,
        *,
        wind=(0.0, 0.0, 0.0),
        density: float = 1.2,
        drag_coefficient: float = 1.2,
        lift_coefficient: float = 1.6,
        gust_amplitude: float = 0.0,
        gust_frequency: float = 0.0,
    ):
        particle_count = validate.count("particle_count", particle_count, 3)
        tris = validate.indices("triangles", triangles, 3, particle_count, "particles")
        if len(tris) == 0:
            raise ParameterError("triangles must hold at least one triangle, got none")
        self.wind = validate.vec3("wind", wind)
        self.density = validate.positive("density", density)
        # Defaults: C_d = 1.2 ~ Hoerner's square plate normal to the flow (1.17); C_l = 1.6 ~ the
        # small-angle lift slope pi AR / 2 of a square (AR = 1) plate, per radian.
        self.drag_coefficient = validate.non_negative("drag_coefficient", drag_coefficient)
        self.lift_coefficient = validate.non_negative("lift_coefficient", lift_coefficient)
        self.gust_amplitude = validate.in_range("gust_amplitude", gust_amplitude, 0.0, 1.0)
        self.gust_frequency = validate.non_negative("gust_frequency", gust_frequency)
        super().__init__(particle_count, tris)

    def settings(self) -> dict:
        """The term's settings for run.json."""
        return {
            "type": "aero_triangles",
            "count": self.count,
            "wind": self.wind,
            "density": self.density,
            "drag_coefficient": self.drag_coefficient,
            "lift_coefficient": self.lift_coefficient,
            "gust_amplitude": self.gust_amplitude,
            "gust_frequency": self.gust_frequency,
        }

    def speed_bound(self) -> float:
        """The strongest gust's speed |wind| (1 + gust_amplitude) [m/s]."""
        return float(np.linalg.norm(self.wind)) * (1.0 + self.gust_amplitude)

    # ---- element functions (base.py)

    @ti.func
    def panel(self, X, V, t):
        """Total force on the triangle, its unit normal, 1/2 rho A and u_n."""
        x0 = ti.Vector([X[0], X[1], X[2]])
        c = (ti.Vector([X[3], X[4], X[5]]) - x0).cross(ti.Vector([X[6], X[7], X[8]]) - x0)
        twice_area = ti.sqrt(c.dot(c))
        n = c / ti.max(twice_area, _EPS)
        w = ti.Vector(self.wind, dt=float)
        if ti.static(self.gust_amplitude != 0.0):
            w *= 1.0 + self.gust_amplitude * ti.sin(2.0 * math.pi * self.gust_frequency * t)
        vmid = ti.Vector([V[0] + V[3] + V[6], V[1] + V[4] + V[7], V[2] + V[5] + V[8]]) / 3.0
        u = w - vmid
        s = ti.sqrt(u.dot(u))
        un = n.dot(u)
        q = 0.25 * self.density * twice_area  # 1/2 rho A
        f = q * (
            self.drag_coefficient * ti.abs(un) * u
            + self.lift_coefficient * un * (s * n - un / ti.max(s, _EPS) * u)
        )
        return f, n, q, un

    @ti.func
    def spread(self, f):
        """The stacked 9-vector giving each vertex f / 3."""
        F = ti.Vector.zero(float, 9)
        for a in ti.static(range(3)):
            for r in ti.static(range(3)):
                F[3 * a + r] = f[r] / 3.0
        return F

    @ti.func
    def element_force(self, e, X, V, t):
        """Drag and lift [N] on the three vertices of triangle e, stacked (9,), at positions X [m] and
        velocities V [m/s]."""
        f, _, _, _ = self.panel(X, V, t)
        return self.spread(f)

    @ti.func
    def element_linear(self, e, X, V, t, h):
        """(F [N], S [kg], df/dx v [N/s]) of triangle e for step h [s]: the normal drag's velocity Jacobian as
        damping, the rest explicit."""
        f, n, q, un = self.panel(X, V, t)
        # S_ab = h (rho C_d A |u_n| / 9) n n^T for every pair (a, b); rho A = 2 q.
        blk = (h * 2.0 * q * self.drag_coefficient * ti.abs(un) / 9.0) * n.outer_product(n)
        S = ti.Matrix.zero(float, 9, 9)
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                for r in ti.static(range(3)):
                    for c in ti.static(range(3)):
                        S[3 * a + r, 3 * b + c] = blk[r, c]
        return self.spread(f), S, ti.Vector.zero(float, 9)

    @ti.func
    def element_rank_one(self, e, X, V, t, h):
        """(F [N], s [sqrt(kg)], df/dx v [N/s]) of triangle e: element_linear's S = s s^T with
        s = sqrt(h rho C_d A |u_n| / 9) (n, n, n) (rank_one.py)."""
        f, n, q, un = self.panel(X, V, t)
        w = ti.sqrt(h * 2.0 * q * self.drag_coefficient * ti.abs(un) / 9.0) * n
        s = ti.Vector([w[0], w[1], w[2], w[0], w[1], w[2], w[0], w[1], w[2]])
        return self.spread(f), s, ti.Vector.zero(float, 9)

    @ti.func
    def element_energy(self, e, X):
        """0: aerodynamic forces have no potential."""
        return 0.0
