"""Damped springs between particles (cloth's structural, shear and bend springs), Baraff & Witkin,
"Large Steps in Cloth Simulation" (1998), sec. 4 and eq. 16, with the spring as the condition C = l - L:
    f_i = -(k (l - L) + c (v_i - v_j) . n) n,   d = x_i - x_j, l = |d|, n = d / l,   f_j = -f_i
    df_i/dx_i = -k [n n^T + (1 - L/l) (I - n n^T)],   df_i/dv_i = -c n n^T   (df_i/dx_j = -df_i/dx_i)
Under compression (l < L) the transverse part (1 - L/l) is negative and makes the implicit system
indefinite; it is clamped at 0 (Choi & Ko, "Stable but Responsive Cloth", 2002, sec. 5): the stretched
case is exact, a compressed spring keeps only its axial stiffness (so a buckling cloth is not forced
to stay flat). The x-derivative of the damping force is left out, as Baraff & Witkin do (sec. 5).

Forces are gathered per particle over its springs (compressed row storage sorted by particle): each
spring is evaluated from both ends, twice the arithmetic of a scatter, but no float atomics, so every
particle's force is a fixed-order sum (deterministic at any thread count) and loops fuse with the update.
"""

import numpy as np
import taichi as ti

from ..runtime import data_oriented, np_float

_EPS = 1e-12


@ti.func
def spring_force(d, dv, rest, k, c):
    """Force on the end at x_i of one spring, d = x_i - x_j, dv = v_i - v_j."""
    length = d.norm()
    n = d / ti.max(length, _EPS)
    return -(k * (length - rest) + c * dv.dot(n)) * n


@ti.func
def spring_frame(d, rest):
    """Unit direction n and the clamped transverse factor max(1 - L/l, 0) of the spring d = x_i - x_j."""
    length = d.norm()
    n = d / ti.max(length, _EPS)
    return n, ti.max(1.0 - rest / ti.max(length, _EPS), 0.0)


@ti.func
def spring_stiffness_apply(n, axial, transverse, p):
    """(axial n n^T + transverse (I - n n^T)) p without forming the matrix."""
    t = n.dot(p)
    return transverse * p + (axial - transverse) * t * n


@data_oriented
class Springs:
    """Springs of a model. pairs (S,2) particle indices; rest_length (S,) [m]; stiffness (S,) [N/m];
    damping (S,) [kg/s] along the spring; family (S,) int (0 stretch, 1 shear, 2 bend; for reports)."""

    def __init__(self, particle_count: int, pairs, rest_length, stiffness, damping, family=None):
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        s = len(pairs)
        self.count = s
        self.pairs = pairs
        self.rest_length = np.asarray(rest_length, dtype=np.float64)
        self.stiffness = np.asarray(stiffness, dtype=np.float64)
        self.damping = np.asarray(damping, dtype=np.float64)
        self.family = np.zeros(s, np.int8) if family is None else np.asarray(family, np.int8)
        # Both directed copies of every spring, sorted by the particle that gathers them.
        owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
        other = np.concatenate([pairs[:, 1], pairs[:, 0]])
        spring = np.concatenate([np.arange(s), np.arange(s)])
        order = np.lexsort((other, owner))
        counts = np.bincount(owner, minlength=particle_count)
        start = np.zeros(particle_count + 1, dtype=np.int32)
        np.cumsum(counts, out=start[1:])
        self.entry_count = 2 * s
        self.max_degree = int(counts.max()) if s else 0
        f = np_float()
        self.adj_start = ti.field(ti.i32, particle_count + 1)
        self.adj_other = ti.field(ti.i32, 2 * s)
        self.adj_param = ti.Vector.field(3, float, 2 * s)  # rest length, stiffness, damping
        self.adj_start.from_numpy(start)
        self.adj_other.from_numpy(other[order].astype(np.int32))
        sp = spring[order]
        param = np.stack([self.rest_length[sp], self.stiffness[sp], self.damping[sp]], axis=1)
        self.adj_param.from_numpy(param.astype(f))
        # Implicit solves store per entry the direction and the two stiffnesses of
        # S = -(h df/dv + h^2 df/dx) = axial n n^T + transverse (I - n n^T) (allocated on first use).
        self.adj_n = None
        self.adj_ab = None

    def settings(self) -> dict:
        names = ("stretch", "shear", "bend")
        fam = {names[k]: int((self.family == k).sum()) for k in range(3) if (self.family == k).any()}
        return {"type": "springs", "count": self.count, "families": fam}

    def ensure_implicit(self) -> None:
        if self.adj_n is None:
            self.adj_n = ti.Vector.field(3, float, self.entry_count)
            self.adj_ab = ti.Vector.field(2, float, self.entry_count)

    @ti.func
    def force(self, i, xf: ti.template(), vf: ti.template()):
        """Sum of spring forces on particle i at the positions xf and velocities vf (fields)."""
        xi = xf[i]
        vi = vf[i]
        f = ti.Vector.zero(float, 3)
        for e in range(self.adj_start[i], self.adj_start[i + 1]):
            j = self.adj_other[e]
            p = self.adj_param[e]
            f += spring_force(xi - xf[j], vi - vf[j], p[0], p[1], p[2])
        return f

    @ti.func
    def assemble(self, i, xf: ti.template(), vf: ti.template(), h):
        """Spring force on i, (df/dx v)_i, and the diagonal block sum_s S_s; stores each entry's n and
        (axial, transverse) of S_s = -(h df/dv + h^2 df/dx) for the matrix-free products."""
        xi = xf[i]
        vi = vf[i]
        f = ti.Vector.zero(float, 3)
        kxv = ti.Vector.zero(float, 3)
        diag = ti.Matrix.zero(float, 3, 3)
        eye = ti.Matrix.identity(float, 3)
        for e in range(self.adj_start[i], self.adj_start[i + 1]):
            j = self.adj_other[e]
            p = self.adj_param[e]
            d = xi - xf[j]
            dv = vi - vf[j]
            f += spring_force(d, dv, p[0], p[1], p[2])
            n, tr = spring_frame(d, p[0])
            # df/dx (v_i - v_j) with the clamped Jacobian, so b matches the matrix that is solved.
            kxv -= spring_stiffness_apply(n, p[1], p[1] * tr, dv)
            axial = h * p[2] + h * h * p[1]
            transverse = h * h * p[1] * tr
            self.adj_n[e] = n
            self.adj_ab[e] = ti.Vector([axial, transverse])
            nn = n.outer_product(n)
            diag += axial * nn + transverse * (eye - nn)
        return f, kxv, diag

    @ti.func
    def apply(self, i, pf: ti.template()):
        """sum_s S_s (p_i - p_j) over the springs of i (the off-diagonal and spring-diagonal part of the
        implicit matrix times p; the solvers keep p zero at pinned particles)."""
        pi = pf[i]
        acc = ti.Vector.zero(float, 3)
        for e in range(self.adj_start[i], self.adj_start[i + 1]):
            ab = self.adj_ab[e]
            acc += spring_stiffness_apply(self.adj_n[e], ab[0], ab[1], pi - pf[self.adj_other[e]])
        return acc
