"""The rigid kind's model part: per body its shape, mass, inertia and the frame its dynamics runs in
(centre of mass and principal axes), as NumPy arrays for users and as fields for kernels."""

import numpy as np
import taichi as ti

from ... import bulk, capacity
from ...errors import ParameterError
from ...runtime import data_oriented, np_float, serial_loops


@data_oriented
class RigidModel:
    """Model methods of the rigid kind (the Model inherits them).

    rigid_count; rigid_mass (B,) [kg]; rigid_inertia (B,3,3) [kg m^2] about the centre of mass, in the
    body's (shape's) frame; rigid_com (B,3) [m] the centre of mass in that frame; rigid_kinematic (B,)
    bool; rigid_shapes: the shapes. Fields for kernels (None without bodies): rigid_inv_mass (B,)
    [1/kg] and rigid_inv_moments (B,3) [1/(kg m^2)] in the principal frame (0 for kinematic bodies)."""

    def _init_rigid(self, *, bodies, contacts=None) -> None:
        b = len(bodies)
        self.rigid_count = b
        self.rigid_shapes = tuple(x["shape"] for x in bodies)
        stack = lambda k, shape: np.array([x[k] for x in bodies], dtype=np.float64).reshape((b, *shape))
        self.rigid_mass = stack("mass", ())
        self.rigid_inertia = stack("inertia", (3, 3))
        self.rigid_com = stack("com", (3,))
        self.rigid_principal = stack("principal", (4,))  # principal frame -> shape frame
        self.rigid_moments = stack("moments", (3,))
        self.rigid_kinematic = np.array([x["kinematic"] for x in bodies], dtype=bool)
        # Keyframed bodies: (index, RigidMotion, rest com (3,), rest orientation (4,)) each.
        self.rigid_motions = tuple(
            (k, x["motion"], tuple(x["x"]), tuple(x["q"]))
            for k, x in enumerate(bodies)
            if x["motion"] is not None
        )
        for _k, motion, _x, _q in self.rigid_motions:
            motion.allocate()
        self._rigid_start = {k: stack(k, (n,)) for k, n in (("x", 3), ("q", 4), ("v", 3), ("w", 3))}
        for a in (self.rigid_mass, self.rigid_inertia, self.rigid_com, self.rigid_kinematic):
            a.setflags(write=False)
        # The options the Stepper builds the bodies' solver from (solvers.SOLVERS): none to give.
        self.rigid_dynamics = dict(contacts=contacts) if b else None
        self.rigid_capacity = capacity.bucket(b) if self.size_buckets else b
        # Few bodies: their loops run serially (a parallel loop's start costs more than their work here).
        self.rigid_serial = serial_loops(self.rigid_capacity)
        self.rigid_live = self.rigid_inv_mass = self.rigid_inv_moments = None
        self.rigid_reach = 0.0
        self.rigid_round_and_polytopes = False
        self.rigid_has_round = self.rigid_parted = self.rigid_prisms = False
        if not b:
            return
        if self.size_buckets:
            self.rigid_live = self.new_field(self, "rigid_live", ti.i32, ())
            self.rigid_live[None] = b
        dynamic = ~self.rigid_kinematic
        self.rigid_inv_mass = self.rigid_array(self, "rigid_inv_mass")
        self.rigid_inv_moments = self.rigid_array(self, "rigid_inv_moments", dims=(3,))
        inv = np.where(dynamic[:, None], 1.0 / self.rigid_moments, 0.0)
        fills = [  # every field filled in one launch (bulk.py: from_numpy is a kernel per field)
            (self.rigid_inv_mass, self.rigid_padded(np.where(dynamic, 1.0 / self.rigid_mass, 0.0))),
            (self.rigid_inv_moments, self.rigid_padded(inv)),
        ]
        self._init_rigid_geometry(bodies, fills)
        bulk.fill(fills)

    def rigid_array(self, owner, role: str, dtype=float, dims: tuple = ()):
        """A field of rigid_capacity rows with elements of `dims`, for `owner` (pooled under buckets)."""
        return self.new_field(owner, role, dtype, (self.rigid_capacity,), dims)

    def rigid_padded(self, a) -> np.ndarray:
        """`a` (rigid_count rows) with zero rows up to rigid_capacity, as the float fields' dtype."""
        return capacity.padded(a, self.rigid_capacity, np_float())

    @ti.func
    def live_rigid(self):
        """Bodies the kernels loop over (a 0-d field under buckets, else a compile-time constant)."""
        if ti.static(self.size_buckets):
            return self.rigid_live[None]
        else:
            return self.rigid_count

    def _init_rigid_geometry(self, bodies, fills: list) -> None:
        """The contact geometry of every body (geometry.py) as fields. Per body: its convex parts (geoms)
        rigid_geom_start[i] to rigid_geom_start[i + 1], rigid_bound (sphere radius about the com) and
        rigid_half (OBB half extents along the principal axes), rigid_friction, rigid_restitution and
        rigid_damping (linear, angular [1/s]). Per geom g: its placement in the body's principal
        frame geom_offset and geom_rot, and in its own frame its points (geom_points from
        geom_point_start[g] to geom_point_start[g + 1], with geom_point_radius), its signed distance
        (geom_round: a core segment geom_seg0-geom_seg1 of radius geom_radius; else the planes geom_planes
        from geom_plane_start[g], and its edges geom_edges (ends and the normals of the two faces they
        join) from geom_edge_start[g]; geom_box: a box of half extents geom_half; geom_prism: a mesh's
        triangle as a prism (its surface's normal along its frame's z, planes top, bottom, then the sides
        of edges 0-1, 1-2, 2-0), geom_active: bit k set where its edge k is an active edge), and
        geom_bound (sphere radius about its origin); per point geom_contact_point (1 where it is a
        contact point, tested against other bodies and the colliders: a mesh's surface vertices once
        each, in the first prism that has it, and no prism's inner corner). Per body its tree of
        oriented boxes over its geoms (obb_tree.py), root node rigid_node_start[i]: per node its box
        node_offset and node_rot (principal frame), node_half, node_bound (sphere about node_offset),
        node_child (its children, -1 for a leaf), node_geom (a leaf's geom). Each field is added with
        its values to `fills`, for the caller to write in one launch."""
        geo = [g for x in bodies for g in x["geometry"]["geoms"]]
        points = np.concatenate([g["points"] for g in geo])
        planes = np.concatenate([g["planes"] for g in geo])
        edges = np.concatenate([g["edges"] for g in geo])
        if len(points) > self.MAX_RIGID_POINTS:
            raise ParameterError(
                f"rigid bodies: {len(points)} contact points (mesh vertices) exceed {self.MAX_RIGID_POINTS}"
            )
        self.rigid_point_count = len(points)
        self.rigid_edge_count = len(edges)
        self.rigid_geom_count = len(geo)
        rows = capacity.bucket if self.size_buckets else (lambda n: max(n, 1))
        starts = lambda key: np.concatenate([[0], np.cumsum([len(g[key]) for g in geo])]).astype(np.int32)

        def put(name, values, shape, dtype=float, dims=()):
            f = self.new_field(self, name, dtype, shape, dims)
            a = np.zeros((shape, *dims))
            a[: len(values)] = values
            fills.append((f, a.astype(np.int32 if dtype == ti.i32 else np_float())))
            setattr(self, name, f)

        cap = self.rigid_capacity
        geom_starts = np.concatenate([[0], np.cumsum([len(x["geometry"]["geoms"]) for x in bodies])])
        put("rigid_geom_start", geom_starts.astype(np.int32), cap + 1, ti.i32)
        put("rigid_bound", [x["geometry"]["bound"] for x in bodies], cap)
        put("rigid_half", [x["geometry"]["half_extents"] for x in bodies], cap, dims=(3,))
        put("rigid_friction", [x["friction"] for x in bodies], cap)
        put("rigid_damping", [x["damping"] for x in bodies], cap, dims=(2,))  # linear, angular [1/s]
        put("rigid_restitution", [x["restitution"] for x in bodies], cap)
        geoms = rows(len(geo))
        put("geom_offset", [g["offset"] for g in geo], geoms, dims=(3,))
        put("geom_rot", [g["rotation"] for g in geo], geoms, dims=(3, 3))
        put("geom_point_start", starts("points"), geoms + 1, ti.i32)
        put("geom_points", points, rows(len(points)), dims=(3,))
        put("geom_point_radius", np.concatenate([g["point_radius"] for g in geo]), rows(len(points)))
        owned = np.concatenate([g["contact_points"] for g in geo]).astype(np.int32)
        put("geom_contact_point", owned, rows(len(points)), ti.i32)
        put("geom_plane_start", starts("planes"), geoms + 1, ti.i32)
        put("geom_planes", planes, rows(len(planes)), dims=(4,))
        put("geom_edge_start", starts("edges"), geoms + 1, ti.i32)
        put("geom_edges", edges, rows(len(edges)), dims=(4, 3))
        put("geom_round", [int(g["round"]) for g in geo], geoms, ti.i32)
        put("geom_box", [int(g["box"]) for g in geo], geoms, ti.i32)
        put("geom_prism", [int(g["prism"]) for g in geo], geoms, ti.i32)
        put("geom_active", [g["active_edges"] for g in geo], geoms, ti.i32)
        put("geom_half", [g["half_extents"] for g in geo], geoms, dims=(3,))
        put("geom_seg0", [g["segment"][0] for g in geo], geoms, dims=(3,))
        put("geom_seg1", [g["segment"][1] for g in geo], geoms, dims=(3,))
        put("geom_radius", [g["radius"] for g in geo], geoms)
        put("geom_bound", [g["bound"] for g in geo], geoms)
        self._init_rigid_trees([x["geometry"]["tree"] for x in bodies], geom_starts, put, rows)
        self.rigid_reach = float(max(g["radius"] for g in geo)) + self.RIGID_MARGIN
        # whether a round core can pass through a polytope (contacts compile that case only then)
        self.rigid_round_and_polytopes = any(g["round"] for g in geo) and not all(g["round"] for g in geo)
        # compile-time switches on scene content: round cores' code only where there are round shapes,
        # the walk down trees of parts only where a body has several (each made a box scene's first step
        # compile seconds longer)
        self.rigid_has_round = any(g["round"] for g in geo)
        self.rigid_parted = any(len(x["geometry"]["geoms"]) > 1 for x in bodies)
        self.rigid_prisms = any(g["prism"] for g in geo)
        # contact keys (contacts.py) are i64 products of geoms, geoms + colliders, sides and features
        features = max(len(points), 2 * len(edges), 1)
        if len(geo) * (len(geo) + 64) * 5 * features >= 1 << 62:
            raise ParameterError(
                f"rigid bodies: {len(geo)} convex parts with {features} points or edge ends are more than "
                "the contact keys can tell apart (decimate the triangle meshes)"
            )

    def _init_rigid_trees(self, trees, geom_starts, put, rows) -> None:
        """The bodies' trees (obb_tree.py) as fields, their node and geom indices made global."""
        sizes = [len(t["bound"]) for t in trees]
        start = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
        cat = lambda key: np.concatenate([t[key] for t in trees])
        shift = lambda key, by: np.concatenate(
            [np.where(t[key] >= 0, t[key] + s, -1) for t, s in zip(trees, by[:-1], strict=True)]
        )
        child, geom = shift("child", start), shift("geom", geom_starts)
        nodes = rows(int(start[-1]))
        put("rigid_node_start", start, self.rigid_capacity + 1, ti.i32)
        put("node_offset", cat("offset"), nodes, dims=(3,))
        put("node_rot", cat("rotation"), nodes, dims=(3, 3))
        put("node_half", cat("half"), nodes, dims=(3,))
        put("node_bound", cat("bound"), nodes)
        put("node_child", child, nodes, ti.i32, dims=(2,))
        put("node_geom", geom, nodes, ti.i32)

    @ti.func
    def geom_pose(self, g, x, r):
        """(origin [m], rotation) of geom g in the world, its body's com at x and principal frame at r."""
        return x + r @ self.geom_offset[g], r @ self.geom_rot[g]

    MAX_RIGID_POINTS = 1 << 24
    # Contacts are made from this far apart [m] (speculative: the solver lets the gap close within the
    # step, no further), as Box2D's and Jolt's speculative distance.
    RIGID_MARGIN = 0.02
