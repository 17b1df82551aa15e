"""Damped springs between particles (cloth's structural, shear and bend springs), Baraff & Witkin,
"Large Steps in Cloth Simulation" (1998), sec. 4 and eq. 16, with the spring as the condition C = l - L:
    f_i = -(k (l - L) + c (v_i - v_j) . n) n,   d = x_i - x_j, l = |d|, n = d / l,   f_j = -f_i
    df_i/dx_i = -k [n n^T + (1 - L/l) (I - n n^T)],   df_i/dv_i = -c n n^T   (df_i/dx_j = -df_i/dx_i)
Under compression (l < L) the transverse part (1 - L/l) is negative and makes the implicit system
indefinite; it is clamped at 0 (Choi & Ko, "Stable but Responsive Cloth", 2002, sec. 5): the stretched
case is exact, a compressed spring keeps only its axial stiffness (so a buckling cloth is not forced
to stay flat). The x-derivative of the damping force is left out, as Baraff & Witkin do (sec. 5).

Two passes, no float atomics: a loop over springs evaluates each spring once into a per-spring field
(in the cache of the solver that runs it), then each particle sums its springs' values with their signs
over a compressed adjacency list sorted by particle, in a fixed order (deterministic at any thread
count). The update loop that follows may overwrite positions in place: the spring pass has read them.
"""

import numpy as np
import taichi as ti

from .. import bulk, capacity
from ..runtime import backend_name, data_oriented, np_float
from .base import TermBounds
from .stiffness import SpringPart

_EPS = 1e-12
SCATTER_WHEN_SERIAL = True  # the serial spring pass sums into its ends (False: per spring, then gather)
# The spring pass on the CPU in packs of PACK springs (Springs._pack): Taichi runs a loop's iterations as
# calls of its body, which LLVM does not vectorise; PACK copies of the force as straight-line code, their
# loads first and their stores last, are what its SLP vectoriser runs in vector registers. Warp's cloth
# scene at 32^2 on the 2-core Xeon, two runs each: 16 serial spring passes 0.44, 0.45 -> 0.38, 0.40 ms;
# the engine's frame 0.60, 0.59 -> 0.54, 0.53 ms (benchmarks/results/cloth_bound.md for every size).
# Packs cost compile time (the pass's code is PACK times longer), so they start at SPRING_PACKS_FROM
# springs (the capacity), where a frame's spring pass is long enough to repay it.
PACK = 8
SPRING_PACKS_FROM = 2048
# None: packs on the CPU from SPRING_PACKS_FROM springs; True: on the CPU at any size; False: never (tests
# compare both).
SPRING_PACKS = None


@ti.func
def spring_force(d, dv, rest, k, c):
    """Force on the end at x_i of one spring, d = x_i - x_j, dv = v_i - v_j."""
    # One reciprocal square root instead of a square root and a division (fast on every backend), and
    # l = |d|^2 / |d| and (dv . d) / |d| without forming the unit vector first: 15 operations after
    # |d|^2 instead of 20, and shorter chains (Warp's cloth at 32^2 on one core: 16 spring passes
    # 0.60 -> 0.45 ms; results move by round-off only).
    d2 = d.dot(d)
    inv = ti.rsqrt(ti.max(d2, _EPS * _EPS))
    length = d2 * inv
    return -(k * (length - rest) + c * dv.dot(d) * inv) * inv * d, d * inv, length


@ti.func
def spring_stiffness_apply(n, axial, transverse, p):
    """(axial n n^T + transverse (I - n n^T)) p without forming the matrix."""
    t = n.dot(p)
    return transverse * p + (axial - transverse) * t * n


@data_oriented
class SpringCache:
    """A solver's scratch for the springs: force on each spring's first end (S,) [N]; with implicit
    solves its direction n (S,), the two stiffnesses (axial, transverse) of
    S_s = -(h df/dv + h^2 df/dx) = axial n n^T + transverse (I - n n^T) (S,2) [kg], and df/dx (v_i - v_j);
    `entry` holds (n, axial, transverse) per adjacency entry (2S,)."""

    def __init__(self, count: int, implicit: bool, new_field=None, rows: int = 0):
        """count: the springs' capacity; rows: the particles' (for the serial pass's per-particle sums);
        new_field(owner, role, dtype, shape, dims): the model's allocator (pooled under capacity
        buckets), or None for plain fields."""
        make = new_field or capacity.plain
        self.f = make(self, "spring_f", float, count, (3,))
        # The serial spring pass adds each force to both ends at once (Springs.evaluate): per-particle
        # sums, and which of the two the last pass left (1: acc, 0: f per spring).
        self.acc = make(self, "spring_acc", float, max(rows, 1), (3,)) if SCATTER_WHEN_SERIAL else None
        self.mode = make(self, "spring_mode", ti.i32, ())
        self.n = make(self, "spring_n", float, count, (3,)) if implicit else None
        self.ab = make(self, "spring_ab", float, count, (2,)) if implicit else None
        # (n, axial, transverse) again per adjacency entry (2S,), in the order the matrix-vector product
        # reads them: its loop then streams one array instead of chasing each entry's spring index
        # (the product runs ~40 times per implicit step, the copy once; benchmarks/results/cloth_implicit.md).
        self.entry = make(self, "spring_entry5", float, 2 * count, (5,)) if implicit else None
        self.kxv = make(self, "spring_kxv", float, count, (3,)) if implicit else None


@data_oriented
class Springs(TermBounds):
    """Springs of a model, an element term of two particles (the term protocol in base.py, in the compact
    form a spring allows: a direction and two stiffnesses instead of four 3x3 blocks).
    pairs (S,2) particle indices; rest_length (S,) [m]; stiffness (S,) [N/m]; damping (S,) [kg/s] along
    the spring; family (S,) int (0 stretch, 1 shear, 2 bend; for reports)."""

    coupled = True
    has_jacobian = True
    has_energy = True
    energy_kind = "potential"  # elastic; the damping only removes energy
    fast_blocks = True  # stiffness_part is NumPy: the stability estimate uses the exact blocks

    def __init__(self, particle_count: int, pairs, rest_length, stiffness, damping, family=None, model=None):
        """model: the Model it belongs to, whose capacity buckets (capacity.py) its arrays follow: then
        they hold capacity rows, padded with springs of zero stiffness that no loop reaches."""
        pairs = np.sort(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), axis=1)
        s = len(pairs)
        self.model = model
        buckets = model is not None and model.size_buckets
        self.buckets = buckets  # kernels branch on it at compile time
        self.capacity = capacity.bucket(s) if buckets else s
        rows = model.particle_capacity if buckets else particle_count
        self.rows = rows
        self._new_field = model.new_field if buckets else None
        make = self._new_field or capacity.plain
        self.spring_live = make(self, "spring_live", ti.i32, ()) if buckets else None
        if buckets:
            self.spring_live[None] = s
        # Springs sorted by their ends: the spring pass then reads positions nearly in order (a cloth's
        # springs as built jump a whole grid row between neighbours), 1.4x faster at 128^2 here.
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        self.count = s
        self.particle_count = particle_count
        self.pairs = pairs[order]
        self.rest_length = np.asarray(rest_length, dtype=np.float64)[order]
        self.stiffness = np.broadcast_to(np.asarray(stiffness, dtype=np.float64), (s,))[order]
        self.damping = np.broadcast_to(np.asarray(damping, dtype=np.float64), (s,))[order]
        wanted = self.capacity >= SPRING_PACKS_FROM if SPRING_PACKS is None else SPRING_PACKS
        self.packed = bool(wanted) and backend_name() == "cpu"  # a GPU runs lanes as threads already
        fam = np.zeros(s, np.int8) if family is None else np.asarray(family, np.int8)
        self.family = fam[order]
        pairs = self.pairs
        # Both ends of every spring, sorted by the particle that gathers them. An entry holds the spring
        # as +(s+1) at its first end (force +f_s) and -(s+1) at its second (-f_s), and the other end.
        owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
        other = np.concatenate([pairs[:, 1], pairs[:, 0]])
        signed = np.concatenate([np.arange(1, s + 1), -np.arange(1, s + 1)])
        order = np.lexsort((other, owner))
        counts = np.bincount(owner, minlength=rows)
        start = np.zeros(rows + 1, dtype=np.int32)
        np.cumsum(counts, out=start[1:])
        self.entry_count = 2 * s
        f = np_float()
        cap = self.capacity
        self.adj_start = make(self, "spring_adj_start", ti.i32, rows + 1)
        self.adj_spring = make(self, "spring_adj_spring", ti.i32, 2 * cap)
        self.adj_other = make(self, "spring_adj_other", ti.i32, 2 * cap)
        # Where each spring sits in the adjacency: (entry at its first end, entry at its second end).
        where = np.empty((s, 2), dtype=np.int32)
        sorted_signed = signed[order]
        first = sorted_signed > 0
        where[sorted_signed[first] - 1, 0] = np.flatnonzero(first)
        where[-sorted_signed[~first] - 1, 1] = np.flatnonzero(~first)
        self.spring_entry = make(self, "spring_entry", ti.i32, cap, (2,))
        self.spring_pair = make(self, "spring_pair", ti.i32, cap, (2,))
        self.spring_param = make(self, "spring_param", float, cap, (3,))  # rest length, stiffness, damping
        param = np.stack([self.rest_length, self.stiffness, self.damping], axis=1)
        bulk.fill(  # one launch, with the Model's other arrays in its batch (from_numpy: a kernel per field)
            [
                (self.adj_start, start),
                (self.adj_spring, capacity.padded(signed[order], 2 * cap, np.int32)),
                (self.adj_other, capacity.padded(other[order], 2 * cap, np.int32)),
                (self.spring_entry, capacity.padded(where, cap, np.int32)),
                (self.spring_pair, capacity.padded(pairs, cap, np.int32)),
                (self.spring_param, capacity.padded(param, cap, f)),
            ]
        )

    def settings(self) -> dict:
        """The term's settings for run.json."""
        names = ("stretch", "shear", "bend")
        fam = {names[k]: int((self.family == k).sum()) for k in range(3) if (self.family == k).any()}
        return {"type": "springs", "count": self.count, "families": fam}

    def make_cache(self, particle_count: int, implicit: bool) -> SpringCache:
        """This term's scratch for one solver: per-spring forces (and the compact linearisation if
        `implicit`)."""
        return SpringCache(self.capacity, implicit, self._new_field, self.rows)

    def energy(self, x, masses=None) -> float:
        """Elastic energy sum_s k/2 (l - L)^2 [J] at positions x (N,3) [m]."""
        d = (
            np.asarray(x, dtype=np.float64)[self.pairs[:, 0]]
            - np.asarray(x, dtype=np.float64)[self.pairs[:, 1]]
        )
        stretch = np.linalg.norm(d, axis=1) - self.rest_length
        return float(0.5 * np.sum(self.stiffness * stretch**2))

    def stiffness_part(self, x, v, t: float):
        """K = -df/dx and C = -df/dv of the springs at x (N,3), in their compact form (stability.py)."""
        return SpringPart(self, np.asarray(x, dtype=np.float64))

    @ti.func
    def live_springs(self):
        """Springs the loops run over: the live count, read at run time under capacity buckets."""
        if ti.static(self.buckets):
            return self.spring_live[None]
        else:
            return self.count

    @ti.func
    def evaluate(self, cache: ti.template(), xf: ti.template(), vf: ti.template(), t, serial: ti.template()):
        """The spring pass (top-level loops: call it first in a kernel): every spring's force at the
        positions xf and velocities vf (fields) into the cache.

        On one thread each force goes straight into its two ends' sums, with no per-spring array and no
        adjacency walk after. The springs are sorted by (first end, second end), so each particle
        receives its springs in ascending order of the other end, the adjacency's order, starting from
        zero: `gather` returns the same bits either way."""
        if ti.static(serial and SCATTER_WHEN_SERIAL):
            ti.loop_config(serialize=True)
            for i in range(self.rows):
                cache.acc[i] = ti.Vector.zero(float, 3)
            ti.loop_config(serialize=True)
            for _ in range(1):
                self._springs(cache, xf, vf, 0, self.live_springs(), True)
            cache.mode[None] = 1
        else:
            n = self.live_springs()
            step = ti.static(PACK if self.packed else 1)  # a pack per iteration: one loop, one launch
            ti.loop_config(serialize=serial)
            for q in range((n + step - 1) // step):
                self._springs(cache, xf, vf, q * step, ti.min(q * step + step, n), False)
            cache.mode[None] = 0

    # The spring pass in shares (integrators/parallel_frame.py): evaluate_range over each share, the
    # per-spring form of the parallel pass.
    splits_evaluation = True

    @ti.func
    def element_count(self):
        """Springs the pass runs over (live_springs)."""
        return self.live_springs()

    @ti.func
    def evaluate_range(self, cache: ti.template(), xf: ti.template(), vf: ti.template(), t, lo, hi):
        """The parallel pass's springs [lo, hi) only (an inner loop: the caller shares out the range):
        the same force per spring into cache.f, for `gather` to walk."""
        self._springs(cache, xf, vf, lo, hi, False)
        if lo == 0:
            cache.mode[None] = 0

    @ti.func
    def _springs(
        self, cache: ti.template(), xf: ti.template(), vf: ti.template(), lo, hi, scatter: ti.template()
    ):
        """Springs [lo, hi) in order: in packs where they apply, the rest one by one. scatter: each force
        into its ends' sums (cache.acc), else into cache.f."""
        s = lo
        if ti.static(self.packed):
            while s + PACK <= hi:
                self._pack(cache, s, xf, vf, scatter)
                s += PACK
        while s < hi:
            ij = self.spring_pair[s]
            p = self.spring_param[s]
            f, _, _ = spring_force(xf[ij[0]] - xf[ij[1]], vf[ij[0]] - vf[ij[1]], p[0], p[1], p[2])
            self._store(cache, s, ij, f, scatter)
            s += 1

    @ti.func
    def _pack(self, cache: ti.template(), s0, xf: ti.template(), vf: ti.template(), scatter: ti.template()):
        """Springs s0 .. s0 + PACK - 1: every load, then spring_force per lane, then every store, so that
        LLVM (which cannot tell the fields apart in memory) may run the lanes side by side."""
        d = ti.Matrix.zero(float, PACK, 3)
        dv = ti.Matrix.zero(float, PACK, 3)
        par = ti.Matrix.zero(float, PACK, 3)
        for lane in ti.static(range(PACK)):
            ij = self.spring_pair[s0 + lane]
            a = xf[ij[0]] - xf[ij[1]]
            b = vf[ij[0]] - vf[ij[1]]
            p = self.spring_param[s0 + lane]
            for c in ti.static(range(3)):
                d[lane, c] = a[c]
                dv[lane, c] = b[c]
                par[lane, c] = p[c]
        out = ti.Matrix.zero(float, PACK, 3)
        for lane in ti.static(range(PACK)):
            f, _, _ = spring_force(
                ti.Vector([d[lane, c] for c in ti.static(range(3))]),
                ti.Vector([dv[lane, c] for c in ti.static(range(3))]),
                par[lane, 0],
                par[lane, 1],
                par[lane, 2],
            )
            for c in ti.static(range(3)):
                out[lane, c] = f[c]
        for lane in ti.static(range(PACK)):
            f = ti.Vector([out[lane, c] for c in ti.static(range(3))])
            self._store(cache, s0 + lane, self.spring_pair[s0 + lane], f, scatter)

    @ti.func
    def _store(self, cache: ti.template(), s, ij, f, scatter: ti.template()):
        if ti.static(scatter):
            cache.acc[ij[0]] += f
            cache.acc[ij[1]] -= f
        else:
            cache.f[s] = f

    @ti.func
    def gather(self, cache: ti.template(), i):
        """Sum of the forces of the last spring pass on particle i."""
        f = ti.Vector.zero(float, 3)
        if ti.static(SCATTER_WHEN_SERIAL):
            if cache.mode[None] == 1:
                f = cache.acc[i]
            else:
                f = self._walk(cache, i)
        else:
            f = self._walk(cache, i)
        return f

    @ti.func
    def _walk(self, cache: ti.template(), i):
        """Particle i's spring forces from the per-spring array, in its adjacency's order."""
        f = ti.Vector.zero(float, 3)
        for e in range(self.adj_start[i], self.adj_start[i + 1]):
            s = self.adj_spring[e]
            if s > 0:
                f += cache.f[s - 1]
            else:
                f -= cache.f[-s - 1]
        return f

    @ti.func
    def linearize(
        self, cache: ti.template(), xf: ti.template(), vf: ti.template(), t, h, serial: ti.template()
    ):
        """The spring pass of an implicit step (top-level loop): force, direction, the two stiffnesses of
        S_s and df/dx (v_i - v_j) with the clamped Jacobian, so b matches the matrix that is solved."""
        ti.loop_config(serialize=serial)
        for s in range(self.live_springs()):
            ij = self.spring_pair[s]
            p = self.spring_param[s]
            dv = vf[ij[0]] - vf[ij[1]]
            f, n, length = spring_force(xf[ij[0]] - xf[ij[1]], dv, p[0], p[1], p[2])
            tr = ti.max(1.0 - p[0] / ti.max(length, _EPS), 0.0)
            cache.f[s] = f
            cache.n[s] = n
            ab = ti.Vector([h * p[2] + h * h * p[1], h * h * p[1] * tr])
            cache.ab[s] = ab
            cache.kxv[s] = -spring_stiffness_apply(n, p[1], p[1] * tr, dv)
            packed = ti.Vector([n[0], n[1], n[2], ab[0], ab[1]])
            e = self.spring_entry[s]
            cache.entry[e[0]] = packed
            cache.entry[e[1]] = packed
        cache.mode[None] = 0  # the forces are per spring again: a later gather walks them

    @ti.func
    def gather_linear(self, cache: ti.template(), i):
        """After linearize: the spring force on i, (df/dx v)_i and the diagonal block sum_s S_s."""
        f = ti.Vector.zero(float, 3)
        kxv = ti.Vector.zero(float, 3)
        diag = ti.Matrix.zero(float, 3, 3)
        eye = ti.Matrix.identity(float, 3)
        for e in range(self.adj_start[i], self.adj_start[i + 1]):
            s = self.adj_spring[e]
            sign = 1.0
            if s < 0:
                sign = -1.0
                s = -s
            s -= 1
            f += sign * cache.f[s]
            kxv += sign * cache.kxv[s]
            n = cache.n[s]
            ab = cache.ab[s]
            nn = n.outer_product(n)
            diag += ab[0] * nn + ab[1] * (eye - nn)
        return f, kxv, diag

    @ti.func
    def apply(self, cache: ti.template(), i, pf: ti.template()):
        """sum_s S_s (p_i - p_j) over the springs of i (the solvers keep p zero at pinned particles)."""
        pi = pf[i]
        acc = ti.Vector.zero(float, 3)
        for e in range(self.adj_start[i], self.adj_start[i + 1]):
            d = cache.entry[e]
            n = ti.Vector([d[0], d[1], d[2]])
            acc += spring_stiffness_apply(n, d[3], d[4], pi - pf[self.adj_other[e]])
        return acc
