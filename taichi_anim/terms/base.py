"""The force-term protocol. Every term is one of two kinds, told apart at compile time by `coupled`:

Pointwise terms (gravity, drag, anchors) act on each particle alone and provide, as `@ti.func`s,
`force(i, m, x, v, t) -> vec3` and `jacobian(i, m, x, v, t) -> (df/dx, df/dv)` (3x3 each). Solvers fuse
them into their per-particle loops; the implicit system stores their summed 3x3 block once per row.

Element terms (springs, triangles, hinges, aerodynamic panels) couple the particles of an element and
provide, for a cache that the solver owns (`make_cache`, allocated when the solver is bound to a model):
  evaluate(cache, xf, vf, t, serial)     a top-level loop over elements: forces at fields (xf, vf)
  gather(cache, i) -> vec3                the force on particle i from the last `evaluate`
  linearize(cache, xf, vf, t, h, serial)  a top-level loop: forces and S = -(h df/dv + h^2 df/dx)
  gather_linear(cache, i) -> (f, df/dx v, S_ii)   after `linearize`, for the right-hand side and the
                                          block-Jacobi preconditioner
  apply(cache, i, pf) -> vec3             row i of S p (matrix-free products in CG and Jacobi)
  energy(x) -> float                      the term's energy [J] at positions x (N,3) (0 if it has none)
Element passes come first in a kernel (they read the whole state before a particle loop overwrites
it), and gathers sum each particle's elements in a fixed order over a compressed adjacency list: no
float atomics, so results do not depend on the thread count.

`ElementTerm` implements all of this for an element of `arity` particles given three element functions
of a subclass: `element_force`, `element_linear` and `element_energy` (see their docstrings). Adding a
term is one file with such a subclass and one Builder method.
"""

import numpy as np
import taichi as ti

from ..runtime import data_oriented, np_float


@data_oriented
class PointTerm:
    """Base of pointwise terms. has_jacobian = False: the Jacobian is identically zero (skipped)."""

    coupled = False
    has_jacobian = True
    has_energy = False

    def make_cache(self, particle_count: int, implicit: bool):
        """None: a pointwise term keeps no per-solver scratch."""
        return None

    def energy(self, x, masses) -> float:
        """Energy [J] at positions x (N,3) [m] with masses (N,) [kg]; 0 for a term without a potential."""
        return 0.0


@data_oriented
class ElementCache:
    """Scratch of one element term for one solver: per element and vertex slot the force of the last
    pass (E, arity) [N]; with implicit solves also df/dx v (E, arity) [N/s] and the blocks
    S_ab = -(h df_a/dv_b + h^2 df_a/dx_b) (E, arity, arity) [kg]."""

    def __init__(self, count: int, arity: int, implicit: bool):
        self.f = ti.Vector.field(3, float, (count, arity))
        self.kxv = ti.Vector.field(3, float, (count, arity)) if implicit else None
        self.S = ti.Matrix.field(3, 3, float, (count, arity, arity)) if implicit else None


def adjacency(vertices: np.ndarray, particle_count: int):
    """CSR list of (element, slot) per particle: start (N+1,), entry (E*arity,) = e*arity + slot,
    sorted by particle, then element (the fixed order of every gather)."""
    count, arity = vertices.shape
    owner = vertices.reshape(-1)
    entry = np.arange(count * arity)
    order = np.lexsort((entry, owner))
    start = np.zeros(particle_count + 1, dtype=np.int32)
    np.cumsum(np.bincount(owner, minlength=particle_count), out=start[1:])
    return start, entry[order].astype(np.int32)


@data_oriented
class ElementTerm:
    """Base of terms over elements of `arity` particles. vertices (E, arity) particle indices.

    Subclasses define, with X and V the element's stacked positions and velocities (3*arity vectors,
    particle a at rows 3a..3a+2):
      element_force(e, X, V, t) -> F (3*arity vector, force on each particle) [N]
      element_linear(e, X, V, t, h) -> (F, S, KV): S = -(h dF/dV + h^2 dF/dX) (3*arity square matrix,
          symmetric positive semi-definite: the subclass projects indefinite parts away and says how),
          KV = (dF/dX) V of the same linearisation (so b matches the matrix that is solved) [N/s]
      element_energy(e, X) -> scalar [J] (conservative part; 0.0 for non-conservative terms)
    """

    coupled = True
    has_jacobian = True
    has_energy = True
    arity = 2

    def __init__(self, particle_count: int, vertices):
        vertices = np.asarray(vertices, dtype=np.int64).reshape(-1, self.arity)
        self.count = len(vertices)
        self.particle_count = particle_count
        self.vertices = vertices
        self.entry_count = self.count * self.arity
        start, entry = adjacency(vertices, particle_count)
        self.element_vertex = ti.Vector.field(self.arity, ti.i32, self.count)
        self.element_vertex.from_numpy(vertices.astype(np.int32))
        self.adj_start = ti.field(ti.i32, particle_count + 1)
        self.adj_entry = ti.field(ti.i32, self.entry_count)
        self.adj_start.from_numpy(start)
        self.adj_entry.from_numpy(entry)
        self._energy_fields = None

    def make_cache(self, particle_count: int, implicit: bool) -> ElementCache:
        """This term's scratch for one solver: an ElementCache (with the implicit blocks if `implicit`)."""
        return ElementCache(self.count, self.arity, implicit)

    # ---- element gathers: stacked element state from fields

    @ti.func
    def stack(self, e, xf: ti.template()):
        """The positions (or velocities) of element e's particles from the Vector field xf, stacked in one
        vector of 3 * arity entries."""
        ids = self.element_vertex[e]
        out = ti.Vector.zero(float, 3 * self.arity)
        for a in ti.static(range(self.arity)):
            p = xf[ids[a]]
            for c in ti.static(range(3)):
                out[3 * a + c] = p[c]
        return out

    # ---- the protocol

    @ti.func
    def evaluate(self, cache: ti.template(), xf: ti.template(), vf: ti.template(), t, serial: ti.template()):
        """A loop over elements: each element's forces [N] at fields (xf [m], vf [m/s]) at time t [s] into
        cache.f."""
        ti.loop_config(serialize=serial)
        for e in range(self.count):
            F = self.element_force(e, self.stack(e, xf), self.stack(e, vf), t)
            for a in ti.static(range(self.arity)):
                cache.f[e, a] = ti.Vector([F[3 * a], F[3 * a + 1], F[3 * a + 2]])

    @ti.func
    def gather(self, cache: ti.template(), i):
        """The force [N] on particle i from the last `evaluate`, summed over its elements in a fixed order."""
        f = ti.Vector.zero(float, 3)
        for k in range(self.adj_start[i], self.adj_start[i + 1]):
            q = self.adj_entry[k]
            f += cache.f[q // self.arity, q % self.arity]
        return f

    @ti.func
    def linearize(
        self, cache: ti.template(), xf: ti.template(), vf: ti.template(), t, h, serial: ti.template()
    ):
        """A loop over elements: forces [N], df/dx v [N/s] and the blocks S = -(h df/dv + h^2 df/dx) [kg] into
        the cache, for step h [s]."""
        ti.loop_config(serialize=serial)
        for e in range(self.count):
            F, S, KV = self.element_linear(e, self.stack(e, xf), self.stack(e, vf), t, h)
            for a in ti.static(range(self.arity)):
                cache.f[e, a] = ti.Vector([F[3 * a], F[3 * a + 1], F[3 * a + 2]])
                cache.kxv[e, a] = ti.Vector([KV[3 * a], KV[3 * a + 1], KV[3 * a + 2]])
                for b in ti.static(range(self.arity)):
                    blk = ti.Matrix.zero(float, 3, 3)
                    for r in ti.static(range(3)):
                        for c in ti.static(range(3)):
                            blk[r, c] = S[3 * a + r, 3 * b + c]
                    cache.S[e, a, b] = blk

    @ti.func
    def gather_linear(self, cache: ti.template(), i):
        """After `linearize`: (f [N], df/dx v [N/s], S_ii [kg]) of particle i, for the right-hand side and the
        block-Jacobi preconditioner."""
        f = ti.Vector.zero(float, 3)
        kxv = ti.Vector.zero(float, 3)
        diag = ti.Matrix.zero(float, 3, 3)
        for k in range(self.adj_start[i], self.adj_start[i + 1]):
            q = self.adj_entry[k]
            e, a = q // self.arity, q % self.arity
            f += cache.f[e, a]
            kxv += cache.kxv[e, a]
            diag += self.diagonal_block(cache, e, a)
        return f, kxv, diag

    @ti.func
    def diagonal_block(self, cache: ti.template(), e, a):
        """S_aa of element e (a subclass with a compact cache overrides it)."""
        return cache.S[e, a, a]

    @ti.func
    def apply(self, cache: ti.template(), i, pf: ti.template()):
        """Row i of S p for the Vector field pf (matrix-free products in CG and Jacobi)."""
        acc = ti.Vector.zero(float, 3)
        for k in range(self.adj_start[i], self.adj_start[i + 1]):
            q = self.adj_entry[k]
            e, a = q // self.arity, q % self.arity
            ids = self.element_vertex[e]
            for b in ti.static(range(self.arity)):
                acc += cache.S[e, a, b] @ pf[ids[b]]
        return acc

    # ---- diagnostics (NumPy in, NumPy out; each call launches a kernel)

    def energy(self, x, masses=None) -> float:
        """Energy [J] of the term at positions x (N,3) [m]."""
        if self._energy_fields is None:  # once: a new field would recompile the kernel per call
            self._energy_fields = (ti.Vector.field(3, float, self.particle_count), ti.field(float, ()))
        xf, out = self._energy_fields
        xf.from_numpy(np.asarray(x, dtype=np_float()))
        self._energy(xf, out)
        return float(out[None])

    @ti.kernel
    def _energy(self, xf: ti.template(), out: ti.template()):
        out[None] = 0.0
        ti.loop_config(serialize=True)  # a fixed summation order
        for e in range(self.count):
            out[None] += self.element_energy(e, self.stack(e, xf))

    def element_arrays(self, x, v, t: float = 0.0, h: float = 1.0):
        """Per element, at positions x (N,3) and velocities v (N,3): F (E, 3*arity) from element_force,
        and from element_linear: F_lin (E, 3*arity), S (E, 3*arity, 3*arity), KV (E, 3*arity). For
        tests (finite-difference checks) and reports."""
        n3 = 3 * self.arity
        fields = getattr(self, "_array_fields", None)
        if fields is None:
            fields = (
                ti.Vector.field(3, float, self.particle_count),
                ti.Vector.field(3, float, self.particle_count),
                ti.Vector.field(n3, float, self.count),
                ti.Vector.field(n3, float, self.count),
                ti.Matrix.field(n3, n3, float, self.count),
                ti.Vector.field(n3, float, self.count),
            )
            self._array_fields = fields
        xf, vf, F, FL, S, KV = fields
        xf.from_numpy(np.asarray(x, dtype=np_float()))
        vf.from_numpy(np.asarray(v, dtype=np_float()))
        self._element_arrays(xf, vf, F, FL, S, KV, t, h)
        return tuple(a.to_numpy().astype(np.float64) for a in (F, FL, S, KV))

    @ti.kernel
    def _element_arrays(
        self,
        xf: ti.template(),
        vf: ti.template(),
        F: ti.template(),
        FL: ti.template(),
        S: ti.template(),
        KV: ti.template(),
        t: float,
        h: float,
    ):
        for e in range(self.count):
            X = self.stack(e, xf)
            V = self.stack(e, vf)
            F[e] = self.element_force(e, X, V, t)
            f, s, kv = self.element_linear(e, X, V, t, h)
            FL[e] = f
            S[e] = s
            KV[e] = kv
