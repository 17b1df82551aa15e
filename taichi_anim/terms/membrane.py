"""Saint Venant-Kirchhoff triangle membrane (constant-strain triangles): Volino, Magnenat-Thalmann &
Faure, "A simple approach to nonlinear tensile stiffness for accurate cloth simulation", ACM TOG 28(4)
2009; the tangent stiffness as in Bonet & Wood, "Nonlinear Continuum Mechanics for Finite Element
Analysis" (2nd ed. 2008), sec. 9.2 (material + initial-stress parts). Per triangle, with rest vertices
in 2D material coordinates (u = warp_direction projected on the triangle's plane, v = n x u; the first
edge's direction when the projection is shorter than 1e-6) and Dm = [X1 - X0, X2 - X0] (2x2):
    F = Ds Dm^-1 (3x2),  Ds = [x1 - x0, x2 - x0],  G = (F^T F - I) / 2,  e = (G00, G11, 2 G01)
    S = C e (second Piola-Kirchhoff stress, Voigt),  E = A0 e . C e / 2
    f_a = -A0 P Dm^-T column a (a = 1, 2), f_0 = -f_1 - f_2,  P = F S (first Piola-Kirchhoff)
with C the plane-stress matrix [N/m] (areal: Young's modulus times thickness). Isotropic:
C = E/(1 - nu^2) [[1, nu, 0], [nu, 1, 0], [0, 0, (1 - nu)/2]]. Orthotropic (warp 1, weft 2):
C = 1/(1 - nu12 nu21) [[E1, nu21 E1, 0], [nu12 E2, E2, 0], [0, 0, G12 (1 - nu12 nu21)]],
nu21 = nu12 E2 / E1 (so C is symmetric); it must be positive definite (nu12^2 E2 < E1).

Why StVK and not co-rotational: it is rotation invariant with an exact closed-form force and Hessian
(a co-rotational element needs the derivative of the polar decomposition, usually dropped, so its
"Jacobian" is not the true one), and its Hessian becomes positive semi-definite by one clamp. For a
direction dX, dF = dDs Dm^-1 and dG = sym(F^T dF):
    d2E = A0 [dG : C : dG  +  tr(S dF^T dF)]
The material part is PSD since C is; the geometric (stress) part is indefinite when S has a negative
eigenvalue (compression). With projected=True (default) S is replaced by its positive part S+ in the
geometric part only: K stays PSD, is exact whenever both principal stresses are >= 0, and a compressed
direction keeps only its material stiffness, the rule of Choi & Ko ("Stable but Responsive Cloth",
2002) for springs. projected=False keeps the exact Hessian (for tests).

Damping is stiffness-proportional (Rayleigh): f_d = -beta K v with the same (projected, so PSD) K, so
it never adds energy. Linearised: S = -(h df/dv + h^2 df/dx) = (h beta + h^2) K, and df/dx v = -K v; the
x-derivative of the damping force is left out, as Baraff & Witkin ("Large Steps in Cloth Simulation",
1998, sec. 5) do for springs. Element loops, caches and gathers live in ElementTerm (base.py).
"""

import numpy as np
import taichi as ti

from .. import bulk, capacity, validate
from ..errors import ParameterError
from ..runtime import data_oriented, np_float
from .base import ElementTerm


def plane_stress_matrix(youngs, poisson, youngs_warp=None, youngs_weft=None, shear_modulus=None):
    """C (3x3, Voigt (G00, G11, 2 G01)) [N/m] of an isotropic or orthotropic membrane, checked PD."""
    nu = validate.non_negative("poisson_ratio", poisson)
    if nu >= 0.5:
        raise ParameterError(f"poisson_ratio must lie in [0, 0.5), got {poisson!r}")
    ortho = (youngs_warp, youngs_weft, shear_modulus)
    if all(p is None for p in ortho):
        e = validate.positive("youngs_modulus", youngs)
        return e / (1.0 - nu * nu) * np.array([[1.0, nu, 0.0], [nu, 1.0, 0.0], [0.0, 0.0, 0.5 * (1.0 - nu)]])
    if any(p is None for p in ortho):
        raise ParameterError(
            "youngs_warp, youngs_weft and shear_modulus must be given together, got "
            f"{youngs_warp!r}, {youngs_weft!r}, {shear_modulus!r}"
        )
    e1 = validate.positive("youngs_warp", youngs_warp)
    e2 = validate.positive("youngs_weft", youngs_weft)
    g12 = validate.positive("shear_modulus", shear_modulus)
    nu21 = nu * e2 / e1
    d = 1.0 - nu * nu21
    if d <= 0.0:  # the only way C can fail to be PD with positive moduli
        raise ParameterError(
            f"poisson_ratio {nu!r} makes the orthotropic membrane matrix indefinite: needs "
            f"poisson_ratio^2 * youngs_weft < youngs_warp ({nu * nu * e2:g} >= {e1:g})"
        )
    return np.array([[e1, nu21 * e1, 0.0], [nu * e2, e2, 0.0], [0.0, 0.0, g12 * d]]) / d


def rest_frames(rest, triangles, warp):
    """Per triangle Dm^-1 (F,2,2) and rest area A0 (F,); raises on a degenerate triangle."""
    p0, e1, e2 = rest[triangles[:, 0]], *(rest[triangles[:, k]] - rest[triangles[:, 0]] for k in (1, 2))
    n = np.cross(e1, e2)
    twice_area = np.linalg.norm(n, axis=1)
    scale2 = np.maximum((e1 * e1).sum(1), (e2 * e2).sum(1))
    bad = np.flatnonzero(~(twice_area > 1e-12 * scale2))  # relative: catches collinear and repeated
    if bad.size:
        k = int(bad[0])
        raise ParameterError(
            f"triangles: {bad.size} rest triangles have zero area; first index {k} {triangles[k].tolist()} "
            f"at {p0[k].tolist()}"
        )
    n /= twice_area[:, None]
    u = warp - (n @ warp)[:, None] * n
    un = np.linalg.norm(u, axis=1)
    # warp_direction is a unit vector: its projection shorter than 1e-6 means it is nearly normal to
    # the triangle; fall back to the first edge (any in-plane axis is as good as another then).
    flat = un < 1e-6
    u[flat], un[flat] = e1[flat], np.linalg.norm(e1[flat], axis=1)
    u /= un[:, None]
    dm = np.stack([u, np.cross(n, u)], 1) @ np.stack([e1, e2], 2)  # (F,2,3) @ (F,3,2)
    return np.linalg.inv(dm), 0.5 * twice_area


@ti.func
def positive_part(S):
    """S+ of a symmetric 2x2 S: its eigenvalues clamped at 0, in closed form (no eigenvectors needed:
    with eigenvalues hi > 0 > lo, S+ = hi e e^T = hi (S - lo I) / (hi - lo))."""
    m = 0.5 * (S[0, 0] + S[1, 1])
    d = 0.5 * (S[0, 0] - S[1, 1])
    r = ti.sqrt(d * d + S[0, 1] * S[0, 1])
    hi, lo = m + r, m - r
    out = S
    if lo < 0.0:
        out = ti.Matrix.zero(float, 2, 2)
        if hi > 0.0:  # then hi - lo = 2 r > 0
            out = hi / (hi - lo) * (S - lo * ti.Matrix.identity(float, 2))
    return out


@data_oriented
class MembraneStVK(ElementTerm):
    """StVK membrane on triangles (F,3) of particle indices, rest shape rest_positions (N,3) [m].
    youngs_modulus [N/m] (areal), poisson_ratio in [0, 0.5) (nu12 when orthotropic), damping beta [s]
    (Rayleigh); youngs_warp, youngs_weft, shear_modulus [N/m] (all three, or none) for warp/weft
    anisotropy along warp_direction; projected=False keeps the indefinite exact Hessian (for tests)."""

    arity = 3
    energy_kind = "potential"  # StVK strain energy; the Rayleigh damping only removes energy

    def __init__(
        self,
        particle_count: int,
        triangles,
        rest_positions,
        *,
        youngs_modulus: float = 1.0e3,
        poisson_ratio: float = 0.3,
        damping: float = 0.0,
        youngs_warp: float | None = None,
        youngs_weft: float | None = None,
        shear_modulus: float | None = None,
        warp_direction=(1.0, 0.0, 0.0),
        projected: bool = True,
    ):
        particle_count = validate.count("particle_count", particle_count)
        rest = validate.finite_array("rest_positions", rest_positions, (3,))
        if len(rest) != particle_count:
            raise ParameterError(f"rest_positions must have {particle_count} rows, got {len(rest)}")
        tri = validate.indices("triangles", triangles, 3, particle_count, "particles")
        C = plane_stress_matrix(youngs_modulus, poisson_ratio, youngs_warp, youngs_weft, shear_modulus)
        self.beta = validate.non_negative("damping", damping)
        warp = np.asarray(validate.unit3("warp_direction", warp_direction))
        dm_inv, area = rest_frames(rest, tri.astype(np.int64), warp)
        self._rest = (dm_inv, area)  # placed with the term's other arrays (place_arrays)
        super().__init__(particle_count, tri)
        self.C = C
        self.c_rows = tuple(tuple(float(c) for c in row) for row in C)  # compile-time constants
        self.projected = bool(projected)
        self.moduli = dict(youngs_modulus=youngs_modulus, poisson_ratio=poisson_ratio)
        if youngs_warp is not None:
            self.moduli.update(youngs_warp=youngs_warp, youngs_weft=youngs_weft, shear_modulus=shear_modulus)
            self.moduli.update(warp_direction=tuple(warp.tolist()))
        self.rest_area = area

    def place_arrays(self, make, rows: int) -> None:
        """Per triangle the inverse rest frame D_m^-1 (2x2) and the rest area [m^2], `rows` rows."""
        dm_inv, area = self._rest
        self.dm_inv = make(self, "membrane_dm_inv", float, rows, (2, 2))
        self.area = make(self, "membrane_area", float, rows)
        bulk.fill(
            [
                (self.dm_inv, capacity.padded(dm_inv, rows, np_float())),
                (self.area, capacity.padded(area, rows, np_float())),
            ]
        )

    def settings(self) -> dict:
        """The term's settings for run.json."""
        return {"type": "membrane_stvk", "count": self.count, **self.moduli, "damping": self.beta}

    # ---- element functions (per triangle; X, V stacked 9-vectors)

    @ti.func
    def shape(self, e):
        """D (3x2) with F = [x0 x1 x2] D: the gradients of the linear shape functions, rows per vertex."""
        m = self.dm_inv[e]
        return ti.Matrix([[-m[0, 0] - m[1, 0], -m[0, 1] - m[1, 1]], [m[0, 0], m[0, 1]], [m[1, 0], m[1, 1]]])

    @ti.func
    def cols(self, X):
        """A stacked 9-vector as a 3x3 matrix with one vertex per column."""
        return ti.Matrix([[X[3 * a + c] for a in ti.static(range(3))] for c in ti.static(range(3))])

    @ti.func
    def stress_change(self, F, dF):
        """The stress change along dF as a 2x2: C dG in Voigt order, dG = sym(F^T dF)."""
        g = ti.Vector(
            [F[:, 0].dot(dF[:, 0]), F[:, 1].dot(dF[:, 1]), F[:, 0].dot(dF[:, 1]) + F[:, 1].dot(dF[:, 0])]
        )
        s = ti.Matrix(self.c_rows) @ g
        return ti.Matrix([[s[0], s[2]], [s[2], s[1]]])

    @ti.func
    def kinematics(self, e, X):
        """D, F, the stress S (2x2), the S used in the geometric stiffness (S+ when projected), and the
        Voigt strain and stress of triangle e at stacked positions X."""
        D = self.shape(e)
        F = self.cols(X) @ D
        C = ti.Matrix(self.c_rows)
        G = 0.5 * (F.transpose() @ F - ti.Matrix.identity(float, 2))
        strain = ti.Vector([G[0, 0], G[1, 1], 2.0 * G[0, 1]])
        s = C @ strain
        S = ti.Matrix([[s[0], s[2]], [s[2], s[1]]])
        Sg = S
        if ti.static(self.projected):
            Sg = positive_part(S)
        return D, F, S, Sg, strain, s

    @ti.func
    def flat(self, M):
        """A 3x3 matrix of per-vertex columns as a stacked 9-vector."""
        return ti.Vector([M[c, a] for a in ti.static(range(3)) for c in ti.static(range(3))])

    @ti.func
    def element_energy(self, e, X):
        """StVK strain energy [J] of triangle e at stacked positions X (9,) [m]."""
        _D, _F, _S, _Sg, strain, s = self.kinematics(e, X)
        return 0.5 * self.area[e] * strain.dot(s)

    @ti.func
    def element_force(self, e, X, V, t):
        """Elastic and Rayleigh damping forces [N] on the vertices of triangle e, stacked (9,)."""
        D, F, S, Sg, _strain, _s = self.kinematics(e, X)
        Q = F @ S  # first Piola stress P
        if ti.static(self.beta > 0.0):  # compile time: undamped membranes skip it
            # K v without the 9x9: the first-order change of P along v, dP = F dS + dF S+.
            dF = self.cols(V) @ D
            Q += self.beta * (F @ self.stress_change(F, dF) + dF @ Sg)
        return -self.area[e] * self.flat(Q @ D.transpose())

    @ti.func
    def element_linear(self, e, X, V, t, h):
        """(F [N], S [kg], df/dx v [N/s]) of triangle e for step h [s], with the compressive stress clamped so
        S stays positive semi-definite."""
        D, F, _S, Sg, _strain, s = self.kinematics(e, X)
        C = ti.Matrix(self.c_rows)
        # B (3x9): d(strain) = B dX; the material part is B^T C B, the force -A0 B^T s.
        B = ti.Matrix.zero(float, 3, 9)
        for a, c in ti.static(ti.ndrange(3, 3)):
            B[0, 3 * a + c] = D[a, 0] * F[c, 0]
            B[1, 3 * a + c] = D[a, 1] * F[c, 1]
            B[2, 3 * a + c] = D[a, 1] * F[c, 0] + D[a, 0] * F[c, 1]
        K = B.transpose() @ C @ B
        geo = D @ Sg @ D.transpose()  # the geometric part, the same 3x3 on x, y and z
        for a, b, c in ti.static(ti.ndrange(3, 3, 3)):
            K[3 * a + c, 3 * b + c] += geo[a, b]
        K *= self.area[e]
        KV = -(K @ V)
        f = -self.area[e] * (B.transpose() @ s) + self.beta * KV  # elastic + damping
        return f, (h * self.beta + h * h) * K, KV
