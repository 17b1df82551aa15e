"""The displacement guard of cloth self-contact (self_contact.py): per-vertex bounds that let no step end
with a crossing (Chen et al., "Vertex Block Descent", SIGGRAPH 2024, sec. 3.7, and "Offset Geometric
Contact", 2025, for the bounds), with unsafe pairs joined into groups that keep their momentum (Provot's
and Bridson et al.'s impact zones, translation only). The reasoning is in self_contact.py's docstring,
item 2; this mixin holds its kernels, on SelfContact's arrays (x0, the pair lists, the bounds, ...).
"""

import taichi as ti

from ..runtime import compile_with, data_oriented

# A guard pair whose sides moved, relative to each other, by this fraction of their distance at the step's
# start is treated as one that could have met (a margin for round-off).
SAFE = 0.9
# Rounds of holding vertices of unsafe pairs before every vertex is held.
HOLD_PASSES = 3


@data_oriented
class DisplacementGuard:
    """Mixin of SelfContact: `_finish` holds the vertices of pairs that could have met, with their groups'
    common motion, and sets the velocities the corrections imply."""

    @ti.func
    def _moves_apart(self, state: ti.template(), i, j):
        """|displacement of local vertex i - displacement of local vertex j| over the step [m]."""
        di = state.particle_x[self.vertex[i]] - self.x0[i]
        dj = state.particle_x[self.vertex[j]] - self.x0[j]
        return (di - dj).norm()

    @ti.func
    def _violations(self, model: ti.template(), state: ti.template(), mark, final: ti.template()):
        """Count the guard pairs that could have met in the step: a pair at distance d at x0 cannot meet
        while every material point of one side moves less than d relative to every point of the other,
        and those relative motions are convex combinations of the vertices' (max over vertex pairs).
        With mark, their vertices are held and the pairs flagged (to join their groups). A vertex moved
        past its reach counts only in the final round (before it, `solve` looks again from there); marked
        there, it is held where its bound says (anchored: its group keeps no common motion)."""
        self.count[7] = 0
        if ti.static(final):
            for v in range(self.verts()):
                # The proximity sweeps, collider projections or a group's common motion may have moved a
                # vertex past its reach, the premise of "a pair not found cannot meet".
                if (state.particle_x[self.vertex[v]] - self.x0[v]).norm() >= self.reach[v]:
                    if self._w(model, v) > 0.0:
                        self.count[7] += 1
                        if mark:
                            self.hold[v] = 1
                            self.anchor[v] = 1
        for v in range(self.verts()):
            for j in range(self.vt_n[v]):
                k = v * self.slots + j
                t = self.tri[self.vt_tri[k]]
                rel = ti.max(
                    self._moves_apart(state, v, t[0]),
                    self._moves_apart(state, v, t[1]),
                    self._moves_apart(state, v, t[2]),
                )
                free = self._w(model, v) + self._w(model, t[0]) + self._w(model, t[1]) + self._w(model, t[2])
                if rel >= SAFE * self.vt_d[k] and free > 0.0:
                    self.count[7] += 1
                    if mark:
                        self.vt_unsafe[k] = ti.i8(1)
                        self.hold[v] = 1
                        for i in ti.static(range(3)):
                            self.hold[t[i]] = 1
        for e in range(self.edges()):
            for j in range(self.ee_n[e]):
                k = e * self.slots + j
                g = self.ee_other[k]
                a, b, c, d = self.edge[e][0], self.edge[e][1], self.edge[g][0], self.edge[g][1]
                rel = ti.max(
                    ti.max(self._moves_apart(state, a, c), self._moves_apart(state, a, d)),
                    ti.max(self._moves_apart(state, b, c), self._moves_apart(state, b, d)),
                )
                free = self._w(model, a) + self._w(model, b) + self._w(model, c) + self._w(model, d)
                if rel >= SAFE * self.ee_d[k] and free > 0.0:
                    self.count[7] += 1
                    if mark:
                        self.ee_unsafe[k] = ti.i8(1)
                        self.hold[a] = 1
                        self.hold[b] = 1
                        self.hold[c] = 1
                        self.hold[d] = 1

    @ti.func
    def _find(self, v):
        """The root of local vertex v's group (path halving; serial callers only)."""
        while self.parent[v] != v:
            self.parent[v] = self.parent[self.parent[v]]
            v = self.parent[v]
        return v

    @ti.func
    def _union(self, a, b):
        ra, rb = self._find(a), self._find(b)
        if ra < rb:
            self.parent[rb] = ra
        elif rb < ra:
            self.parent[ra] = rb

    @ti.func
    def _join_groups(self):
        """Join the four vertices of every flagged pair into one group (union-find, serial: a fixed order
        and no contention)."""
        ti.loop_config(serialize=True)
        for v in range(self.verts()):
            for j in range(self.vt_n[v]):
                k = v * self.slots + j
                if self.vt_unsafe[k]:
                    t = self.tri[self.vt_tri[k]]
                    for i in ti.static(range(3)):
                        self._union(v, t[i])
        ti.loop_config(serialize=True)
        for e in range(self.edges()):
            for j in range(self.ee_n[e]):
                k = e * self.slots + j
                if self.ee_unsafe[k]:
                    g = self.ee_other[k]
                    a = self.edge[e][0]
                    self._union(a, self.edge[e][1])
                    self._union(a, self.edge[g][0])
                    self._union(a, self.edge[g][1])

    @ti.func
    def _held_step(self, v):
        """Local vertex v's guard input displacement from x0, shortened to its bound."""
        step = self.x_in[v] - self.x0[v]
        length = step.norm()
        b = self.bound[v]
        if length > b:
            step *= b / length
        return step

    @ti.func
    def _in_collider(self, model: ti.template(), v, x, t):
        """Whether local vertex v at x overlaps a collider at time t [s] (closer than its radius: where
        the colliders' projection would move it)."""
        nearest = ti.cast(1e30, float)
        for c in ti.static(model.colliders):
            nearest = ti.min(nearest, c.sdf(x, t))
        return nearest < model.radius(self.vertex[v])

    @ti.func
    def _place(self, model: ti.template(), state: ti.template(), t):
        """Held vertices, from the guard's input positions: each moved back to within its bound of x0,
        then every vertex of its group shifted by the group's momentum deficit over its mass, so the
        group keeps its momentum (a perfectly inelastic contact: the group's mass-weighted common
        motion). The shift is common to the group, so every pair inside it stays safe; a group with a
        pinned or anchored vertex, or one whose shift would leave a vertex inside a collider (external:
        it takes the momentum), is not shifted. t [s]: the step's end, for the colliders."""
        for v in range(self.verts()):
            self.g_mass[v] = 0.0
            self.g_deficit[v] = ti.Vector.zero(float, 3)
            self.g_fixed[v] = 0
        # Sums in a fixed serial order: the same run gives the same bits (no float atomics).
        ti.loop_config(serialize=True)
        for v in range(self.verts()):
            if self.hold[v]:
                r = self._find(v)
                self.g_root[v] = r
                w = self._w(model, v)
                if w > 0.0 and self.anchor[v] == 0:
                    self.g_mass[r] += 1.0 / w
                    self.g_deficit[r] += (self._held_step(v) - (self.x_in[v] - self.x0[v])) / w
                else:
                    self.g_fixed[r] = 1
        if ti.static(model.collider_count > 0):
            # A group whose common motion would leave a vertex inside a collider (closer than its radius)
            # is pressed against it: the collider takes the momentum (as a pinned vertex's does), and the
            # group is not shifted. Nothing moves a vertex after the guard, so a shift into a collider would
            # end the step there, and the next step's projection would push it out into the cloth above it.
            # Tested at the shifted position only: a group already touching (its held position a hair
            # inside after round-off) is held too, whichever way the shift points; it is in contact.
            for v in range(self.verts()):
                r = self.g_root[v]
                if self.hold[v] and self.g_fixed[r] == 0 and self.g_mass[r] > 0.0:
                    x = self.x0[v] + self._held_step(v) - self.g_deficit[r] / self.g_mass[r]
                    if self._in_collider(model, v, x, t):
                        self.g_fixed[r] = 1
        for v in range(self.verts()):
            i = self.vertex[v]
            if self.hold[v] and model.inv_mass(i) > 0.0:
                x = self.x0[v] + self._held_step(v)
                r = self.g_root[v]
                if self.g_fixed[r] == 0 and self.g_mass[r] > 0.0:
                    x -= self.g_deficit[r] / self.g_mass[r]
                if (x - self.x_in[v]).norm_sqr() > 0.0:
                    ti.atomic_add(self.count[2], 1)
                state.particle_x[i] = x

    @ti.func
    def _clamp_all(self, model: ti.template(), state: ti.template()):
        """The last resort, if unsafe pairs are left or a pair list overflowed: every vertex moved back
        within its bound of the step's start (every pair then moves by less than 2 gamma d < d; this one
        does not keep momentum). Kinematic vertices (pinned, attached) go where they are driven: a pinned
        vertex does not move, one that a user animates is not guarded."""
        for v in range(self.verts()):
            i = self.vertex[v]
            if (self.count[7] > 0 or self.count[3] > 0) and model.inv_mass(i) > 0.0:
                step = state.particle_x[i] - self.x0[v]
                length = step.norm()
                b = self.bound[v]
                if length > b:
                    state.particle_x[i] = self.x0[v] + step * (b / length)
                    ti.atomic_add(self.count[2], 1)

    # See SelfContact._query. Small cloths (serial_guard) run the whole pass as one serial task: its loops
    # are a few operations per vertex, less than the ~0.1 ms a parallel loop's thread-pool round trip costs
    # here (it has about twenty), and the hold passes then run as a loop instead of unrolled copies.
    @compile_with(cfg_optimization=False)
    @ti.kernel
    def _finish(self, model: ti.template(), state: ti.template(), h: float, t: float, final: ti.template()):
        if ti.static(self.serial_guard):
            ti.loop_config(serialize=True)
            for _ in range(1):
                self._finish_all(model, state, h, t, final)
        else:
            self._finish_all(model, state, h, t, final)

    @ti.func
    def _hold_passes(self, model: ti.template(), state: ti.template(), t, final: ti.template()):
        """HOLD_PASSES passes that hold the vertices of pairs that could have met, then the count of those
        left (count[7]). Serial: one loop over the passes and the count, so that the kernel holds one
        copy of _violations (marking or not is a run-time flag)."""
        if ti.static(self.serial_guard):
            for p in range(HOLD_PASSES + 1):
                self._violations(model, state, p < HOLD_PASSES, final)
                if p < HOLD_PASSES:
                    self._join_groups()
                    self._place(model, state, t)
        else:
            for _pass in ti.static(range(HOLD_PASSES)):
                self._violations(model, state, True, final)
                self._join_groups()
                self._place(model, state, t)
            self._violations(model, state, False, final)

    @ti.func
    def _finish_all(self, model: ti.template(), state: ti.template(), h, t, final: ti.template()):
        for v in range(self.verts()):
            self.hold[v] = 0
            self.anchor[v] = 0
            self.parent[v] = v
            self.x_in[v] = state.particle_x[self.vertex[v]]
            for j in range(self.vt_n[v]):
                self.vt_unsafe[v * self.slots + j] = ti.i8(0)
        for e in range(self.edges()):
            for j in range(self.ee_n[e]):
                self.ee_unsafe[e * self.slots + j] = ti.i8(0)
        # Hold the vertices of pairs that could have met, with their groups' common motion, re-check
        # (a group's motion can make a pair to its outside fast), and after HOLD_PASSES hold every
        # vertex within its bound: all held, every pair is safe (gamma < 1/2).
        if ti.static(self.guard):
            self._hold_passes(model, state, t, final)
            if self.count[7] > 0:
                self.count[6] += 1
            self._clamp_all(model, state)
            if ti.static(not final):
                # Vertices past their reach: `solve` finds the pairs again from these positions.
                self.count[8] = 0
                for v in range(self.verts()):
                    if (state.particle_x[self.vertex[v]] - self.x0[v]).norm() >= self.reach[v]:
                        if self._w(model, v) > 0.0:
                            self.count[8] += 1
        for v in range(self.verts()):
            i = self.vertex[v]
            x = state.particle_x[i]
            if (x - self.x_pred[v]).norm_sqr() > 0.0:
                # The corrections act as an inelastic impulse: the velocity keeps the method's update plus
                # the displacement the contacts added (x_pred: the positions this round started from).
                state.particle_v[i] += (x - self.x_pred[v]) / h
