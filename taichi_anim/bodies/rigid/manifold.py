"""Contact manifolds of at most four points per pair of convex parts (`manifold_points=4` of
`set_rigid_contacts`):
the contact polygon's corners that span it most, as Jolt's PruneContactPoints and Bullet's manifold keep
(Gregorius, "Robust Contact Creation for Physics Simulations", GDC 2015). A mixin of the detection
(detection.py), over the contact buffers of contacts.py."""

import taichi as ti

from ...runtime import data_oriented


@data_oriented
class ManifoldReduction:
    """Keeps four of the contacts one pair of parts found (_reduce)."""

    @ti.func
    def _reduce(self, first):
        """Keep at most four of the contacts from slot `first` on, all of one pair of parts: the contact
        polygon's corners that span it most, as Jolt's PruneContactPoints and Bullet's manifold keep
        (Gregorius, "Robust Contact Creation for Physics Simulations", GDC 2015): in the plane across the
        first contact's normal, the point farthest from the points' centre, the point farthest from it,
        then the points farthest on either side of the line through those two (the largest triangles). A
        near tie goes to the point found first, so the same corners are kept from step to step and keep
        their warm starts (_pick)."""
        last = self.found[None]
        if last - first > 4 and last <= self.sizes[0]:
            n = self.normal[first]
            centre = ti.Vector.zero(float, 3)
            for c in range(first, last):
                centre += self.point[c]
            centre /= last - first
            zero = ti.Vector.zero(float, 3)
            size = ti.cast(0.0, float)  # the polygon's radius, squared
            for c in range(first, last):
                size = ti.max(size, self._flat(c, centre, n).norm_sqr())
            tol = 1e-2 * size
            keep = ti.Vector([-1, -1, -1, -1])
            keep[0] = self._pick(first, last, 0, centre, n, zero, zero, tol)
            p0 = self._flat(keep[0], centre, n)
            keep[1] = self._pick(first, last, 1, centre, n, p0, zero, tol)
            line = self._flat(keep[1], centre, n) - p0
            keep[2] = self._pick(first, last, 2, centre, n, p0, line, tol)
            keep[3] = self._pick(first, last, 3, centre, n, p0, line, tol)
            # moved down in slot order (each to a slot at or below its own): sorted, the -1s first
            for i in ti.static(range(3)):
                for j in ti.static(range(3 - i)):
                    if keep[j] > keep[j + 1]:
                        keep[j], keep[j + 1] = keep[j + 1], keep[j]
            slot = first
            for i in ti.static(range(4)):
                if keep[i] >= 0:
                    self._move(keep[i], slot)
                    slot += 1
            self.found[None] = slot

    @ti.func
    def _pick(self, first, last, kind: ti.template(), centre, n, p0, line, tol):
        """The first contact whose score is within tol of the largest: kind 0 its squared distance from
        the centre, 1 from p0, 2 and 3 the area it spans with the line from p0 on either side (-1 where no
        point lies off the line by tol). First, not largest: where two points nearly coincide (a's corner
        and b's on a stack), the one taken would flip with micrometre shifts and lose its warm start."""
        best = ti.cast(-1e30, float)
        for c in range(first, last):
            best = ti.max(best, self._score(c, kind, centre, n, p0, line))
        pick = -1
        if ti.static(kind < 2) or best > tol:
            for c in range(first, last):
                if pick < 0 and self._score(c, kind, centre, n, p0, line) >= best - tol:
                    pick = c
        return pick

    @ti.func
    def _score(self, c, kind: ti.template(), centre, n, p0, line):
        d = self._flat(c, centre, n)
        score = ti.cast(0.0, float)
        if ti.static(kind == 0):
            score = d.norm_sqr()
        elif ti.static(kind == 1):
            score = (d - p0).norm_sqr()
        else:
            score = n.dot(line.cross(d - p0)) * ti.static(1.0 if kind == 2 else -1.0)
        return score

    @ti.func
    def _flat(self, c, centre, n):
        """Contact c's point about `centre`, in the plane across unit n."""
        d = self.point[c] - centre
        return d - n * n.dot(d)

    @ti.func
    def _move(self, src, dst):
        """Contact `src` written over slot dst."""
        self.a[dst], self.b[dst], self.key[dst] = self.a[src], self.b[src], self.key[src]
        self.point[dst], self.normal[dst], self.sep[dst] = self.point[src], self.normal[src], self.sep[src]
        self.surface_v[dst], self.mu[dst], self.e[dst] = self.surface_v[src], self.mu[src], self.e[src]
