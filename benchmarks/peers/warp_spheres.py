"""The engine's hard-sphere step ported to NVIDIA Warp (warp-lang) with `warp.HashGrid`: the peer of
benchmarks/spheres.py. Same algorithm and formulas as taichi_anim (integrators/symplectic_euler.py,
collision/response.py and collision/spheres.py), for equal spheres in a box container; only the
neighbour structure (Warp's HashGrid, a radix sort of cell indices) and the memory layout differ.

One step of size h:
  1. prediction, symplectic Euler with gravity: v* = v + h (m g) (1/m), x* = x + h v*, then the box walls
     (`_project` of collision/response.py: each wall the sphere overlaps moves it out, and an approach
     faster than rest_speed bounces with the wall's restitution and Coulomb friction);
  2. `HashGrid.build(x*, 2 r)`;
  3. `iterations` Jacobi position sweeps on ping-pong buffers: a sphere with n overlapping pairs moves
     by min(1, omega / n) times the sum of w_i / (w_i + w_j) (r_i + r_j - |d|) / |d| d over them
     (over-relaxed mean, omega = `relaxation`), then out of the walls;
  4. one velocity sweep: v = v* + (x - x*)/h, plus the mean over pairs that overlapped in the prediction
     and approached (v_rel.n < 0 there) of the change that makes the relative normal velocity -e times
     its value before the solve (e = 0 below rest_speed), with Coulomb friction on the tangential part.

The engine also separates coincident centres along x (no line of centres); the benchmark's lattice
never has any, so the port leaves that branch out.

Threads take spheres in the grid's cell order (`hash_grid_point_id`), Warp's idiom for memory locality;
the arrays stay in particle order (the engine copies them into cell order instead). Warp runs CPU
kernels on one thread.
"""

import numpy as np
import warp as wp

wp.config.quiet = True


@wp.func
def respond(v: wp.vec3, n: wp.vec3, e: float, mu: float):
    """collision/response.py `respond`: velocity after an impact on a surface of outward normal n."""
    vn = wp.dot(v, n)
    out = v
    if vn < 0.0:
        v_normal = vn * n
        v_tangent = v - v_normal
        vt = wp.length(v_tangent)
        keep = wp.max(1.0 - mu * (1.0 + e) * (-vn) / wp.max(vt, 1.0e-12), 0.0)
        out = keep * v_tangent - e * v_normal
    return out


@wp.func
def wall(x: wp.vec3, v: wp.vec3, n: wp.vec3, offset: float, r: float, e: float, mu: float, rest: float):
    """One plane n.x >= offset of collision/response.py `_project_each`."""
    d = wp.dot(n, x) - offset - r
    if d < 0.0:
        x = x - d * n
        e_eff = e
        if -wp.dot(v, n) <= rest:
            e_eff = 0.0
        v = respond(v, n, e_eff, mu)
    return x, v


@wp.func
def walls(x: wp.vec3, v: wp.vec3, r: float, lo: wp.vec3, hi: wp.vec3, e: float, mu: float, rest: float):
    """collision/response.py `_project` for the six planes of `add_collider_box` (lo then hi, per axis)."""
    nearest = wp.min(
        wp.min(wp.min(x[0] - lo[0], hi[0] - x[0]), wp.min(x[1] - lo[1], hi[1] - x[1])),
        wp.min(x[2] - lo[2], hi[2] - x[2]),
    )
    if nearest < r:
        for a in range(3):
            n = wp.vec3(0.0)
            n[a] = 1.0
            x, v = wall(x, v, n, lo[a], r, e, mu, rest)
            x, v = wall(x, v, -n, -hi[a], r, e, mu, rest)
    return x, v


@wp.func
def pair_projection(xi: wp.vec3, ri: float, wi: float, xj: wp.vec3, rj: float, wj: float):
    """collision/spheres.py `pair_projection`."""
    d = xi - xj
    dist = wp.length(d)
    return wi / wp.max(wi + wj, 1.0e-30) * (ri + rj - dist) / dist * d


@wp.func
def pair_velocity(
    n: wp.vec3,
    vi: wp.vec3,
    wi: float,
    vj: wp.vec3,
    wj: float,
    vn_before: float,
    e: float,
    mu: float,
    rest_speed: float,
):
    """collision/spheres.py `pair_velocity`."""
    e_eff = e
    if -vn_before <= rest_speed:
        e_eff = 0.0
    target = -e_eff * vn_before
    vrel = vi - vj
    vn = wp.dot(vrel, n)
    share = wi / wp.max(wi + wj, 1.0e-30)
    dv = share * (target - vn) * n
    vt = vrel - vn * n
    vt_norm = wp.length(vt)
    if mu > 0.0 and vt_norm > 1.0e-12:
        dv = dv - share * wp.min(mu * (target - vn_before), vt_norm) / vt_norm * vt
    return dv


@wp.kernel
def predict(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    xp: wp.array(dtype=wp.vec3),
    vp: wp.array(dtype=wp.vec3),
    force: wp.vec3,
    inv_mass: float,
    h: float,
    r: float,
    lo: wp.vec3,
    hi: wp.vec3,
    wall_e: float,
    wall_mu: float,
    rest_speed: float,
):
    i = wp.tid()
    v1 = v[i] + h * (force * inv_mass)
    x1 = x[i] + h * v1
    x1, v1 = walls(x1, v1, r, lo, hi, wall_e, wall_mu, rest_speed)
    xp[i] = x1
    vp[i] = v1


@wp.kernel
def project(
    grid: wp.uint64,
    src: wp.array(dtype=wp.vec3),
    dst: wp.array(dtype=wp.vec3),
    r: float,
    w: float,
    reach: float,
    relaxation: float,
    lo: wp.vec3,
    hi: wp.vec3,
):
    i = wp.hash_grid_point_id(grid, wp.tid())
    x = src[i]
    dx = wp.vec3(0.0)
    n = int(0)  # noqa: UP018 (Warp: a loop-carried variable needs an explicit type)
    for j in wp.hash_grid_query(grid, x, reach):
        if j != i:
            xj = src[j]
            d = x - xj
            d2 = wp.dot(d, d)
            if d2 > 1.0e-24 and d2 < reach * reach:  # coincident centres: left to the next step
                dx = dx + pair_projection(x, r, w, xj, r, w)
                n += 1
    if n > 0:
        x = x + dx * wp.min(1.0, relaxation / float(n))
    x, _unused = walls(x, wp.vec3(0.0), r, lo, hi, 0.0, 0.0, 0.0)
    dst[i] = x


@wp.kernel
def velocities(
    grid: wp.uint64,
    xs: wp.array(dtype=wp.vec3),
    xp: wp.array(dtype=wp.vec3),
    vp: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
    r: float,
    w: float,
    reach: float,
    inv_h: float,
    e: float,
    mu: float,
    rest_speed: float,
):
    i = wp.hash_grid_point_id(grid, wp.tid())
    xi = xs[i]
    xpi = xp[i]
    vpi = vp[i]
    vi = vpi + (xi - xpi) * inv_h
    dv = wp.vec3(0.0)
    n = int(0)  # noqa: UP018 (Warp: a loop-carried variable needs an explicit type)
    for j in wp.hash_grid_query(grid, xpi, reach):
        if j != i:
            d = xpi - xp[j]
            d2 = wp.dot(d, d)
            if d2 > 1.0e-24 and d2 < reach * reach:
                nrm = d / wp.sqrt(d2)
                vn_before = wp.dot(vpi - vp[j], nrm)
                if vn_before < 0.0:
                    ds = xi - xs[j]
                    ns = ds / wp.max(wp.length(ds), 1.0e-30)
                    vj = vp[j] + (xs[j] - xp[j]) * inv_h
                    dv = dv + pair_velocity(ns, vi, w, vj, w, vn_before, e, mu, rest_speed)
                    n += 1
    if n > 0:
        vi = vi + dv / float(n)
    v_out[i] = vi


@wp.kernel
def overlaps(grid: wp.uint64, x: wp.array(dtype=wp.vec3), r: float, out: wp.array(dtype=float)):
    """Largest overlap 2r - |x_i - x_j| of sphere i with any other (0 if none)."""
    i = wp.tid()
    xi = x[i]
    worst = float(0.0)  # noqa: UP018 (as above)
    for j in wp.hash_grid_query(grid, xi, 2.0 * r):
        if j != i:
            worst = wp.max(worst, 2.0 * r - wp.length(xi - x[j]))
    out[i] = worst


class WarpSpheres:
    """N equal spheres of radius r [m] and mass m [kg] in the container lo..hi [m] (six walls of
    restitution wall_e and friction wall_mu), gravity g [m/s^2]; sphere contacts with restitution e,
    friction mu, `iterations` Jacobi position sweeps with over-relaxation `relaxation` and rest_speed
    [m/s], as collision/spheres.py."""

    def __init__(
        self,
        x: np.ndarray,
        v: np.ndarray,
        *,
        radius: float,
        mass: float,
        gravity,
        lo,
        hi,
        restitution: float,
        friction: float,
        wall_restitution: float,
        wall_friction: float,
        iterations: int,
        relaxation: float,
        rest_speed: float,
        device: str = "cpu",
    ):
        wp.init()
        self.device = device
        self.n = len(x)
        self.r = float(radius)
        self.mass = float(mass)
        self.inv_mass = 1.0 / self.mass
        self.force = wp.vec3(*(np.float32(self.mass) * np.asarray(gravity, np.float32)))
        self.lo = wp.vec3(*lo)
        self.hi = wp.vec3(*hi)
        self.e = float(restitution)
        self.mu = float(friction)
        self.wall_e = float(wall_restitution)
        self.wall_mu = float(wall_friction)
        self.iterations = int(iterations)
        self.relaxation = float(relaxation)
        self.rest_speed = float(rest_speed)
        self.cell = 2.0 * self.r  # as the engine: a touching pair is at most r_i + r_j apart
        dims = np.maximum(np.ceil((np.asarray(hi) - np.asarray(lo)) / self.cell).astype(int), 1)
        self.dims = tuple(int(d) for d in dims)
        self.grid = wp.HashGrid(*self.dims, device=device)
        f = np.float32
        self.x = wp.array(np.asarray(x, f), dtype=wp.vec3, device=device)
        self.v = wp.array(np.asarray(v, f), dtype=wp.vec3, device=device)
        self.xp = wp.zeros_like(self.x)
        self.vp = wp.zeros_like(self.v)
        self.xa = wp.zeros_like(self.x)
        self.xb = wp.zeros_like(self.x)
        self._worst = wp.zeros(self.n, dtype=float, device=device)

    def settings(self) -> dict:
        return {"hash_grid_dims": self.dims, "cell_size": self.cell, "device": self.device}

    def predict(self, h: float) -> None:
        wp.launch(
            predict,
            dim=self.n,
            inputs=[
                self.x, self.v, self.xp, self.vp, self.force, self.inv_mass, h, self.r, self.lo, self.hi,
                self.wall_e, self.wall_mu, self.rest_speed,
            ],
            device=self.device,
        )  # fmt: skip

    def build(self) -> None:
        self.grid.build(self.xp, self.cell)

    def solve(self, h: float) -> None:
        """Position sweeps from the prediction, then the velocity sweep; the state becomes the result."""
        w = self.inv_mass
        src = self.xp
        for k in range(self.iterations):
            dst = self.xa if k % 2 == 0 else self.xb
            wp.launch(
                project,
                dim=self.n,
                inputs=[self.grid.id, src, dst, self.r, w, 2.0 * self.r, self.relaxation, self.lo, self.hi],
                device=self.device,
            )
            src = dst
        wp.launch(
            velocities,
            dim=self.n,
            inputs=[
                self.grid.id, src, self.xp, self.vp, self.v, self.r, w, 2.0 * self.r, 1.0 / h, self.e,
                self.mu, self.rest_speed,
            ],
            device=self.device,
        )  # fmt: skip
        # The solved positions become the state; the state's old buffer (already read by `predict`)
        # takes their place in the ping-pong.
        old = self.x
        self.x = src
        if src is self.xa:
            self.xa = old
        else:
            self.xb = old

    def step(self, h: float) -> None:
        self.predict(h)
        self.build()
        self.solve(h)

    def sync(self) -> None:
        wp.synchronize_device(self.device)

    def positions(self) -> np.ndarray:
        return self.x.numpy()

    def velocities(self) -> np.ndarray:
        return self.v.numpy()

    def max_overlap(self) -> float:
        """Largest overlap [m] of any pair in the current state (grid rebuilt on x; not timed)."""
        self.grid.build(self.x, self.cell)
        wp.launch(
            overlaps, dim=self.n, inputs=[self.grid.id, self.x, self.r, self._worst], device=self.device
        )
        return float(self._worst.numpy().max())
