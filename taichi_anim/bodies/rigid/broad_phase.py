"""The broad phase ahead of the cascade: sweep and prune (Baraff's sort and sweep, "Dynamic Simulation of
Non-Penetrating Rigid Bodies", 1992, ch. 7; Cohen et al.'s I-COLLIDE, 1995), so that a pile of a thousand
bodies does not test half a million pairs of bounding spheres each step.

Each body's bounding sphere, grown by how far it can move in the step and half the contact margin, spans
an interval along each axis; two bodies can pass the cascade's sphere test only if their intervals
overlap along all three (a superset: the sphere test itself runs next, and counts as before). The bodies
stay sorted by their intervals' lower ends along the axis the centres spread most along (a 1000-box bin
is a tall pile: along x, 28 % of its pairs overlapped), from step to step, by insertion sort, which costs
about one pass where little moved (temporal coherence). A sweep over the sorted bodies finds the pairs
overlapping along that axis and lists those that overlap along the other two; they are then
put in the order a loop over every pair (a, b > a) would meet them (a counting sort by a, then each a's
few partners by b), so that the contacts, and the Gauss-Seidel solve that runs in their order, are
exactly those of testing every pair. More overlapping pairs than the list holds: every pair is tested,
as without a broad phase."""

import taichi as ti

from ...runtime import data_oriented

# Overlapping pairs the list holds per body: a box in a pile overlaps a few tens of others along x.
PAIRS_PER_BODY = 64


@data_oriented
class BroadPhase:
    """Sweep-and-prune fields and functions of RigidContacts (contacts.py)."""

    def _init_broad_phase(self, model) -> None:
        make = model.new_field
        self.pair_capacity = max(PAIRS_PER_BODY * model.rigid_capacity, 1024)
        self.sweep_lo = model.rigid_array(self, "bp_lo")
        self.sweep_hi = model.rigid_array(self, "bp_hi")
        self.sweep_grow = model.rigid_array(self, "bp_grow")  # the intervals' half width
        self.sweep_order = model.rigid_array(self, "bp_order", ti.i32)  # bodies by lower end, kept
        self.sweep_sorted = make(self, "bp_sorted", ti.i32, ())  # how many bodies the order holds
        self.sweep_axis = make(self, "bp_axis", ti.i32, ())
        self.pair_start = make(self, "bp_start", ti.i32, model.rigid_capacity + 1)
        self.pair_fill = model.rigid_array(self, "bp_fill", ti.i32)
        self.pair_a = make(self, "bp_a", ti.i32, self.pair_capacity)  # as swept: a < b
        self.pair_raw = make(self, "bp_raw", ti.i32, self.pair_capacity)
        self.pair_b = make(self, "bp_b", ti.i32, self.pair_capacity)  # partners, by a then b
        self.pairs_found = make(self, "bp_found", ti.i32, ())  # sweep_sorted: 0 from RigidContacts._start

    @ti.func
    def _sweep(self, model: ti.template(), state: ti.template(), h):
        """Lists, for the step of h [s], the pairs of bodies whose intervals overlap (pair_b from
        pair_start[a] to pair_start[a + 1] holds a's partners b > a, ascending), unless they are more
        than the list holds (pairs_found then says how many)."""
        n = model.live_rigid()
        # the axis the centres spread most along (kept unless another spreads 20 % more: each switch
        # costs a fresh sort)
        total, square = ti.Vector.zero(float, 3), ti.Vector.zero(float, 3)
        ti.loop_config(serialize=True)
        for i in range(n):
            total += state.rigid_x[i]
            square += state.rigid_x[i] * state.rigid_x[i]
        spread = square - total * total / ti.max(n, 1)
        axis = self.sweep_axis[None]
        for k in ti.static(range(3)):
            if spread[k] > 1.2 * spread[axis]:
                axis = k
        self.sweep_axis[None] = axis
        half_margin = 0.5 * self.margin
        ti.loop_config(serialize=model.rigid_serial)
        for i in range(n):
            grow = model.rigid_bound[i] + self._reach(model, state, i, h) + half_margin
            self.sweep_lo[i] = state.rigid_x[i][axis] - grow
            self.sweep_hi[i] = state.rigid_x[i][axis] + grow
            self.sweep_grow[i] = grow
        # the first step, or another scene in these fields: a fresh order (a new axis sorts the old one)
        reset = self.sweep_sorted[None] != n
        ti.loop_config(serialize=True)
        for i in range(n):
            if reset:
                self.sweep_order[i] = i
        self.sweep_sorted[None] = n
        ti.loop_config(serialize=True)
        for k in range(1, n):  # insertion sort: little to do where the order barely changed
            body = self.sweep_order[k]
            lo = self.sweep_lo[body]
            j = k - 1
            while j >= 0:
                if self.sweep_lo[self.sweep_order[j]] <= lo:
                    break
                self.sweep_order[j + 1] = self.sweep_order[j]
                j -= 1
            self.sweep_order[j + 1] = body
        found = 0
        ti.loop_config(serialize=True)
        for k in range(n):
            i = self.sweep_order[k]
            m = k + 1
            if found > ti.static(self.pair_capacity):
                m = n  # the list overflowed: every pair is tested anyway
            while m < n:
                j = self.sweep_order[m]
                if self.sweep_lo[j] > self.sweep_hi[i]:
                    break
                # and along the other two axes
                apart = ti.abs(state.rigid_x[j] - state.rigid_x[i]) > self.sweep_grow[i] + self.sweep_grow[j]
                apart[axis] = False
                if apart.any() or (model.rigid_inv_mass[i] == 0.0 and model.rigid_inv_mass[j] == 0.0):
                    m += 1  # apart, or two bodies that nothing moves
                    continue
                if found < ti.static(self.pair_capacity):
                    self.pair_a[found] = ti.min(i, j)
                    self.pair_raw[found] = ti.max(i, j)
                found += 1
                m += 1
        self.pairs_found[None] = found
        listed = found <= ti.static(self.pair_capacity)
        self._order_pairs(n if listed else 0, found if listed else 0)

    @ti.func
    def _order_pairs(self, n, found):
        """The swept pairs (pair_a, pair_raw) put in the order of a loop over a, then b > a: counted per a,
        placed in pair_b, then each a's few partners sorted by b (insertion sort)."""
        ti.loop_config(serialize=True)
        for a in range(n + 1):
            self.pair_start[a] = 0
        ti.loop_config(serialize=True)
        for p in range(found):
            self.pair_start[self.pair_a[p] + 1] += 1
        ti.loop_config(serialize=True)
        for a in range(n):
            self.pair_start[a + 1] += self.pair_start[a]
            self.pair_fill[a] = self.pair_start[a]
        ti.loop_config(serialize=True)
        for p in range(found):
            a = self.pair_a[p]
            self.pair_b[self.pair_fill[a]] = self.pair_raw[p]
            self.pair_fill[a] += 1
        ti.loop_config(serialize=True)
        for a in range(n):
            for k in range(self.pair_start[a] + 1, self.pair_start[a + 1]):
                b = self.pair_b[k]
                j = k - 1
                while j >= self.pair_start[a]:
                    if self.pair_b[j] <= b:
                        break
                    self.pair_b[j + 1] = self.pair_b[j]
                    j -= 1
                self.pair_b[j + 1] = b

    @ti.func
    def _partners(self, model: ti.template(), a):
        """(how many partners b > a body a has this step, the first one's slot): the swept pairs', or
        every b > a where the list overflowed (_partner then counts them out)."""
        count, first = model.live_rigid() - 1 - a, -1
        if self.pairs_found[None] <= ti.static(self.pair_capacity):
            count, first = self.pair_start[a + 1] - self.pair_start[a], self.pair_start[a]
        return count, first

    @ti.func
    def _partner(self, a, first, t):
        """Body a's t-th partner: from the list (first >= 0), else a + 1 + t."""
        b = a + 1 + t
        if first >= 0:
            b = self.pair_b[first + t]
        return b
