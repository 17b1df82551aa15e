"""Blobby field on a grid: psi(p) = sum_i exp(-|p - p_i|^2 / sigma^2), Blinn 1982, "A Generalization of
Algebraic Surface Drawing" (ACM TOG 1(3)), the summed Gaussian density D = sum_i b_i exp(-a_i r_i^2) with
b_i = 1 and a_i = 1 / sigma^2.

Each particle contributes only to nodes within the cutoff radius r_c = cutoff * sigma. Truncation error:
every omitted particle lies at distance >= r_c from the node, so it would have added less than
exp(-cutoff^2); hence 0 <= psi_exact(p) - psi(p) < N_omitted(p) * exp(-cutoff^2) <= N exp(-cutoff^2).
The default cutoff 3 gives exp(-9) = 1.2e-4 per omitted particle, 1/800 of iso = 0.1 and 1/4000 of
iso = 0.5. Cutoff 2 would allow 1.8e-2 per omitted particle (six of them add up to iso = 0.1); cutoff 4
costs (4/3)^3 = 2.4x the pair evaluations for an error (1e-7) far below what a grid resolves.

Only nodes near particles are visited: each particle flags the blocks of BLOCK^3 nodes its cutoff box
touches (integer writes), the flagged blocks are listed in block order, and only their nodes are
evaluated; every other node is psi = 0 exactly, which is what the truncated sum gives there. The flagged
box reaches one node further down on each axis than the cutoff box, so every grid edge and every grid
cell with a nonzero corner has its lower corner in a flagged block (what the isosurface extractors rely
on). The outermost layer of nodes is held at psi = 0, so the isosurface is closed even where blobs leave
the grid (they are cut and capped there): give bounds a margin of one blob radius to avoid that.

Gather by block: each flagged block queries the neighbour structure once, around its centre, and adds
the blobs of the particles found to its own nodes (only its thread writes them: no float atomics, and the
sum order is the structure's fixed order, so the result is reproducible). The Gaussian factorises over
the axes, so 3 x BLOCK exponentials per particle and block serve its BLOCK^3 nodes. The study in
benchmarks/results/blobs_study.md measured it 3x faster than a gather per node (each node querying its
particles, one exponential per pair): 8.9 against 27 ms at 128^3, 34 against 102 ms at 256^3 for a
1000-particle jet. Since then: psi is stored block by block (a block's BLOCK^3 values contiguous), so a
block's row along z is BLOCK adjacent values that the splat adds as one straight run (zeros outside the
cutoff sphere) and two threads never share a cache line; each particle's Gaussian factors along the axes
are computed once (its axis profiles) and read by every block it reaches; and on the CPU the workers
(workers.py) claim the blocks one at a time. A 16,000-particle surge's field: 52 ms before, 16-20 ms
(2 cores, timing `evaluate` alone; benchmarks/fluid_surfacing.py times the whole surface).
"""

import math

import numpy as np
import taichi as ti

from .. import validate, workers
from ..capacity import plain
from ..collision.neighbors import make_neighbor_search
from ..errors import ParameterError
from ..runtime import data_oriented, np_float
from .blocks import BLOCK, BLOCK3
from .isosurface import DEFAULT_METHOD, BlobMesh, extract

DEFAULT_CUTOFF = 3.0  # in units of sigma; see the module docstring
# None: the CPU's workers share the gather's blocks out where they run (workers.available()); True / False
# force it on / off (tests compare the two: the same bits).
WORKER_GATHER = None


@data_oriented
class BlobField:
    """psi on a grid of nodes lo + spacing * (i, j, k) spanning `bounds`.

    capacity: most particles per evaluation (each keeps its axis profiles, 6 x profile_width floats,
    profile_width = floor(2 r_c / spacing) + 2: 12 for a liquid's blobs); sigma [m]: blob width (one blob
    alone has psi = exp(-r^2 / sigma^2)); bounds: (lo, hi) [m] of the grid; resolution: nodes along the
    longest side of bounds (the others get the same spacing); cutoff: r_c / sigma (default 3: truncation
    error below exp(-9) = 1.2e-4 per particle); neighbor_method: see `make_neighbor_search` (default "grid":
    every visited block and every mesh vertex is a query, many more than particles, so the grid pays for its
    build at any particle count, unlike particle-particle searches).
    Fields: psi, the node values flat, block by block over the grid padded to whole blocks
    (`value(node)` reads one from Taichi scope, `values()` gives the (nx, ny, nz) array).
    """

    def __init__(
        self,
        *,
        capacity: int,
        sigma: float,
        bounds,
        resolution: int = 128,
        cutoff: float = DEFAULT_CUTOFF,
        neighbor_method: str = "grid",
        make=plain,
    ):
        self._make = make  # the allocator: new fields, or a model's pool under capacity buckets
        self.capacity = validate.count("capacity", capacity, 1)
        self.sigma = validate.positive("sigma", sigma)
        self.cutoff = validate.positive("cutoff", cutoff)
        resolution = validate.count("resolution", resolution, 3)
        lo = np.asarray(validate.vec3("bounds lo", bounds[0]))
        hi = np.asarray(validate.vec3("bounds hi", bounds[1]))
        if np.any(hi <= lo):
            raise ParameterError(
                f"bounds must have lo < hi on every axis, got lo={lo.tolist()}, hi={hi.tolist()}"
            )
        self.spacing = float((hi - lo).max() / (resolution - 1))
        # At least 3 nodes per axis: the two outer layers are the zero pad, so a flat box still has an inside.
        self.dims = tuple(
            int(max(3, np.ceil((b - a) / self.spacing - 1e-9) + 1)) for a, b in zip(lo, hi, strict=True)
        )
        self.lo = tuple(float(c) for c in lo)
        self.hi = tuple(float(a + self.spacing * (n - 1)) for a, n in zip(lo, self.dims, strict=True))
        self.truncation_bound_per_particle = float(np.exp(-(self.cutoff**2)))
        self.block_dims = tuple((n + BLOCK - 1) // BLOCK for n in self.dims)
        self.block_count = int(np.prod(self.block_dims))
        # psi is stored block by block over whole blocks, so a block's row of BLOCK nodes along z is one
        # straight run of memory, and a block's values share no cache line with another's (see _splat).
        self.padded_dims = tuple(BLOCK * n for n in self.block_dims)
        # A particle's blob along one axis reaches at most `profile_width` nodes, from its first_node.
        self.cutoff_radius = self.cutoff * self.sigma
        self.profile_width = int(np.floor(2.0 * self.cutoff_radius / self.spacing)) + 2
        fb = np.dtype(np_float()).itemsize
        # psi and the isosurface's int32 edge index per node; per particle: the staging field and buffer,
        # and the axis profiles (squared distance and Gaussian factor per node) with their first nodes.
        nodes = math.prod(self.padded_dims)
        validate.capacity(f"resolution {resolution}", nodes, bytes_each=fb + 4, unit="grid nodes")
        per_particle = (6 + 6 * self.profile_width) * fb + 12
        validate.capacity("capacity", self.capacity, bytes_each=per_particle, unit="particles")

        self.psi = make(self, "blob_psi", float, nodes)
        self.block_flag = make(self, "blob_block_flag", ti.i32, self.block_count)
        # block -> position in active_block, or -1
        self.block_slot = make(self, "blob_block_slot", ti.i32, self.block_count)
        self.active_block = make(self, "blob_active_block", ti.i32, self.block_count)  # flagged, in order
        self.active_count = make(self, "blob_active_count", ti.i32, ())
        # lowest and highest flagged block coordinates
        self.active_box = make(self, "blob_active_box", ti.i32, 2, (3,))
        # The gather's next unclaimed block, where the CPU's workers share the blocks out (_gather_blocks).
        self.block_claim = make(self, "blob_block_claim", ti.i32, 1)
        # Per neighbour slot k and axis c: the first node the particle's blob reaches (first_node[k][c]),
        # and for the profile_width nodes from it the squared distance along c and exp(-that / sigma^2).
        width = self.profile_width
        self.first_node = make(self, "blob_first_node", ti.i32, self.capacity, (3,))
        self.axis_q = make(self, "blob_axis_q", float, (self.capacity, 3, width))
        self.axis_e = make(self, "blob_axis_e", float, (self.capacity, 3, width))
        self._claimed = workers.available() if WORKER_GATHER is None else WORKER_GATHER
        self._worker_items = workers.loop_size()
        self._reset()  # a pooled field (capacity buckets) holds what its last owner left
        # A block's query around its centre reaches every particle within r_c of any of its nodes.
        self.block_radius = self.cutoff_radius + 0.5 * (BLOCK - 1) * self.spacing * float(np.sqrt(3.0))
        r = self.block_radius
        self.neighbors = make_neighbor_search(
            self.capacity,
            r,
            domain=(tuple(lo - r), tuple(np.asarray(self.hi) + r)),
            method=neighbor_method,
            make=make,
        )
        # The surface's vertices query the particles within the cutoff only: on the grid, cells of half
        # the cutoff and 5^3 of them scanned (for_each_near), against 27 (block radius)^3 in the blocks'
        # grid (the normals of a 54,000-particle liquid's surface took 68 ms with the blocks' grid, 16
        # with cutoff-sized cells, 8 with half-sized ones).
        rc = self.cutoff_radius
        box = (tuple(lo - rc), tuple(np.asarray(self.hi) + rc))
        self._vertex_query_near = neighbor_method == "grid"
        self.vertex_neighbors = make_neighbor_search(
            self.capacity, 0.5 * rc if self._vertex_query_near else rc, domain=box, method=neighbor_method,
            make=make,
        )  # fmt: skip
        self._x = None  # staging field for NumPy input, allocated on first use
        self._inv_s2 = 1.0 / self.sigma**2
        v3i = ti.types.vector(3, ti.i32)
        self._Block = ti.types.struct(base=v3i, lo=v3i, hi=v3i)
        self._Grad = ti.types.struct(p=ti.types.vector(3, float), g=ti.types.vector(3, float))

    def describe(self) -> str:
        """One line for summaries: grid nodes, spacing [m], sigma [m], cutoff and truncation bound."""
        d = "x".join(map(str, self.dims))
        return (
            f"blob field on {d} nodes, spacing {self.spacing:.4g} m, sigma {self.sigma:.4g} m, cutoff "
            f"{self.cutoff:g} sigma (truncation < {self.truncation_bound_per_particle:.2g} per particle), "
            f"neighbours: {self.neighbors.describe()}"
        )

    def settings(self) -> dict:
        """The field's settings for run.json."""
        return {
            "sigma": self.sigma,
            "cutoff": self.cutoff,
            "spacing": self.spacing,
            "dims": self.dims,
            "lo": self.lo,
            "hi": self.hi,
            "block": BLOCK,
            "neighbors": self.neighbors.settings(),
        }

    # ----------------------------------------------------------------------------------------- evaluation

    def evaluate(self, x, count: int | None = None, death=None, t: float = 0.0) -> None:
        """psi at every node from particles [0, count) of x: a Vector field (N,3) [m] (with an optional
        `death` field [s]: only particles with death > t count) or a NumPy array (N,3) [m]."""
        if isinstance(x, np.ndarray) or isinstance(x, (list, tuple)):
            pts = validate.finite_array("x", np.atleast_2d(np.asarray(x, dtype=np.float64)), (3,))
            if len(pts) > self.capacity:
                raise ParameterError(f"x must hold at most capacity={self.capacity} points, got {len(pts)}")
            if self._x is None:
                self._x = self._make(self, "blob_staging_x", float, self.capacity, (3,))
            buf = np.zeros((self.capacity, 3), dtype=np_float())
            buf[: len(pts)] = pts
            self._x.from_numpy(buf)
            x, count, death = self._x, len(pts), None
        n = self.neighbors.checked_count(x, count)
        self.vertex_neighbors.checked_count(x, count)
        self._evaluate(x, n, death, float(t), death is not None)  # death None: not read

    @ti.func
    def node_position(self, i, j, k):
        """Position [m] of grid node (i, j, k)."""
        return ti.Vector(self.lo, dt=float) + self.spacing * ti.Vector([i, j, k], dt=float)

    @ti.func
    def block_coords(self, b):
        """Integer coordinates of block b among the blocks (z fastest)."""
        bz = b % self.block_dims[2]
        by = (b // self.block_dims[2]) % self.block_dims[1]
        return ti.Vector([b // (self.block_dims[2] * self.block_dims[1]), by, bz])

    @ti.func
    def block_node(self, b, local):
        """Grid coordinates of node `local` (0 ... BLOCK^3 - 1, z fastest) of block b."""
        q = ti.Vector([local // (BLOCK * BLOCK), (local // BLOCK) % BLOCK, local % BLOCK])
        return self.block_coords(b) * BLOCK + q

    @ti.func
    def block_of(self, node):
        """Index of the block holding grid node `node` (integer coordinates)."""
        c = node // BLOCK
        return (c[0] * self.block_dims[1] + c[1]) * self.block_dims[2] + c[2]

    @ti.func
    def node_index(self, node):
        """Index in `psi` of the integer node coordinates `node` (inside the padded grid): block by block
        (each block's BLOCK^3 values contiguous, z fastest), so two threads working on neighbouring
        blocks never write the same cache line."""
        q = node % BLOCK
        return self.row_index(self.block_of(node), q[0], q[1]) + q[2]

    @ti.func
    def row_index(self, b, i, j):
        """Index in `psi` of block b's node (i, j, 0) (coordinates within the block): the first of the
        row of BLOCK values along z."""
        return b * BLOCK3 + (i * BLOCK + j) * BLOCK

    @ti.func
    def value(self, node):
        """psi at the integer node coordinates `node` (inside the grid)."""
        return self.psi[self.node_index(node)]

    @ti.func
    def inside_grid(self, node):
        """Whether the integer node coordinates lie in the grid."""
        return (node >= 0).all() and (node < ti.Vector(self.dims)).all()

    @ti.func
    def _profiles(self):
        """Each particle's axis profiles (call at a kernel's top level, after the neighbours' build): the
        Gaussian factorises over the axes, so 3 x profile_width exponentials per particle serve every
        block it reaches (computed per particle and block, the exponentials took about half the gather:
        24 per pair, ~10 blocks per particle)."""
        lo = ti.Vector(self.lo, dt=float)
        for k in range(self.neighbors.size[None]):
            p = self.neighbors.sorted_x[k]
            # Clamped before the cast: a particle far outside the grid must not overflow i32 (it reaches
            # no node then, and its profile is never read).
            first = ti.floor((p - self.cutoff_radius - lo) / self.spacing)
            f = ti.cast(ti.min(ti.max(first, -2.0 * self.profile_width), 1.0e9), ti.i32)
            self.first_node[k] = f
            for c in ti.static(range(3)):
                for j in range(self.profile_width):
                    t = lo[c] + (f[c] + j) * self.spacing - p[c]
                    self.axis_q[k, c, j] = t * t
                    self.axis_e[k, c, j] = ti.exp(-t * t * self._inv_s2)

    @ti.func
    def _splat(self, b, k, ret: ti.template()):
        """Add particle k's blob to the nodes [ret.lo, ret.hi) of block b (first node ret.base) that lie
        within the cutoff radius: exp(-|d|^2/s^2) = exp(-dx^2/s^2) exp(-dy^2/s^2) exp(-dz^2/s^2), the
        factors read from the particle's axis profiles.

        Along z, every row adds to all BLOCK of its nodes, zero where the node is outside the sphere or
        the block's range: a fixed run of adjacent nodes compiles to straight-line code that the CPU's
        vector units take (a loop over the sphere's own nodes took 2.6x as long, measured on a 13,200
        particle lattice), and adding 0 leaves a non-negative sum's bits as they are."""
        width = self.profile_width
        start = ret.base - self.first_node[k]  # the block's first node in the particle's profiles
        # Only the block's nodes in the particle's profile: most particles a block's query finds touch
        # a corner of it, and some none.
        lo = ti.max(ret.lo, -start)
        hi = ti.min(ret.hi, width - start)
        if (lo < hi).all():
            rc2 = self.cutoff_radius * self.cutoff_radius
            q = ti.Matrix.zero(float, 3, BLOCK)  # squared distance along each axis, node by node
            e = ti.Matrix.zero(float, 3, BLOCK)
            for c, a in ti.static(ti.ndrange(3, BLOCK)):
                q[c, a] = rc2  # outside the profile or the block's range: fails the sphere test below
                if lo[c] <= a < hi[c]:
                    q[c, a] = self.axis_q[k, c, start[c] + a]
                    e[c, a] = self.axis_e[k, c, start[c] + a]
            for i in range(lo[0], hi[0]):
                for j in range(lo[1], hi[1]):
                    qij = q[0, i] + q[1, j]
                    if qij < rc2:
                        eij = e[0, i] * e[1, j]
                        row = self.row_index(b, i, j)
                        for m in ti.static(range(BLOCK)):
                            w = eij * e[2, m]
                            if qij + q[2, m] >= rc2:
                                w = 0.0
                            # A plain add, not `+=` (which Taichi makes atomic): only this block's thread
                            # writes these nodes.
                            self.psi[row + m] = self.psi[row + m] + w

    # The two neighbour structures' builds and the evaluation in one launch: three kernels to compile
    # or load before (the builds' for each structure).
    @ti.kernel
    def _evaluate(self, x: ti.template(), n: ti.i32, death: ti.template(), t: float, alive: ti.template()):
        self.neighbors.build_pass(x, n, death, t, alive)
        self.vertex_neighbors.build_pass(x, n, death, t, alive)
        self._profiles()
        self._activate_blocks()
        self._gather_blocks()

    @ti.kernel
    def _reset(self):
        """An empty field: psi 0 everywhere, no block flagged or listed (the state `_activate_blocks`
        clears incrementally from)."""
        for node in self.psi:
            self.psi[node] = 0.0
        for b in range(self.block_count):
            self.block_flag[b] = 0
            self.block_slot[b] = -1
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.active_count[None] = 0

    @ti.func
    def _activate_blocks(self):
        """Clear the previous evaluation's blocks, flag and list this one's (call at a kernel's top level:
        its loops run as passes of that launch)."""
        dims = ti.Vector(self.dims)
        # Clear what the previous evaluation wrote (its blocks only, not the whole grid).
        rows = BLOCK * BLOCK
        for j in range(self.active_count[None] * rows):
            row = self.row_index(self.active_block[j // rows], (j % rows) // BLOCK, j % BLOCK)
            for m in ti.static(range(BLOCK)):  # a row along z: BLOCK adjacent values
                self.psi[row + m] = 0.0
        for s in range(self.active_count[None]):
            b = self.active_block[s]
            self.block_flag[b] = 0
            self.block_slot[b] = -1
        # Flag the blocks each particle's cutoff box touches (all write the same 1: order does not matter).
        lo = ti.Vector(self.lo, dt=float)
        for k in range(self.neighbors.size[None]):
            p = self.neighbors.sorted_x[k]
            # Clamp before the cast: a particle far outside the grid must not overflow i32.
            top = ti.cast(dims, float)
            a0 = ti.ceil((p - self.cutoff_radius - lo) / self.spacing) - 1.0
            c0 = ti.floor((p + self.cutoff_radius - lo) / self.spacing)
            a = ti.cast(ti.min(ti.max(a0, 0.0), top), ti.i32)
            c = ti.cast(ti.min(ti.max(c0, -1.0), top - 1.0), ti.i32)
            if (a <= c).all():
                a //= BLOCK
                c //= BLOCK
                for bx, by, bz in ti.ndrange((a[0], c[0] + 1), (a[1], c[1] + 1), (a[2], c[2] + 1)):
                    self.block_flag[(bx * self.block_dims[1] + by) * self.block_dims[2] + bz] = 1
        # List flagged blocks in block order (serial: the list, and so every output order, is reproducible).
        ti.loop_config(serialize=True)
        for _ in range(1):
            n = 0
            box_lo = ti.Vector(self.block_dims)
            box_hi = ti.Vector([-1, -1, -1])
            for b in range(self.block_count):
                if self.block_flag[b]:
                    self.active_block[n] = b
                    self.block_slot[b] = n
                    bc = self.block_coords(b)
                    box_lo = ti.min(box_lo, bc)
                    box_hi = ti.max(box_hi, bc)
                    n += 1
            self.active_count[None] = n
            self.active_box[0] = box_lo
            self.active_box[1] = box_hi

    @ti.func
    def for_each_block(self, body: ti.template()):
        """body(s) for every flagged block s = 0 ... active_count - 1 (call at a kernel's top level: its
        loops are passes of that launch). On the CPU the workers claim blocks one by one: Taichi 1.7
        hands a CPU loop out in pieces of at least 512 iterations, so a loop over a few hundred heavy
        blocks ran on one thread, and over 766 (a 16,000-particle surge) split 512 / 254. A block's
        results must not depend on who runs it."""
        if ti.static(self._claimed):
            ti.loop_config(serialize=True)
            for _ in range(1):
                self.block_claim[0] = 0
            for task in range(self._worker_items):
                if workers.is_worker(task):
                    s = workers.claim(self.block_claim, 0)
                    while s < self.active_count[None]:
                        body(s)
                        s = workers.claim(self.block_claim, 0)
        else:
            for s in range(self.active_count[None]):
                body(s)

    @ti.func
    def _gather_blocks(self):
        self.for_each_block(self._gather_block)

    @ti.func
    def _gather_block(self, s):
        """psi at the nodes of the s-th flagged block from the particles near it."""
        b = self.active_block[s]
        base = self.block_coords(b) * BLOCK
        # Interior nodes only: the outer layer stays 0, the zero pad that closes the isosurface.
        top = ti.Vector(self.dims) - 1
        acc = self._Block(base=base, lo=ti.max(1 - base, 0), hi=ti.min(top - base, BLOCK))
        centre = self.node_position(base[0], base[1], base[2]) + 0.5 * (BLOCK - 1) * self.spacing
        self.neighbors.for_each_neighbor(b, centre, self.block_radius, self._splat, acc)

    def isosurface(self, iso: float = 0.5, *, method=None, normals: bool = True) -> BlobMesh:
        """The closed surface psi = iso of the last evaluation as a BlobMesh (vertices [m], triangles,
        outward normals, or None with normals=False). One blob alone gives a sphere of radius
        sigma * sqrt(ln(1 / iso)). method: "open3d" (default), "skimage" or "taichi" (see isosurface.py)."""
        return extract(self, iso, DEFAULT_METHOD if method is None else method, normals)

    # --------------------------------------------------------------------------------------- read back

    @ti.func
    def _add_gradient(self, i, k, ret: ti.template()):
        self._add_gradient_at(i, k, ret.p - self.vertex_neighbors.sorted_x[k], ret)

    @ti.func
    def _add_gradient_at(self, i, k, d, ret: ti.template()):
        ret.g += d * ti.exp(-d.norm_sqr() * self._inv_s2)

    @ti.kernel
    def _outward_normals(self, points: ti.types.ndarray(), out: ti.types.ndarray()):
        for v in range(points.shape[0]):
            p = ti.Vector([points[v, 0], points[v, 1], points[v, 2]], dt=float)
            acc = self._Grad(p=p, g=ti.Vector.zero(float, 3))
            if ti.static(self._vertex_query_near):
                self.vertex_neighbors.for_each_near(v, p, self.cutoff_radius, self._add_gradient_at, acc)
            else:
                self.vertex_neighbors.for_each_neighbor(v, p, self.cutoff_radius, self._add_gradient, acc)
            # -grad psi = (2 / sigma^2) sum (p - p_i) exp(...): the positive factor drops out on normalising.
            length = acc.g.norm()
            n = ti.Vector.zero(float, 3)
            if length > 1e-300:  # zero only at a critical point of psi; avoid 0/0 = NaN
                n = acc.g / length
            for c in ti.static(range(3)):
                out[v, c] = n[c]

    def outward_normals(self, points) -> np.ndarray:
        """(M,3) unit vectors -grad psi / |grad psi| at `points` (M,3) [m], from the analytic gradient
        grad psi = sum_i -2 (p - p_i) / sigma^2 exp(-|p - p_i|^2 / sigma^2) of the last evaluation
        (zero where the gradient vanishes)."""
        pts = np.ascontiguousarray(validate.finite_array("points", points, (3,)))
        out = np.zeros_like(pts)
        if len(pts):
            self._outward_normals(pts, out)
        return out

    # The flagged blocks' rows into a zeroed box (every other node is 0): a row of BLOCK values per
    # iteration, instead of a node-by-node walk of the whole box (8 ms for a 54,000-particle surge's
    # 2.5 million nodes).
    @ti.kernel
    def _copy_box(self, out: ti.types.ndarray(), o0: ti.i32, o1: ti.i32, o2: ti.i32):
        rows = BLOCK * BLOCK
        for r in range(self.active_count[None] * rows):
            b = self.active_block[r // rows]
            node = self.block_coords(b) * BLOCK + ti.Vector([(r % rows) // BLOCK, r % BLOCK, 0])
            i = node[0] - o0
            j = node[1] - o1
            if 0 <= i < out.shape[0] and 0 <= j < out.shape[1]:
                src = self.row_index(b, (r % rows) // BLOCK, r % BLOCK)
                for m in ti.static(range(BLOCK)):
                    k = node[2] + m - o2
                    if 0 <= k < out.shape[2]:
                        out[i, j, k] = self.psi[src + m]

    def active_volume(self) -> tuple[np.ndarray, np.ndarray]:
        """(origin (3,) int node index, psi (a, b, c) copy) of the smallest box of nodes holding every
        nonzero node plus one zero node on each side (or the grid's zero outer layer): what a library
        isosurface extractor needs to see. An empty box (0, 0, 0) when no particle touched the grid."""
        if int(self.active_count[None]) == 0:
            return np.zeros(3, dtype=np.int64), np.zeros((0, 0, 0), dtype=np_float())
        box = self.active_box.to_numpy()
        lo = np.maximum(box[0] * BLOCK - 1, 0)
        hi = np.minimum((box[1] + 1) * BLOCK, np.asarray(self.dims) - 1)  # inclusive
        out = np.zeros(tuple(int(n) for n in hi - lo + 1), dtype=np_float())
        self._copy_box(out, int(lo[0]), int(lo[1]), int(lo[2]))
        return lo.astype(np.int64), out

    def values(self) -> np.ndarray:
        """psi at every node, (nx, ny, nz)."""
        blocks = self.psi.to_numpy().reshape(self.block_dims + (BLOCK,) * 3)
        grid = blocks.transpose(0, 3, 1, 4, 2, 5).reshape(self.padded_dims)
        nx, ny, nz = self.dims
        return np.ascontiguousarray(grid[:nx, :ny, :nz])

    def node_positions(self) -> np.ndarray:
        """(nx, ny, nz, 3) node positions [m]."""
        axes = [self.lo[a] + self.spacing * np.arange(self.dims[a]) for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    @property
    def active_block_count(self) -> int:
        """Blocks of BLOCK^3 nodes evaluated by the last `evaluate` (the rest of the grid is 0)."""
        return int(self.active_count[None])
