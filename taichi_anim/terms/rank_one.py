"""Element terms whose implicit blocks are rank one: S = s s^T with s a stacked 3*arity vector.

Two terms linearise this way: dihedral bending (Gauss-Newton, S = (h beta + h^2) k w g g^T, bending.py)
and the aerodynamic panels' normal drag (S_ab = (h rho C_d A |u_n| / 9) n n^T for every vertex pair,
aero.py, i.e. s = sqrt(h rho C_d A |u_n| / 9) (n, n, n)). Storing s per vertex instead of the arity^2
3x3 blocks takes 1/arity of the generic cache's S memory (1/3 for triangles, 1/4 for hinges), and a row
of S p is arity dot products and one scaled vector: S_ab p_b = s_a (s_b . p_b), summed over b
(`add_row_product`, inside ElementTerm.apply).

A term mixes this in before ElementTerm and defines element_rank_one(e, X, V, t, h) -> (F, s, KV), with
F and KV as element_linear's and s the factor; element_linear stays its full-matrix form (the
protocol's reference, terms/check.py compares the two paths through the solver's products).
"""

import taichi as ti

from .. import capacity
from ..runtime import data_oriented


class RankOneLinear:
    """Mixin for ElementTerm subclasses with rank-one implicit blocks (see the module's docstring)."""

    def make_cache(self, particle_count: int, implicit: bool) -> "RankOneCache":
        """This term's scratch for one solver: per-element forces and, if `implicit`, the factor s per
        vertex slot."""
        self._ensure_placed()
        return RankOneCache(self.element_rows, self.arity, implicit, self._make, self._role())

    @ti.func
    def linearize(
        self, cache: ti.template(), xf: ti.template(), vf: ti.template(), t, h, serial: ti.template()
    ):
        """A loop over elements: forces [N], df/dx v [N/s] and the factor s of S = s s^T for step h [s]."""
        ti.loop_config(serialize=serial)
        for e in range(self.live_elements()):
            f, s, kv = self.element_rank_one(e, self.stack(e, xf), self.stack(e, vf), t, h)
            for a in ti.static(range(self.arity)):
                cache.f[e, a] = ti.Vector([f[3 * a], f[3 * a + 1], f[3 * a + 2]])
                cache.kxv[e, a] = ti.Vector([kv[3 * a], kv[3 * a + 1], kv[3 * a + 2]])
                cache.s[e, a] = ti.Vector([s[3 * a], s[3 * a + 1], s[3 * a + 2]])

    @ti.func
    def diagonal_block(self, cache: ti.template(), e, a):
        """S_aa = s_a s_a^T of element e (the block-Jacobi preconditioner's part)."""
        return cache.s[e, a].outer_product(cache.s[e, a])

    @ti.func
    def add_row_product(self, cache: ti.template(), e, a, ids, pf: ti.template(), acc):
        """acc plus S_ab p_b summed over b, from the rank-one factors: s_a (s_b . p_b)."""
        sp = 0.0
        for b in ti.static(range(self.arity)):
            sp += cache.s[e, b].dot(pf[ids[b]])
        return acc + sp * cache.s[e, a]


@data_oriented
class RankOneCache:
    """A solver's scratch for a rank-one term: forces (E, arity) [N]; with implicit solves df/dx v
    (E, arity) [N/s] and the factor s (E, arity) [sqrt(kg)] of S = s s^T."""

    def __init__(self, count: int, arity: int, implicit: bool, make=capacity.plain, role: str = "element"):
        self.f = make(self, f"{role}_f", float, (count, arity), (3,))
        self.kxv = make(self, f"{role}_kxv", float, (count, arity), (3,)) if implicit else None
        self.s = make(self, f"{role}_s", float, (count, arity), (3,)) if implicit else None
