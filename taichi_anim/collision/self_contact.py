"""Cloth self-contact and cloth-cloth contact: proximity constraints within a thickness, then per-vertex
displacement bounds that let no step end with a crossing.

Runs after a method's step (any integrator: explicit, implicit, springs or membrane), on the step's start
positions x0 (intersection-free) and its end positions x1:

1. Proximity (Bridson, Fedkiw & Anderson, "Robust Treatment of Collisions, Contact and Friction for Cloth
   Animation", SIGGRAPH 2002, sec. 7.1): every vertex-triangle and edge-edge pair of non-adjacent
   primitives closer than the thickness at x1 is pushed apart along its closest-feature direction (the
   side it had at x0), as a position-based constraint C = thickness - d >= 0 (Mueller et al., "Position
   Based Dynamics", 2007, eq. 9 with the inverse masses weighted by the barycentric coordinates), with
   Coulomb friction on the pair's tangential displacement (Macklin et al., "Unified Particle Physics for
   Real-Time Applications", 2014, eq. 24). Corrections are mass-weighted and every pair's sum to zero
   momentum, so the exchange is equal and opposite; they are applied in Gauss-Seidel sweeps in a fixed
   order (reproducible).
2. Guard (Chen et al., "Vertex Block Descent", SIGGRAPH 2024, sec. 3.7, and "Offset Geometric Contact",
   2025, for the bounds): a pair at distance d at x0 cannot meet within the step while each material
   point of one side moves, relative to each of the other, by less than d; relative motions of material
   points are convex combinations of the vertices', so max |dx_i - dx_j| over the pair's vertex pairs
   < d suffices (linear motion in the step). Pairs failing it (by SAFE d) have their vertices held: moved
   back towards x0 to within b_v = gamma min(d_v, d_T for v's triangles T, d_e for v's edges e), where
   d_v is v's distance to the nearest non-incident triangle, d_T the nearest vertex's to T, d_e the
   nearest non-adjacent edge's to e (all at x0). A pair whose vertices are all held moves by at most
   2 gamma d < d: safe. The check repeats (holding can make another pair unsafe), and after HOLD_PASSES
   every vertex is held. This is the continuous guarantee, without a root-finding CCD pass, for any step
   a method proposes, provided x0 has no crossing and kinematic vertices are static (a pinned vertex
   that the user animates is not guarded). A held vertex keeps the velocity of the motion it was allowed.
   Momentum: the vertices of every unsafe pair join one group (union-find), and after the holding each
   group is shifted by its momentum deficit over its mass, so it keeps its momentum (a perfectly
   inelastic contact, the group's mass-weighted common motion, as in Provot's and Bridson et al.'s
   impact zones, translation only). A common shift leaves every pair inside the group as safe as it was;
   pairs to the outside are re-checked, and a vertex the shift carries past its reach has its pairs
   looked for again from there (a second round). Only the last resort (every vertex held, after
   HOLD_PASSES), a group with a pinned vertex and one whose shift would leave a vertex inside a collider
   (pressed against it: the collider takes the momentum) do not keep momentum.

Candidate pairs come from a box structure over the triangles at x0 (a BVH, spatial/), refit every step
(an edge's candidates are the edges owned by the triangles its box meets: owned_edges), each primitive's
box grown by its reach r = m + KEEP thickness / 2 for a vertex that the
method moved by m: a pair farther apart than both sides' reaches cannot meet while every vertex moves
less than its reach (a vertex moved past its reach by the sweeps is held), and every pair that can come
within KEEP thicknesses is found.

The guarantee needs a start without crossings: the guard keeps every pair on the side it starts on, so
two sheets that start interpenetrating stay hooked. The first time a State is stepped its triangles are
checked exactly (spatial/crossings.py) and, by default, a start with crossing or touching pairs of
non-adjacent triangles is refused with the count and the first pair (start_crossings="warn" runs it
anyway, with a warning naming the count).
"""

import warnings
import weakref

import numpy as np
import taichi as ti

from .. import bulk, capacity, validate
from ..errors import DivergenceError, ParameterError
from ..runtime import compile_with, data_oriented, serial_loops
from ..spatial.bounds import aabb_point_distance_sq
from ..spatial.crossings import intersecting_triangle_pairs, triangles_meet
from ..spatial.distance import point_triangle_closest, segment_segment_closest
from ..spatial.select import BoxQueryMethod, make_box_query
from .self_contact_guard import SAFE, DisplacementGuard
from .self_contact_proximity import ProximitySweeps

# Pairs kept for the proximity sweeps: those within this many thicknesses at the method's proposed end
# positions (the sweeps move vertices by about a thickness at most).
KEEP = 1.5


def mesh_edges(triangles: np.ndarray) -> np.ndarray:
    """(E,2) unique undirected edges (sorted pairs) of triangles (F,3)."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def owned_edges(triangles: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(F,3) per triangle, the indices into `edges` (mesh_edges' sorted pairs) of its three edges that it
    is the first triangle to hold (its owner, the lowest triangle index), -1 for the others: every edge
    appears once over all triangles."""
    f = len(triangles)
    sides = np.stack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]], axis=1)
    pairs = np.sort(sides, axis=2)
    n = int(max(triangles.max(initial=0), edges.max(initial=0))) + 1
    keys = pairs[..., 0] * n + pairs[..., 1]  # (F, 3)
    ids = np.searchsorted(edges[:, 0] * n + edges[:, 1], keys)
    flat = ids.reshape(-1)
    first = np.full(len(edges), 3 * f, dtype=np.int64)
    np.minimum.at(first, flat, np.arange(3 * f))
    return np.where(first[flat] == np.arange(3 * f), flat, -1).reshape(f, 3)


def incidence(items: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR (start (count+1,), list) of the rows of `items` (K, arity) that hold each index < count."""
    rows = np.repeat(np.arange(len(items)), items.shape[1])
    order = np.argsort(items.reshape(-1), kind="stable")
    start = np.zeros(count + 1, dtype=np.int64)
    np.add.at(start, items.reshape(-1) + 1, 1)
    return np.cumsum(start).astype(np.int32), rows[order].astype(np.int32)


@data_oriented
class SelfContact(ProximitySweeps, DisplacementGuard):
    """The contact solver for every cloth triangle of `model` (built by the Stepper when the scene asked
    for self-contact). thickness [m]: the separation kept between non-adjacent primitives; friction:
    Coulomb coefficient; iterations: Gauss-Seidel sweeps of the proximity constraints; relaxation: the
    factor applied to each pair's correction (over-relaxation above 1); bound_fraction gamma in
    (0, 0.5); pairs_per_vertex: capacity of the pair lists (an overflow raises rather than drop one);
    guard=False leaves out the displacement bounds (proximity only: cheaper, but a fast step can end
    with a crossing; for comparisons); broad_phase: "auto", "brute", "grid", "octree" or "bvh";
    start_crossings: what a State whose first step starts with crossing triangles gets, "raise" (a
    ParameterError naming the count and the first pair) or "warn" (a RuntimeWarning; the pairs stay
    crossed).

    A solver of the Stepper's list (solvers.py), the last: `before_substep` records the substep's start,
    `after_substep` corrects what the method and the solvers before it proposed, `check` reads the
    statistics (and raises if a pair list overflowed)."""

    name = "self-contact"

    def __init__(
        self,
        model,
        *,
        thickness: float,
        friction: float,
        iterations: int,
        relaxation: float,
        bound_fraction: float,
        pairs_per_vertex: int,
        guard: bool = True,
        broad_phase: str = "auto",
        start_crossings: str = "raise",
    ):
        self.thickness = thickness
        self.start_crossings = start_crossings
        self._checked = weakref.WeakSet()  # States whose start was checked for crossings
        self._triangles = np.asarray(model.triangles, dtype=np.int64)
        self.friction = friction
        self.iterations = iterations
        self.relaxation = relaxation
        self.gamma = bound_fraction
        self.guard = guard
        self.broad_phase = broad_phase
        tri_model = np.asarray(model.triangles, dtype=np.int64)
        used = np.unique(tri_model)
        local = np.full(model.particle_count, -1, dtype=np.int64)
        local[used] = np.arange(len(used))
        tri = local[tri_model]
        edges = mesh_edges(tri)
        nv, nf, ne = len(used), len(tri), len(edges)
        self.vertex_count, self.triangle_count, self.edge_count = nv, nf, ne
        # Arrays of capacity rows: the counts, or under capacity buckets (capacity.py) their buckets, from
        # the model's pool, with the loops running to the live counts read at run time: a cloth of another
        # size in the same buckets compiles nothing new.
        self.buckets = model.size_buckets
        rows = capacity.bucket if self.buckets else int
        cv, cf, ce = rows(nv), rows(nf), rows(ne)
        self.serial_guard = serial_loops(cv)  # the guard's pass as one serial task (self_contact_guard.py)
        make = self._make = model.new_field
        self.live = None
        if self.buckets:
            self.live = make(self, "self_contact_live", ti.i32, (), (3,))
            self.live[None] = (nv, nf, ne)
        with bulk.batch():  # the uploads in one launch (from_numpy is a kernel per field)
            self.vertex = self._upload("self_contact_vertex", used, cv)
            self.tri = self._upload("self_contact_tri", tri, cf, 3)
            self.edge = self._upload("self_contact_edge", edges, ce, 2)
            self.tri_edges = self._upload("self_contact_tri_edges", owned_edges(tri, edges), cf, 3)
            vt_start, vt_list = incidence(tri, nv)
            ve_start, ve_list = incidence(edges, nv)
            self.vt_start = self._upload("self_contact_vt_start", vt_start, cv + 1)
            self.vt_list = self._upload("self_contact_vt_list", vt_list, 3 * cf)
            self.ve_start = self._upload("self_contact_ve_start", ve_start, cv + 1)
            self.ve_list = self._upload("self_contact_ve_list", ve_list, 2 * ce)
        self.x0 = make(self, "self_contact_x0", float, cv, (3,))
        self.x_pred = make(self, "self_contact_x_pred", float, cv, (3,))
        self.d_vert = make(self, "self_contact_d_vert", float, cv)
        self.d_tri = make(self, "self_contact_d_tri", float, cf)
        self.d_edge = make(self, "self_contact_d_edge", float, ce)
        self.bound = make(self, "self_contact_bound", float, cv)
        # Pairs, in slots per query primitive (vertex v: v K .. v K + vt_n[v]; edge e likewise), written in
        # the traversal's order: the lists, and so the sweeps, are the same whatever the thread timing.
        # Every pair found within the two sides' reaches is kept (a guard pair, with its distance at x0
        # [m]); `near` marks those the proximity sweeps treat.
        k = self.slots = pairs_per_vertex
        self.vt_tri = make(self, "self_contact_vt_tri", ti.i32, cv * k)
        self.vt_d = make(self, "self_contact_vt_d", float, cv * k)
        self.vt_near = make(self, "self_contact_vt_near", ti.i8, cv * k)
        self.vt_n = make(self, "self_contact_vt_n", ti.i32, cv)
        self.ee_other = make(self, "self_contact_ee_other", ti.i32, ce * k)
        self.ee_d = make(self, "self_contact_ee_d", float, ce * k)
        self.ee_near = make(self, "self_contact_ee_near", ti.i8, ce * k)
        self.ee_n = make(self, "self_contact_ee_n", ti.i32, ce)
        self.hold = make(self, "self_contact_hold", ti.i32, cv)
        # The guard's groups: pairs flagged unsafe join their vertices (union-find); each group keeps its
        # momentum (`_place`). Per vertex: anchored (held absolutely), the guard's input position, its
        # group's root, and per root the free mass [kg], momentum deficit [kg m] and a fixed flag.
        self.vt_unsafe = make(self, "self_contact_vt_unsafe", ti.i8, cv * k)
        self.ee_unsafe = make(self, "self_contact_ee_unsafe", ti.i8, ce * k)
        self.anchor = make(self, "self_contact_anchor", ti.i32, cv)
        self.parent = make(self, "self_contact_parent", ti.i32, cv)
        self.x_in = make(self, "self_contact_x_in", float, cv, (3,))
        self.g_root = make(self, "self_contact_g_root", ti.i32, cv)
        self.g_mass = make(self, "self_contact_g_mass", float, cv)
        self.g_deficit = make(self, "self_contact_g_deficit", float, cv, (3,))
        self.g_fixed = make(self, "self_contact_g_fixed", ti.i32, cv)
        # [0, 1] vertex-triangle and edge-edge proximity pairs of the last step; [2] vertex-steps held by
        # their bound (a running total); [3] a sticky overflow flag; [4, 5] guard pairs of the last step;
        # [6] steps that held every vertex (a running total); [7] violations in the current pass; [8]
        # vertices past their reach after the first round (a second round looks again from there).
        self.count = make(self, "self_contact_count", ti.i32, 9)
        if self.buckets:  # running totals: a pooled field holds what its last owner left
            self.count.from_numpy(np.zeros(9, dtype=np.int32))
        self.reach = make(self, "self_contact_reach", float, cv)  # per vertex [m]: how far its queries look
        self.tri_reach = make(self, "self_contact_tri_reach", float, cf)
        self.edge_reach = make(self, "self_contact_edge_reach", float, ce)
        # A box structure over the triangles (a BVH, or brute force for small cloths: spatial/select.py),
        # chosen by capacity. The edges' boxes are plain arrays: an edge's candidates are the edges its
        # box's triangles own (owned_edges), each triangle's box holding its edges' boxes. One structure
        # instead of one per kind of primitive: the tablecloth's and layers' frames compile or load one
        # BVH build and one refit fewer (the tablecloth's builds 0.267 -> 0.172 s warm; cold, a build
        # took about 0.28 s and a refit 0.12 s).
        self.tri_boxes = make_box_query(cf, method=broad_phase, make=make)
        self.edge_lo = make(self, "self_contact_edge_lo", float, ce, (3,))
        self.edge_hi = make(self, "self_contact_edge_hi", float, ce, (3,))
        self._built = False
        # Made after ti.init, so `float` resolves to the chosen precision.
        vec3 = ti.types.vector(3, float)
        self._acc = ti.types.struct(x=vec3, lo=vec3, hi=vec3, r=float, d=float, n=ti.i32)
        self.stats = {"vertex_triangle_pairs": 0, "edge_edge_pairs": 0, "clamped": 0}
        self.start_crossing_pairs = 0  # crossing triangle pairs found at the last start checked

    def _upload(self, role: str, data: np.ndarray, rows: int, n: int = 1):
        """An int32 field of `rows` rows (n columns) holding `data` (zero rows past it)."""
        f = self._make(self, role, ti.i32, rows, () if n == 1 else (n,))
        bulk.fill([(f, capacity.padded(np.asarray(data).astype(np.int32), rows, np.int32))])
        return f

    # The live counts of vertices, triangles and edges (capacity.live).
    @ti.func
    def verts(self):
        return capacity.live(self.live, 0, self.vertex_count)

    @ti.func
    def tris(self):
        return capacity.live(self.live, 1, self.triangle_count)

    @ti.func
    def edges(self):
        return capacity.live(self.live, 2, self.edge_count)

    def settings(self) -> dict:
        return {
            "thickness": self.thickness,
            "friction": self.friction,
            "iterations": self.iterations,
            "relaxation": self.relaxation,
            "bound_fraction": self.gamma,
            "guard": self.guard,
            "pairs_per_vertex": self.slots,
            "broad_phase": self.tri_boxes.describe(),
            "start_crossings": self.start_crossings,
        }

    # -- the step ---------------------------------------------------------------------------------------

    def substeps(self, model, state, dt: float) -> int:
        """1: the guard's bounds hold for any step size."""
        return 1

    def before_substep(self, model, state, h: float) -> None:
        """Record the step's start positions (call before the method advances the state); a State's
        first step checks its start for crossings (`check_start`)."""
        if state not in self._checked:
            self.check_start(state)
            self._checked.add(state)
        self._begin(state)

    def check_start(self, state) -> int:
        """Count the pairs of non-adjacent cloth triangles of `state` that cross or touch (exactly, as
        spatial.crossings does) and, if there are any, raise ParameterError naming the count and the
        first pair (start_crossings "raise") or warn (start_crossings "warn"). Returns the count."""
        tri = self._triangles
        x = state.positions()
        pairs = intersecting_triangle_pairs(x, tri)
        self.start_crossing_pairs = len(pairs)
        if not len(pairs):
            return 0
        i, j = (int(k) for k in pairs[0])
        what = (
            f"triangles {i} (vertices {tuple(map(int, tri[i]))}) and {j} (vertices {tuple(map(int, tri[j]))})"
        )
        for f, g in ((i, j), (j, i)):  # name an edge of one that meets the other
            for a, b in ((0, 1), (1, 2), (2, 0)):
                p, q = x[tri[f, a]], x[tri[f, b]]
                if triangles_meet(np.array([[p, q, q]]), x[tri[g]][None])[0]:
                    edge = f"edge ({int(tri[f, a])}, {int(tri[f, b])}) of triangle {f}"
                    what = f"{edge} meets triangle {g} (vertices {tuple(map(int, tri[g]))})"
                    break
            else:
                continue
            break
        message = (
            f"self-contact: the start state has {len(pairs)} pair(s) of non-adjacent cloth triangles that "
            f"cross or touch, the first: {what}; the guard keeps every pair on the side it starts on, so "
            f"crossed cloth stays hooked"
        )
        if self.start_crossings == "raise":
            raise ParameterError(
                f"{message}. Place the cloths apart (at least the thickness {self.thickness:g} m) or pass "
                f"start_crossings='warn' to add_cloth_self_contact to run anyway"
            )
        warnings.warn(f"{message} (start_crossings='warn': running anyway)", RuntimeWarning, stacklevel=4)
        return len(pairs)

    def after_substep(self, model, state, h: float, step: int) -> None:
        """Proximity constraints and displacement bounds on the state a method just advanced by h [s]."""
        self._find_pairs(model, state)
        if self.count[0] + self.count[1] > 0:  # one read: most steps of a falling cloth have no pairs
            self._proximity(model, state, state.time + h)
        if not self.guard:
            self._finish(model, state, h, state.time + h, True)
            return
        self._finish(model, state, h, state.time + h, False)
        if self.count[8] > 0:
            # A group's common motion (or a proximity sweep) carried a vertex past its reach, beyond the
            # pairs looked at: look again from these positions (reaches grown to their displacements),
            # and guard them once more (then a vertex past its reach is held where its bound says).
            self._find_pairs(model, state)
            self._finish(model, state, h, state.time + h, True)

    def _find_pairs(self, model, state) -> None:
        """Candidate pairs, their distances at x0 and the bounds, for the positions the state holds."""
        self._boxes(model, state)
        if self._built:
            self.tri_boxes.update()
        else:
            self.tri_boxes.build(self.triangle_count)
            self._built = True
        self._query()
        self._query_edges()
        self._bounds()

    def check(self, state) -> None:
        """Read the statistics (`read_stats`): DivergenceError if a pair list overflowed."""
        self.read_stats()

    def read_stats(self) -> dict:
        """Pairs found in the last step, and vertex-steps held by their bound so far (reads
        synchronise); raises if a candidate list overflowed."""
        c = bulk.read([self.count], 9)[0]  # one serial launch (to_numpy is a parallel loop: ~0.1 ms)
        if c[3]:
            raise DivergenceError(
                f"self-contact found more than pairs_per_vertex={self.slots} pairs for one vertex or "
                f"edge (raise it for dense piles and fast cloth, which looks farther; or the cloth is "
                f"exploding); the step was finished with every vertex held within its bound"
            )
        self.stats = {
            "vertex_triangle_pairs": int(c[0]),
            "edge_edge_pairs": int(c[1]),
            "guard_pairs": int(c[4] + c[5]),
            "clamped": int(c[2]),
            "all_held": int(c[6]),
        }
        return self.stats

    @ti.kernel
    def _begin(self, state: ti.template()):
        for v in range(self.verts()):
            self.x0[v] = state.particle_x[self.vertex[v]]

    @ti.kernel
    def _boxes(self, model: ti.template(), state: ti.template()):
        for v in range(self.verts()):
            x = state.particle_x[self.vertex[v]]
            self.x_pred[v] = x
            # Reach: a pair farther apart than the reaches of its two sides cannot meet while every vertex
            # moves less than its reach (held vertices move at most gamma times it); the reaches of two
            # sides also sum to KEEP thicknesses plus both displacements, so every pair that can come
            # within KEEP thicknesses at the end is found.
            self.reach[v] = (x - self.x0[v]).norm() + 0.5 * KEEP * self.thickness
        for f in range(self.tris()):
            t = self.tri[f]
            a, b, c = self._tri_x0(f)
            r = ti.max(self.reach[t[0]], self.reach[t[1]], self.reach[t[2]])
            self.tri_reach[f] = r
            self.tri_boxes.prim_lo[f] = ti.min(a, b, c) - r
            self.tri_boxes.prim_hi[f] = ti.max(a, b, c) + r
        for e in range(self.edges()):
            i, j = self.edge[e][0], self.edge[e][1]
            p, q = self.x0[i], self.x0[j]
            r = ti.max(self.reach[i], self.reach[j])
            self.edge_reach[e] = r
            self.edge_lo[e] = ti.min(p, q) - r
            self.edge_hi[e] = ti.max(p, q) + r

    @ti.func
    def _tri_x0(self, f):
        t = self.tri[f]
        return self.x0[t[0]], self.x0[t[1]], self.x0[t[2]]

    @ti.func
    def _add_pair(
        self,
        ids: ti.template(),
        dist: ti.template(),
        near: ti.template(),
        base,
        other,
        d,
        close,
        ret: ti.template(),
    ):
        """Write pair (query primitive, other) at distance d into the query primitive's next slot."""
        if ret.n < self.slots:
            k = base + ret.n
            ids[k] = other
            dist[k] = d
            near[k] = ti.cast(close, ti.i8)
            ret.n += 1
        else:
            self.count[3] = 1

    @ti.func
    def _visit_triangle(self, v, f, ret: ti.template()):
        t = self.tri[f]
        reach = ret.r + self.tri_reach[f]
        # The hierarchy's boxes are grown by the reach on every axis; the Euclidean distance to the bare
        # box rejects more (a pair farther apart than both reaches needs nothing: see _query).
        lo = self.tri_boxes.prim_lo[f] + self.tri_reach[f]
        hi = self.tri_boxes.prim_hi[f] - self.tri_reach[f]
        if t[0] != v and t[1] != v and t[2] != v and aabb_point_distance_sq(lo, hi, ret.x) < reach * reach:
            a, b, c = self._tri_x0(f)
            w = point_triangle_closest(ret.x, a, b, c)
            d = (ret.x - (w[0] * a + w[1] * b + w[2] * c)).norm()
            # Any distance found is a true one, so taking the minimum with it can only tighten a bound.
            ret.d = ti.min(ret.d, d)
            ti.atomic_min(self.d_tri[f], d)
            if d < reach:
                close = d - self._apart(v, t[0], t[1], t[2]) < KEEP * self.thickness
                self._add_pair(self.vt_tri, self.vt_d, self.vt_near, v * self.slots, f, d, close, ret)

    @ti.func
    def _apart(self, v, i, j, k):
        """The most vertex v moved relative to vertex i, j or k over the proposed step [m]: a pair's
        distance changes by at most that much (so no second closest-point query at the end positions)."""
        dv = self.x_pred[v] - self.x0[v]
        return ti.max(
            (dv - self.x_pred[i] + self.x0[i]).norm(),
            (dv - self.x_pred[j] + self.x0[j]).norm(),
            (dv - self.x_pred[k] + self.x0[k]).norm(),
        )

    @ti.func
    def _visit_owned(self, e, f, ret: ti.template()):
        """_visit_edge for the edges triangle f owns (a run-time loop: one copy of the edge test). Its
        box, grown by the largest reach of its vertices, holds each of its edges' boxes grown by theirs,
        so every edge whose box meets the query's is found through its owner (rounding is monotone: the
        held box stays inside in floating point too); _visit_edge's own test (the bare boxes' gap under
        both reaches) is the stricter one, so the pairs kept are those the edges' own boxes gave (and a
        pair on the rounding edge of its box, now kept), listed in the triangles' traversal order."""
        owned = self.tri_edges[f]
        for k in range(3):
            if owned[k] >= 0:
                self._visit_edge(e, owned[k], ret)

    @ti.func
    def _visit_edge(self, e, g, ret: ti.template()):
        a, b = self.edge[e][0], self.edge[e][1]
        c, d = self.edge[g][0], self.edge[g][1]
        reach = ret.r + self.edge_reach[g]
        lo = self.edge_lo[g] + self.edge_reach[g]
        hi = self.edge_hi[g] - self.edge_reach[g]
        gap = ti.max(lo - ret.hi, 0.0) + ti.max(ret.lo - hi, 0.0)  # between the bare boxes
        if g > e and a != c and a != d and b != c and b != d and gap.norm_sqr() < reach * reach:
            p0, p1, q0, q1 = self.x0[a], self.x0[b], self.x0[c], self.x0[d]
            st = segment_segment_closest(p0, p1, q0, q1)
            dist = ((p0 + st[0] * (p1 - p0)) - (q0 + st[1] * (q1 - q0))).norm()
            ret.d = ti.min(ret.d, dist)
            ti.atomic_min(self.d_edge[g], dist)
            if dist < reach:
                close = (
                    dist - ti.max(self._apart(a, c, d, d), self._apart(b, c, d, d)) < KEEP * self.thickness
                )
                self._add_pair(self.ee_other, self.ee_d, self.ee_near, e * self.slots, g, dist, close, ret)

    # Large inlined exact tests: Taichi's CFG passes cost compile time only (with _query_edges, _finish
    # and BVH._build, the tablecloth's cold compile fell from 14.4 to 9.9 s at the same ms per frame).
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _query(self):
        for f in range(self.tris()):
            self.d_tri[f] = self.tri_reach[f]
        for e in range(self.edges()):
            self.d_edge[e] = self.edge_reach[e]
        # A pair (vertex v, triangle T) is visited when v's box, grown by its reach, overlaps T's box grown
        # by T's: one that is not lies farther than r_v + r_T, more than both can move.
        for v in range(self.verts()):
            r = self.reach[v]
            ret = self._acc(x=self.x0[v], lo=self.x0[v], hi=self.x0[v], r=r, d=r, n=0)
            self.tri_boxes.for_each_overlap(v, ret.x - r, ret.x + r, self._visit_triangle, ret)
            self.d_vert[v] = ret.d
            self.vt_n[v] = ret.n

    # See _query.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _query_edges(self):
        # A kernel of its own: one with both traversals took several times as long to compile.
        for e in range(self.edges()):
            p, q = self.x0[self.edge[e][0]], self.x0[self.edge[e][1]]
            r = self.edge_reach[e]
            ret = self._acc(x=p, lo=ti.min(p, q), hi=ti.max(p, q), r=r, d=r, n=0)
            self.tri_boxes.for_each_overlap(e, ti.min(p, q) - r, ti.max(p, q) + r, self._visit_owned, ret)
            self.ee_n[e] = ret.n
            ti.atomic_min(self.d_edge[e], ret.d)

    @ti.kernel
    def _bounds(self):
        for v in range(self.verts()):
            d = self.d_vert[v]
            for k in range(self.vt_start[v], self.vt_start[v + 1]):
                d = ti.min(d, self.d_tri[self.vt_list[k]])
            for k in range(self.ve_start[v], self.ve_start[v + 1]):
                d = ti.min(d, self.d_edge[self.ve_list[k]])
            # With nothing found, d is the vertex's reach: held, it moves at most gamma times that.
            self.bound[v] = self.gamma * d
        for k in ti.static((0, 1, 4, 5)):
            self.count[k] = 0
        # Statistics, summed serially: a parallel loop would contend for the four counters.
        ti.loop_config(serialize=True)
        for v in range(self.verts()):
            self.count[4] += self.vt_n[v]
            for j in range(self.vt_n[v]):
                self.count[0] += ti.cast(self.vt_near[v * self.slots + j], ti.i32)
        ti.loop_config(serialize=True)
        for e in range(self.edges()):
            self.count[5] += self.ee_n[e]
            for j in range(self.ee_n[e]):
                self.count[1] += ti.cast(self.ee_near[e * self.slots + j], ti.i32)


def self_contact_options(
    *,
    thickness: float,
    friction: float = 0.0,
    iterations: int = 4,
    relaxation: float = 1.0,
    bound_fraction: float = 0.4,
    pairs_per_vertex: int = 128,
    guard: bool = True,
    broad_phase: str = "auto",
    start_crossings: str = "raise",
) -> dict:
    """Validated options of `SelfContact` (the Builder's add_cloth_self_contact)."""
    return dict(
        thickness=validate.positive("thickness", thickness),
        friction=validate.non_negative("friction", friction),
        iterations=validate.count("iterations", iterations, 1),
        relaxation=validate.in_range("relaxation", relaxation, 1e-3, 2.0),
        bound_fraction=validate.in_range("bound_fraction", bound_fraction, 1e-3, 0.5 * SAFE),
        pairs_per_vertex=validate.count("pairs_per_vertex", pairs_per_vertex, 1),
        guard=bool(guard),
        broad_phase=validate.choice("broad_phase", broad_phase, [m.value for m in BoxQueryMethod] + ["auto"]),
        start_crossings=validate.choice("start_crossings", start_crossings, ["raise", "warn"]),
    )
