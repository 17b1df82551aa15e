"""Dihedral bending of a triangle mesh: the bending energy of Discrete Shells (Grinspun, Hirani, Desbrun
& Schröder, "Discrete Shells", SCA 2003, sec. 3) with the dihedral-angle gradient of Bridson, Marino &
Fedkiw ("Simulation of clothing with folds and wrinkles", SCA 2003, sec. 4; also Tamstorf & Grinspun,
"Discrete bending forces and their Jacobians", Graphical Models 75(6) 2013).

A hinge is two triangles sharing an edge, (x0, x1, x2, x3): x0-x1 the shared edge, triangles (x0,x1,x2)
and (x1,x0,x3) in the mesh's orientation (mesh_hinges). With e = x1 - x0 and unnormalised normals
    n1 = e x (x2 - x0),  n2 = (x3 - x0) x e,   theta = atan2((n2^ x n1^) . e^, n1^ . n2^)  in (-pi, pi]
(atan2 of both: accurate near flat and near fully folded, where acos or asin alone lose digits);
theta > 0 when the hinge folds towards the normals' side. Its gradient, with a_i = (x_i - x0).e / |e|^2
the position of x_i's foot along the edge:
    g2 = |e| n1 / |n1|^2,  g3 = |e| n2 / |n2|^2,  g0 = -(1 - a2) g2 - (1 - a3) g3,  g1 = -a2 g2 - a3 g3
(|g2| = 1 / height of x2 over the edge; g0, g1 make theta invariant under translations and rotations).

Energy, per hinge, with theta0 the rest angle (so a curved garment keeps its shape) and weights from the
REST shape, |e0| the rest edge length and A1, A2 the rest triangle areas:
    E = (k/2) w (theta - theta0)^2,   w = |e0|^2 / (A1 + A2),   k [N m] the bending stiffness,
as for a plate D = Y t^3 / (12 (1 - nu^2)). theta - theta0 is wrapped into (-pi, pi]: the energy is smooth
around the rest angle for every theta0 (a crease near +-pi included); its one jump is at the pose
opposite the rest angle. Why this constant: bend a grid mesh (spacing a across, c along the axis, one
diagonal per quad) isometrically into a cylinder of curvature kappa. Every quad stays a planar chord
rectangle, so diagonals and edges across the axis stay flat, and each hinge on an axis-parallel edge
turns by theta = kappa a exactly, with w = c^2 / (a c): E = (k/2) kappa^2 a c per hinge, i.e. the plate's
(D/2) kappa^2 per area of the hinge's two triangles. On other meshes the constant depends on the mesh,
a known property of discrete shells: on an equilateral mesh cylindrical bending gets D/2 kappa^2 too
(exactly about an edge direction, to O((kappa a)^2) otherwise), but a sphere gets 2/3 of the energy of a
nu = 0 plate (the mesh acts as a plate with nu = -1/3; tests/test_term_bending.py measures both).
These hold for prescribed (isometric) shapes. When the mesh is free to find its own minimum, square grid
cells relax the hinge energy through a grid-scale zig-zag of the vertex heights: a clamped strip on square
cells comes out ~22% softer than a plate of stiffness D (tip error +23% in the limit), while cells 4x
longer along the bend match Euler-Bernoulli to first order (tests/test_continuum_statics.py).

Force f = -k w (theta - theta0) g - beta k w g (g . v), the second part Rayleigh damping [s] with the
stiffness K below, so it never adds energy. Linearised (Gauss-Newton): K = k w g g^T, rank one and
positive semi-definite. The exact stiffness -df/dx = k w (g g^T + (theta - theta0) Hess(theta)) has an
indefinite second part, dropped here; it vanishes at the rest angle, where K is exact. Then
S = -(h df/dv + h^2 df/dx) = (h beta + h^2) K and df/dx v = -K v; the x-derivative of the damping force
is left out (Baraff & Witkin, "Large Steps in Cloth Simulation", 1998, sec. 5). A triangle that
collapses in motion (|n| = 0) gives its wing g = 0 and theta = atan2(0, 0) = 0, not NaN (|e|^2, |n|^2 are
floored at 1e-30); near collapse |g| ~ 1/height grows like the exact gradient (the membrane term is what
keeps triangles from collapsing).
"""

import math

import numpy as np
import taichi as ti

from .. import bulk, capacity, validate
from ..errors import ParameterError
from ..runtime import data_oriented, np_float
from .base import ElementTerm
from .rank_one import RankOneLinear

_TINY = 1e-30  # [m^2, m^4] floor of |e|^2 and |n|^2: representable in f32, far below any real mesh


def mesh_hinges(triangles) -> np.ndarray:
    """Hinges (H,4) of a consistently oriented triangle mesh (F,3): one per edge shared by exactly two
    triangles, (x0, x1, x2, x3) with x0-x1 the edge as the first of its triangles (lowest index) walks it,
    x2 that triangle's third vertex and x3 the other's, so (x0,x1,x2) and (x1,x0,x3) keep the mesh's
    orientation. Sorted by edge (lower, then higher vertex index). Boundary edges (one triangle) and
    non-manifold edges (three or more) get no hinge; two triangles walking their edge the same way
    (inconsistent orientation) raise ParameterError."""
    tri = validate.indices("triangles", triangles, 3, np.iinfo(np.int32).max, "vertices").astype(np.int64)
    u, v, w = tri.reshape(-1), tri[:, [1, 2, 0]].reshape(-1), tri[:, [2, 0, 1]].reshape(-1)
    lo, hi = np.minimum(u, v), np.maximum(u, v)
    owner = np.repeat(np.arange(len(tri)), 3)
    order = np.lexsort((owner, hi, lo))  # each edge's half-edges adjacent, lowest triangle first
    lo, hi = lo[order], hi[order]
    new = np.ones(len(order) + 1, dtype=bool)
    new[1:-1] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    start = np.flatnonzero(new)
    size = np.diff(start)
    first = order[start[:-1][size == 2]]
    second = order[start[:-1][size == 2] + 1]
    bad = np.flatnonzero(u[first] != v[second])
    if bad.size:
        a, b = first[bad[0]], second[bad[0]]
        raise ParameterError(
            f"triangles: {bad.size} edges are walked the same way by both their triangles (inconsistent "
            f"orientation); first edge {[int(u[a]), int(v[a])]} in triangles {a // 3} and {b // 3}"
        )
    return np.stack([u[first], v[first], w[first], w[second]], axis=1)


def hinge_angles(positions, hinges) -> np.ndarray:
    """Signed dihedral angles theta (H,) [rad] of hinges (H,4) at positions (N,3), as in the kernels."""
    p = np.asarray(positions, dtype=np.float64)[np.asarray(hinges, dtype=np.int64)]
    e = p[:, 1] - p[:, 0]
    n1, n2 = np.cross(e, p[:, 2] - p[:, 0]), np.cross(p[:, 3] - p[:, 0], e)
    n1 /= np.sqrt(np.maximum((n1 * n1).sum(1), _TINY))[:, None]
    n2 /= np.sqrt(np.maximum((n2 * n2).sum(1), _TINY))[:, None]
    e /= np.sqrt(np.maximum((e * e).sum(1), _TINY))[:, None]
    return np.arctan2((np.cross(n2, n1) * e).sum(1), (n1 * n2).sum(1))


@ti.func
def hinge_angle_gradient(X):
    """theta and its gradient g (12-vector, vertex a at rows 3a..3a+2) of a stacked hinge X."""
    x0 = ti.Vector([X[0], X[1], X[2]])
    e = ti.Vector([X[3], X[4], X[5]]) - x0
    d2 = ti.Vector([X[6], X[7], X[8]]) - x0
    d3 = ti.Vector([X[9], X[10], X[11]]) - x0
    n1, n2 = e.cross(d2), d3.cross(e)
    ee = ti.max(e.dot(e), _TINY)
    q1, q2 = ti.max(n1.dot(n1), _TINY), ti.max(n2.dot(n2), _TINY)
    r1, r2, re = 1.0 / ti.sqrt(q1), 1.0 / ti.sqrt(q2), 1.0 / ti.sqrt(ee)
    # atan2 of sin and cos, each to ~eps absolute: theta to ~eps at any angle (acos loses half the
    # digits near 0 and pi, asin near pi/2).
    theta = ti.atan2((n2.cross(n1)).dot(e) * (r1 * r2 * re), n1.dot(n2) * (r1 * r2))
    length = ee * re
    g2, g3 = (length / q1) * n1, (length / q2) * n2
    a2, a3 = d2.dot(e) / ee, d3.dot(e) / ee
    g0 = -(1.0 - a2) * g2 - (1.0 - a3) * g3
    g1 = -a2 * g2 - a3 * g3
    g = ti.Vector.zero(float, 12)
    for c in ti.static(range(3)):
        g[c], g[3 + c], g[6 + c], g[9 + c] = g0[c], g1[c], g2[c], g3[c]
    return theta, g


@data_oriented
class BendingDihedral(RankOneLinear, ElementTerm):
    """Discrete-shells bending on hinges (H,4) of particle indices (mesh_hinges), rest shape
    rest_positions (N,3) [m] (gives each hinge's rest angle and weight); stiffness k [N m] (a plate's
    D = Y t^3 / (12 (1 - nu^2))), damping beta [s] (Rayleigh, stiffness-proportional)."""

    arity = 4
    energy_kind = "potential"  # the hinge energy; the Rayleigh damping only removes energy

    def __init__(
        self, particle_count: int, hinges, rest_positions, *, stiffness: float, damping: float = 0.0
    ):
        particle_count = validate.count("particle_count", particle_count, 1)
        rest = validate.finite_array("rest_positions", rest_positions, (3,))
        if len(rest) != particle_count:
            raise ParameterError(f"rest_positions must have {particle_count} rows, got {len(rest)}")
        hin = validate.indices("hinges", hinges, 4, particle_count, "particles").astype(np.int64)
        if len(hin) == 0:
            raise ParameterError("hinges must hold at least one hinge, got none")
        srt = np.sort(hin, axis=1)
        rep = np.flatnonzero((srt[:, 1:] == srt[:, :-1]).any(1))
        if rep.size:
            raise ParameterError(f"hinges: hinge {int(rep[0])} repeats a particle: {hin[rep[0]].tolist()}")
        self.stiffness = validate.positive("stiffness", stiffness)
        self.beta = validate.non_negative("damping", damping)
        p = rest[hin]
        e = p[:, 1] - p[:, 0]
        ee = (e * e).sum(1)
        area1 = 0.5 * np.linalg.norm(np.cross(e, p[:, 2] - p[:, 0]), axis=1)
        area2 = 0.5 * np.linalg.norm(np.cross(p[:, 3] - p[:, 0], e), axis=1)
        scale2 = np.max(((p[:, :, None] - p[:, None]) ** 2).sum(-1), axis=(1, 2))  # longest side^2
        bad = np.flatnonzero(~(np.minimum(area1, area2) > 0.5e-12 * scale2))  # relative, as membrane.py
        if bad.size:
            k = int(bad[0])
            raise ParameterError(
                f"hinges: {bad.size} hinges have a zero-area rest triangle; first hinge {k} "
                f"{hin[k].tolist()} (rest areas {area1[k]:g}, {area2[k]:g} m^2)"
            )
        self.rest_angle = hinge_angles(rest, hin)
        self.weight = ee / (area1 + area2)
        super().__init__(particle_count, hin)

    def place_arrays(self, make, rows: int) -> None:
        """Per hinge: theta0, k w, beta (beta per hinge so a Builder can merge garments with their own)."""
        param = np.stack([self.rest_angle, self.stiffness * self.weight, np.full(self.count, self.beta)], 1)
        self.hinge_param = make(self, "hinge_param", float, rows, (3,))
        bulk.fill([(self.hinge_param, capacity.padded(param, rows, np_float()))])

    @classmethod
    def from_mesh(cls, particle_count: int, triangles, rest_positions, **kw) -> "BendingDihedral":
        """The term on every interior edge of a triangle mesh (F,3) (mesh_hinges)."""
        return cls(particle_count, mesh_hinges(triangles), rest_positions, **kw)

    def settings(self) -> dict:
        """The term's settings for run.json."""
        return {
            "type": "bending_dihedral",
            "count": self.count,
            "stiffness": self.stiffness,
            "damping": self.beta,
        }

    # ---- element functions (per hinge; X, V stacked 12-vectors)

    @ti.func
    def excess(self, e, X):
        """(theta - theta0 wrapped into (-pi, pi], g, the hinge's parameters)."""
        theta, g = hinge_angle_gradient(X)
        p = self.hinge_param[e]
        d = theta - p[0]
        if d > math.pi:
            d -= 2.0 * math.pi
        elif d <= -math.pi:
            d += 2.0 * math.pi
        return d, g, p

    @ti.func
    def element_energy(self, e, X):
        """Bending energy [J] of hinge e at stacked positions X (12,) [m]."""
        d, _g, p = self.excess(e, X)
        return 0.5 * p[1] * d * d

    @ti.func
    def element_force(self, e, X, V, t):
        """Bending and damping forces [N] on the four vertices of hinge e, stacked (12,)."""
        d, g, p = self.excess(e, X)
        return -p[1] * (d + p[2] * g.dot(V)) * g

    @ti.func
    def element_linear(self, e, X, V, t, h):
        """(F [N], S [kg], df/dx v [N/s]) of hinge e for step h [s] (Gauss-Newton part, rank one)."""
        d, g, p = self.excess(e, X)
        gv = g.dot(V)
        f = -p[1] * (d + p[2] * gv) * g
        S = (p[1] * (h * p[2] + h * h)) * g.outer_product(g)  # rank one: (h beta + h^2) k w g g^T
        return f, S, -p[1] * gv * g

    @ti.func
    def element_rank_one(self, e, X, V, t, h):
        """(F [N], s [sqrt(kg)], df/dx v [N/s]) of hinge e for step h [s]: element_linear's S = s s^T
        (rank_one.py: 4 vectors per hinge instead of 16 3x3 blocks, S p in 8 dot products)."""
        d, g, p = self.excess(e, X)
        gv = g.dot(V)
        f = -p[1] * (d + p[2] * gv) * g
        kv = -p[1] * gv * g
        s = ti.sqrt(p[1] * (h * p[2] + h * h)) * g
        return f, s, kv
