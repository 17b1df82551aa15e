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
term is one file with such a subclass and one Builder method (or, for a term of one's own,
`Builder.add_force(term)`).

What the checkers ask of a term (the watchdog, statics and the stability guard ask the term, never its
class; `TermBounds` gives the defaults, and `check_protocol` refuses a term that lacks what it declares):
  energy_kind                 "potential": `energy(x, masses)` is the potential of its conservative
                              part (any other part only removes energy, e.g. damping); "dissipative": it
                              only removes energy and vanishes at v = 0 (drag in still air); "source": it
                              can add energy (wind, aerodynamics, a stirring field): it must give
                              `speed_bound()`, and the scene's energy is then not checked
  speed_bound() [m/s]         the largest speed it drives particles towards (wind); 0 by default
  acceleration_bound() [m/s^2] the largest uniform acceleration it keeps supplying (|g|); 0 by default
  stored_energy(x, masses) [J] the energy it can release from positions x: energy - energy_floor
  energy_floor(masses) [J]    the least value its potential takes (0 for elastic terms, by default)
  static_potential(x, masses) the potential of its force at v = 0 (statics' line search), or None
  point_blocks(x, v, t)       (pointwise) -df/dx and -df/dv (N,3,3) in NumPy, or None: then a kernel
                              evaluates `jacobian` (the stability estimate)
  stiffness_part(x, v, t)     (elements) K = -df/dx and C = -df/dv as a stability part (stability.py)
"""

import numpy as np
import taichi as ti

from .. import bulk, capacity
from ..errors import ParameterError
from ..runtime import data_oriented, np_float
from .stiffness import BlockPart

ENERGY_KINDS = ("potential", "dissipative", "source")


class TermBounds:
    """Defaults of what the checkers ask of a term (see the module docstring); every one is safe: a term
    that adds energy must say so (energy_kind "source") and give its speed, or `check_protocol` refuses it."""

    energy_kind = None  # undeclared: check_protocol refuses the term

    def settings(self) -> dict:
        """The term's settings for run.json: its type (the class name unless a subclass says more)."""
        return {"type": type(self).__name__}

    def speed_bound(self) -> float:
        """The largest speed [m/s] the term drives particles towards (0: none of its own)."""
        return 0.0

    def acceleration_bound(self) -> float:
        """The largest uniform acceleration [m/s^2] the term keeps supplying (0: none)."""
        return 0.0

    def energy_floor(self, masses) -> float:
        """The least value [J] the term's potential takes, with particle masses (N,) [kg] (0: elastic)."""
        return 0.0

    def stored_energy(self, x, masses) -> float:
        """The energy [J] the term can release from positions x (N,3) [m]: its potential above its floor
        (0 unless energy_kind is "potential"). A potential below the declared floor raises, naming the
        term: its `energy_floor` is wrong."""
        if self.energy_kind != "potential":
            return 0.0
        e = float(self.energy(x, masses))
        floor = float(self.energy_floor(masses))
        if floor - e > 1e-9 * max(abs(e), abs(floor)) + 1e-12:  # beyond round-off of an elastic 0
            raise ParameterError(
                f"{type(self).__name__}: its energy {e:.6g} J is below its energy_floor {floor:.6g} J; "
                "override energy_floor(masses) with the least value its potential takes"
            )
        return max(e - floor, 0.0)

    def static_potential(self, x, masses):
        """The potential [J] of the term's force at v = 0 at positions x (N,3) [m], or None if that force
        has none (a source)."""
        if self.energy_kind == "potential":
            return float(self.energy(x, masses))
        if self.energy_kind == "dissipative":
            return 0.0
        return None


@data_oriented
class PointTerm(TermBounds):
    """Base of pointwise terms. has_jacobian = False: the Jacobian is identically zero (skipped);
    has_energy: its energy is elastic and reported by Model.energy."""

    coupled = False
    has_jacobian = True
    has_energy = False

    def make_cache(self, particle_count: int, implicit: bool):
        """None: a pointwise term keeps no per-solver scratch."""
        return None

    def energy(self, x, masses) -> float:
        """Energy [J] at positions x (N,3) [m] with masses (N,) [kg]; 0 for a term without a potential
        (a term of energy_kind "potential" must override it)."""
        return 0.0

    def point_blocks(self, x, v, t: float):
        """(K, C) = (-df/dx, -df/dv) (N,3,3) at x, v (N,3) in NumPy, or None (a kernel evaluates them)."""
        return None


@data_oriented
class ElementCache:
    """Scratch of one element term for one solver: per element and vertex slot the force of the last
    pass (E, arity) [N]; with implicit solves also df/dx v (E, arity) [N/s] and the blocks
    S_ab = -(h df_a/dv_b + h^2 df_a/dx_b) (E, arity, arity) [kg]."""

    def __init__(self, count: int, arity: int, implicit: bool, make=capacity.plain, role: str = "element"):
        self.f = make(self, f"{role}_f", float, (count, arity), (3,))
        self.kxv = make(self, f"{role}_kxv", float, (count, arity), (3,)) if implicit else None
        self.S = make(self, f"{role}_S", float, (count, arity, arity), (3, 3)) if implicit else None


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
class ElementTerm(TermBounds):
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
    fast_blocks = False  # element_arrays compiles the element Hessians (seconds): stability probes instead

    def __init__(self, particle_count: int, vertices):
        vertices = np.asarray(vertices, dtype=np.int64).reshape(-1, self.arity)
        self.count = len(vertices)
        self.particle_count = particle_count
        self.vertices = vertices
        self.entry_count = self.count * self.arity
        self._energy_fields = None
        # Fields: exactly sized now, or (capacity buckets on: a model will take the term) at bind().
        self.buckets = False  # kernels branch on it at compile time
        self.element_live = None
        self.particle_rows = self.element_rows = None
        self._make = capacity.plain
        if not capacity.enabled():
            self._place(capacity.plain, particle_count, self.count)

    def bind(self, model) -> None:
        """Called by the Model that takes the term: under capacity buckets (capacity.py) its arrays are
        placed at the model's particle capacity and the bucket of its element count, from the model's
        pool, and loops run to the live element count (a field read), so that another size compiles
        nothing; otherwise they stay (or are made) exactly sized."""
        if model.size_buckets and not self.buckets:
            self.buckets = True
            self._make = model.new_field
            self.element_live = model.new_field(self, f"{self._role()}_live", ti.i32, ())
            self.element_live[None] = self.count
            self._place(model.new_field, model.particle_capacity, capacity.bucket(self.count))
        elif self.particle_rows is None:
            self._place(capacity.plain, self.particle_count, self.count)

    def _role(self) -> str:
        return type(self).__name__

    def _place(self, make, particle_rows: int, element_rows: int) -> None:
        """Allocate and fill the term's arrays for `particle_rows` particles and `element_rows` elements
        (rows past the live counts: zeros, which no loop reaches), then the subclass's (place_arrays)."""
        role = self._role()
        self.particle_rows, self.element_rows = particle_rows, element_rows
        self._energy_fields = self._array_fields = None  # diagnostics' scratch follows the new rows
        start, entry = adjacency(self.vertices, particle_rows)
        self.element_vertex = make(self, f"{role}_vertex", ti.i32, element_rows, (self.arity,))
        self.adj_start = make(self, f"{role}_adj_start", ti.i32, particle_rows + 1)
        self.adj_entry = make(self, f"{role}_adj_entry", ti.i32, element_rows * self.arity)
        with bulk.batch():  # these and the subclass's arrays in one launch (from_numpy: a kernel per field)
            bulk.fill(
                [
                    (self.element_vertex, capacity.padded(self.vertices, element_rows, np.int32)),
                    (self.adj_start, start),
                    (self.adj_entry, capacity.padded(entry, element_rows * self.arity, np.int32)),
                ]
            )
            self.place_arrays(make, element_rows)

    def place_arrays(self, make, rows: int) -> None:
        """A subclass's own per-element arrays, `rows` rows from make(owner, role, dtype, shape, dims)
        (see _place); none here. It runs inside a bulk.batch(): arrays written with bulk.fill join one
        launch, and the term's arrays (element_vertex, the adjacency) are written only when the batch
        closes, so no kernel launched here may read them."""

    def _ensure_placed(self) -> None:
        if self.particle_rows is None:  # used outside a model with buckets on: exact sizes
            self._place(capacity.plain, self.particle_count, self.count)

    @ti.func
    def live_elements(self):
        """Elements the loops run over: the live count under buckets (a field read), else a constant."""
        if ti.static(self.buckets):
            return self.element_live[None]
        else:
            return self.count

    def make_cache(self, particle_count: int, implicit: bool) -> ElementCache:
        """This term's scratch for one solver: an ElementCache (with the implicit blocks if `implicit`)."""
        self._ensure_placed()
        return ElementCache(self.element_rows, self.arity, implicit, self._make, self._role())

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
        for e in range(self.live_elements()):
            self._evaluate_one(cache, e, xf, vf, t)

    # Evaluation in shares (integrators/parallel_frame.py): evaluate_range over each share.
    splits_evaluation = True

    @ti.func
    def element_count(self):
        """Elements `evaluate` runs over (live_elements)."""
        return self.live_elements()

    @ti.func
    def evaluate_range(self, cache: ti.template(), xf: ti.template(), vf: ti.template(), t, lo, hi):
        """`evaluate` over the elements [lo, hi) only, as an inner loop (the caller shares out the range)."""
        for e in range(lo, hi):
            self._evaluate_one(cache, e, xf, vf, t)

    @ti.func
    def _evaluate_one(self, cache: ti.template(), e, xf: ti.template(), vf: ti.template(), t):
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
        for e in range(self.live_elements()):
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
            acc = self.add_row_product(cache, e, a, self.element_vertex[e], pf, acc)
        return acc

    @ti.func
    def add_row_product(self, cache: ti.template(), e, a, ids, pf: ti.template(), acc):
        """acc plus the rows of element e's S for its vertex slot a times p (a subclass with a compact
        cache overrides it)."""
        for b in ti.static(range(self.arity)):
            acc += cache.S[e, a, b] @ pf[ids[b]]
        return acc

    # ---- diagnostics (NumPy in, NumPy out; each call launches a kernel)

    def energy(self, x, masses=None) -> float:
        """Energy [J] of the term at positions x (N,3) [m]."""
        self._ensure_placed()
        if self._energy_fields is None:  # once: a new field would recompile the kernel per call
            role = self._role()
            self._energy_fields = (
                self._make(self, f"{role}_energy_x", float, self.particle_rows, (3,)),
                self._make(self, f"{role}_energy", float, ()),
            )
        xf, out = self._energy_fields
        xf.from_numpy(capacity.padded(x, self.particle_rows, np_float()))
        self._energy(xf, out)
        return float(out[None])

    def stiffness_part(self, x, v, t: float):
        """K = -df/dx and C = -df/dv of every element at x, v (N,3), as a stability part (stability.py)."""
        # S(h) = h C + h^2 K (see element_linear): two step sizes separate K and C.
        s1 = self.element_arrays(x, v, t, 1.0)[2]
        s2 = self.element_arrays(x, v, t, 2.0)[2]
        k = 0.5 * (s2 - 2.0 * s1)
        return BlockPart(self.vertices, k, s1 - k)

    @ti.kernel
    def _energy(self, xf: ti.template(), out: ti.template()):
        out[None] = 0.0
        ti.loop_config(serialize=True)  # a fixed summation order
        for e in range(self.live_elements()):
            out[None] += self.element_energy(e, self.stack(e, xf))

    def element_arrays(self, x, v, t: float = 0.0, h: float = 1.0):
        """Per element, at positions x (N,3) and velocities v (N,3): F (E, 3*arity) from element_force,
        and from element_linear: F_lin (E, 3*arity), S (E, 3*arity, 3*arity), KV (E, 3*arity). For
        tests (finite-difference checks) and reports."""
        n3 = 3 * self.arity
        self._ensure_placed()
        fields = getattr(self, "_array_fields", None)
        if fields is None:
            rows, elements = self.particle_rows, self.element_rows
            fields = (
                ti.Vector.field(3, float, rows),
                ti.Vector.field(3, float, rows),
                ti.Vector.field(n3, float, elements),
                ti.Vector.field(n3, float, elements),
                ti.Matrix.field(n3, n3, float, elements),
                ti.Vector.field(n3, float, elements),
            )
            self._array_fields = fields
        xf, vf, F, FL, S, KV = fields
        xf.from_numpy(capacity.padded(x, self.particle_rows, np_float()))
        vf.from_numpy(capacity.padded(v, self.particle_rows, np_float()))
        self._element_arrays(xf, vf, F, FL, S, KV, t, h)
        return tuple(a.to_numpy()[: self.count].astype(np.float64) for a in (F, FL, S, KV))

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
        for e in range(self.live_elements()):
            X = self.stack(e, xf)
            V = self.stack(e, vf)
            F[e] = self.element_force(e, X, V, t)
            f, s, kv = self.element_linear(e, X, V, t, h)
            FL[e] = f
            S[e] = s
            KV[e] = kv


# ---- the protocol check (Builder.add_force, finalize) and the user's finite-difference check

_POINT_METHODS = ("force", "jacobian", "energy", "make_cache")
_ELEMENT_METHODS = ("evaluate", "gather", "linearize", "gather_linear", "apply", "make_cache", "energy")
_BOUND_METHODS = (
    "settings",
    "speed_bound",
    "acceleration_bound",
    "energy_floor",
    "stored_energy",
    "static_potential",
)


def check_protocol(term) -> None:
    """Raise ParameterError naming `term`'s class and everything it lacks to be a force term the engine
    can use: the methods of its kind (pointwise: `force`, `jacobian`; an ElementTerm: `element_force`,
    `element_linear`, `element_energy`), a declared `energy_kind` ("potential", "dissipative" or
    "source"), an `energy` of its own if it declares a potential, and a `speed_bound` of its own if it
    declares a source (the watchdog bounds particle speeds with it). Builder.add_force calls it; the
    user's check is `check_term` (terms/check.py), which adds finite differences."""
    name = type(term).__name__
    missing = []
    coupled = getattr(term, "coupled", None)
    if not isinstance(coupled, bool):
        missing.append("coupled (False for a pointwise term, True for an element term)")
    elif coupled and isinstance(term, ElementTerm):
        missing += [m for m in ("element_force", "element_linear", "element_energy") if not _has(term, m)]
    else:
        missing += [m for m in (_ELEMENT_METHODS if coupled else _POINT_METHODS) if not _has(term, m)]
    missing += [m for m in _BOUND_METHODS if not _has(term, m)]
    for flag in ("has_jacobian", "has_energy"):
        if not isinstance(getattr(term, flag, None), bool):
            missing.append(f"{flag} (True or False)")
    kind = getattr(term, "energy_kind", None)
    if kind not in ENERGY_KINDS:
        missing.append(f"energy_kind (one of {', '.join(map(repr, ENERGY_KINDS))}; got {kind!r})")
    elif kind == "potential" and coupled is False and _inherited(term, "energy", PointTerm):
        missing.append("energy(x, masses) (it declares energy_kind 'potential')")
    elif kind == "source" and _inherited(term, "speed_bound", TermBounds):
        missing.append("speed_bound() (it declares energy_kind 'source': the watchdog needs its speed)")
    if missing:
        raise ParameterError(
            f"force term {name} lacks: {'; '.join(missing)} (the force-term protocol: "
            "taichi_anim/terms/base.py)"
        )


def _has(term, method: str) -> bool:
    return callable(getattr(term, method, None))


def _inherited(term, method: str, base) -> bool:
    """Whether `term` takes `method` unchanged from `base` (or lacks it)."""
    own = getattr(type(term), method, None)
    return own is None or own is getattr(base, method, None)
