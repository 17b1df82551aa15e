"""The liquid's walls as boundary particles (Akinci et al., "Versatile Rigid-Fluid Coupling for
Incompressible SPH", SIGGRAPH 2012, sec. 3): one layer of samples about a spacing apart on every static
collider's surface within reach of the liquid, each standing for the volume V_b = 1 / sum_k W(x_b - x_k)
over its neighbouring samples (eq. 4), so that an uneven sampling (edges sampled twice, skinny
triangles) still gives a wall the same density contribution. A sample adds psi_b W(x_i - x_b) with
psi_b = rho0 V_b (eq. 5) to a fluid particle's density, and mirrors its pressure (eq. 10; DFSPH adds the
mirrored pressure's hydrostatic part and its missing half, wall_pressure.py).

The layer lies half a spacing inside the solid, so that a block of liquid filled up to a wall (its first
particles half a spacing from the surface) starts a spacing from the samples, as inside the liquid, and
the liquid's volume ends at the wall's surface. Planes are sampled on a square grid over the liquid's
domain; every other collider on its surface mesh (`collider.surface`, outward faces): the mesh is first
moved half a spacing inside (inset_vertices), then sampled triangle by triangle, so that every sample is
half a spacing behind each face it lies under, at edges and corners too. (Moving each face's own grid
along its normal instead leaves the grid's rim on the neighbouring faces' planes: a box's edges were
sampled at its surface, which held a floating plank a fifth of a spacing too high.) Samples of a plane
that fall deeper inside another plane's solid (a container wall continued past its edge) are dropped."""

from __future__ import annotations

import math

import numpy as np

from ...errors import ParameterError


def boundary_samples(colliders, domain, spacing: float, reach: float) -> np.ndarray:
    """(B,3) [m] samples about `spacing` apart, half a spacing inside the colliders' surfaces, within
    `reach` [m] of the domain (lo, hi)."""
    lo, hi = np.asarray(domain[0], dtype=np.float64) - reach, np.asarray(domain[1], dtype=np.float64) + reach
    planes = [c.half_space() for c in colliders if c.half_space() is not None]
    parts = []
    for c in colliders:
        if getattr(c, "motion", None) is not None or getattr(c, "deforming", False):
            raise ParameterError(
                f"a liquid's walls must be static: collider {type(c).__name__} moves "
                "(moving walls are not sampled as boundary particles yet)"
            )
        hs = c.half_space()
        if hs is not None:
            n = np.asarray(hs[0], dtype=np.float64)
            parts.append(_plane(n, float(hs[1]) - 0.5 * spacing, lo, hi, spacing))
        else:
            v, faces = c.surface((lo, hi))
            parts.append(mesh_samples(np.asarray(v, dtype=np.float64), faces, spacing))
    x = np.concatenate(parts) if parts else np.zeros((0, 3))
    x = x[np.all((x >= lo) & (x <= hi), axis=1)]
    for n, offset in planes:  # deeper inside another plane's solid than its own layer: behind that wall
        x = x[x @ np.asarray(n, dtype=np.float64) - offset > -(0.5 + 1e-6) * spacing]
    key = np.round(x / (1e-4 * spacing)).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return x[np.sort(first)]


def _plane(n, offset: float, lo, hi, spacing: float) -> np.ndarray:
    """A square grid of `spacing` on the plane n.x = offset, covering the box lo..hi's projection, at
    half-integer multiples of the spacing from the world origin's projection."""
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    corners = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    origin = offset * n  # the world origin's projection: u and w coordinates are world coordinates
    a, b = (corners - origin) @ u, (corners - origin) @ w
    # At half-integer multiples of the spacing: for axis-aligned walls these continue the lattice of a
    # block filled from a corner at whole multiples (add_fluid_block), one layer beyond it.
    ia = (np.arange(math.floor(a.min() / spacing) - 1, math.ceil(a.max() / spacing) + 1) + 0.5) * spacing
    ib = (np.arange(math.floor(b.min() / spacing) - 1, math.ceil(b.max() / spacing) + 1) + 0.5) * spacing
    ga, gb = np.meshgrid(ia, ib, indexing="ij")
    return origin + ga.reshape(-1, 1) * u + gb.reshape(-1, 1) * w


def inset_vertices(v, faces, depth: float) -> np.ndarray:
    """(V,3) [m] the vertices moved `depth` [m] inside the surface: each to the point `depth` behind the
    plane of every face around it (a box's corner moves `depth` along each of its three axes), in the
    least-squares sense where more than three planes meet (a curved mesh's vertex). Directions that the
    planes fix only weakly (normals a few degrees apart) are left to their mean, and no vertex moves
    more than 3 depth (a sharp spike). Vertices at one point are one vertex here (an STL file repeats
    every corner for each of its triangles)."""
    v = np.asarray(v, dtype=np.float64)
    scale = max(float(np.abs(v).max()), 1e-30) if len(v) else 1.0
    _, weld = np.unique(np.round(v / (1e-9 * scale)), axis=0, return_inverse=True)
    weld = weld.ravel()
    around: list[list[np.ndarray]] = [[] for _ in range(weld.max() + 1 if len(v) else 0)]
    for face in faces:
        face = list(face)
        for k in range(1, len(face) - 1):
            corners = (face[0], face[k], face[k + 1])
            n = np.cross(v[corners[1]] - v[corners[0]], v[corners[2]] - v[corners[0]])
            length = np.linalg.norm(n)
            if length > 0.0:
                for c in corners:
                    around[weld[c]].append(n / length)
    shifts = np.zeros((len(around), 3))
    for i, normals in enumerate(around):
        if not normals:
            continue
        u, s, wt = np.linalg.svd(np.asarray(normals), full_matrices=False)
        keep = s > 0.1 * s[0]
        shift = wt[keep].T @ ((u[:, keep].T @ np.full(len(normals), -depth)) / s[keep])  # n . shift = -depth
        length = np.linalg.norm(shift)
        shifts[i] = shift if length <= 3.0 * depth else shift * (3.0 * depth / length)
    return v + shifts[weld]


def mesh_samples(v, faces, spacing: float) -> np.ndarray:
    """Samples of the surface moved half a spacing inside (inset_vertices), triangle by triangle
    (polygons fanned): a grid at most `spacing` apart along the two edges from the corner facing the
    longest edge (so the two triangles of a rectangle continue one grid), and the longest edge sampled
    at most `spacing` apart. Shared edges are sampled by both of their triangles (callers drop repeated
    points)."""
    v = inset_vertices(v, faces, 0.5 * spacing)
    out = []
    for face in faces:
        face = list(face)
        for k in range(1, len(face) - 1):
            a, b, c = v[face[0]], v[face[k]], v[face[k + 1]]
            if np.linalg.norm(np.cross(b - a, c - a)) == 0.0:
                continue  # a degenerate triangle: its edges are sampled by its neighbours
            # The grid's corner is the one facing the longest edge: a rectangle's two triangles then
            # both grid its sides (one square grid), and the diagonal is the third edge.
            longest = int(np.argmax([np.linalg.norm(c - b), np.linalg.norm(a - c), np.linalg.norm(b - a)]))
            a, b, c = ((a, b, c), (b, c, a), (c, a, b))[longest]
            nu, nv, nw = (_intervals(np.linalg.norm(e), spacing) for e in (b - a, c - a, c - b))
            i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
            s, t = (i / nu).ravel(), (j / nv).ravel()
            keep = s + t <= 1.0 + 1e-9
            s, t = s[keep], t[keep]
            edge = np.arange(nw + 1) / nw  # the third edge, b to c
            s, t = np.concatenate([s, 1.0 - edge]), np.concatenate([t, edge])
            out.append(a + s[:, None] * (b - a) + t[:, None] * (c - a))
    return np.concatenate(out) if out else np.zeros((0, 3))


def _intervals(length: float, spacing: float) -> int:
    """The fewest intervals at most `spacing` long on an edge of `length` (an edge of 7 spacings in
    floating point, 7.000000000000001, is 7 intervals, not 8)."""
    return max(1, math.ceil(length / spacing - 1e-9))
