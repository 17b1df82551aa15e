"""Warp's `wp.Mesh` (closest point, ray cast) and `wp.Bvh` (box overlap) on the CPU: the peer of
benchmarks/bvh.py, over the same arrays. Warp runs a CPU kernel on one thread."""

import numpy as np
import warp as wp

wp.config.quiet = True


@wp.kernel
def _closest(mesh: wp.uint64, p: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    i = wp.tid()
    q = wp.mesh_query_point_no_sign(mesh, p[i], 1.0e30)
    out[i] = 1.0e30
    if q.result:
        out[i] = wp.length(p[i] - wp.mesh_eval_position(mesh, q.face, q.u, q.v))


@wp.kernel
def _rays(
    mesh: wp.uint64, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)
):
    i = wp.tid()
    q = wp.mesh_query_ray(mesh, o[i], d[i], 1.0e30)
    out[i] = 1.0e30
    if q.result:
        out[i] = q.t


@wp.kernel
def _boxes(
    bvh: wp.uint64, lo: wp.array(dtype=wp.vec3), hi: wp.array(dtype=wp.vec3), out: wp.array(dtype=int)
):
    i = wp.tid()
    q = wp.bvh_query_aabb(bvh, lo[i], hi[i])
    k = wp.int32(0)
    c = wp.int32(0)
    while wp.bvh_query_next(q, k):
        c += 1
    out[i] = c


class WarpMesh:
    """v (n, 3) f32 vertices, f (m, 3) faces; queries p, o, d, qlo, qhi (q, 3) as in bvh.py."""

    def __init__(self, v, f, p, o, d, qlo, qhi):
        wp.init()
        a = lambda x: wp.array(np.asarray(x, np.float32), dtype=wp.vec3, device="cpu")  # noqa: E731
        self.points, self.indices = a(v), wp.array(np.asarray(f, np.int32).ravel(), dtype=int, device="cpu")
        t = np.asarray(v)[np.asarray(f)]
        self.lo, self.hi = a(t.min(1)), a(t.max(1))
        self.p, self.o, self.d, self.qlo, self.qhi = a(p), a(o), a(d), a(qlo), a(qhi)
        self.q = len(p)
        self.dist, self.t = wp.zeros(self.q, dtype=float), wp.zeros(self.q, dtype=float)
        self.count = wp.zeros(self.q, dtype=int)
        self.build()

    def build(self):
        self.mesh = wp.Mesh(points=self.points, indices=self.indices)
        self.bvh = wp.Bvh(self.lo, self.hi)

    def refit(self):
        self.mesh.refit()
        self.bvh.refit()

    def closest(self):
        wp.launch(_closest, dim=self.q, inputs=[self.mesh.id, self.p, self.dist], device="cpu")

    def rays(self):
        wp.launch(_rays, dim=self.q, inputs=[self.mesh.id, self.o, self.d, self.t], device="cpu")

    def boxes(self):
        wp.launch(_boxes, dim=self.q, inputs=[self.bvh.id, self.qlo, self.qhi, self.count], device="cpu")

    @staticmethod
    def sync() -> float:
        wp.synchronize()
        import time

        return time.perf_counter()
