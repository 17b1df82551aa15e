"""Taichi kernels of the software rasterizer: a visibility buffer (Burns & Hunt 2013) filled by ray casts
against each primitive's screen footprint, then deferred shading with supersampling.

Pass 1, one kernel per primitive kind, parallel over primitives: each one visits the samples of its
screen bounding box and, where it covers a sample, writes key = (depth bits << 32) | primitive id with
an atomic min into the (H*s, W*s) int64 buffer. Depth is the view-space z [m] of the visible point
(positive f32, whose bit pattern orders like the value), so the nearest primitive wins whatever the
draw order and whatever thread gets there first (ties go to the lower id): the picture is
deterministic. Coverage and depth are exact per sample:
- a sphere is hit where the sample's ray meets it, |o + t d - c| = r with the nearer root
  t = (oc . d) - sqrt(r^2 - |oc - (oc . d) d|^2) (the stable form: the miss distance is taken from a
  difference of vectors, not from |oc|^2 - r^2), so a sphere has its true radius in the picture, and
  spheres that intersect each other or a surface are cut exactly where they meet;
- a triangle by the ray-triangle test of Moller & Trumbore (1997), which gives the barycentric
  coordinates and t; its bounding box comes from its projected corners;
- a line segment is stepped one sample at a time along its longer screen axis (DDA) and stamped as a
  square of `width` samples, depth interpolated linearly in 1/z (perspective-correct).
The sphere's bounding box is exact: the tangent planes through the eye bound x/z within
(cx cz -+ r sqrt(cx^2 + cz^2 - r^2)) / (cz^2 - r^2), and likewise y/z.

Pass 2 (`shade`), parallel over output pixels: each of the s x s samples of the pixel is shaded from its
key alone (the ray is recast against that one primitive to get the point, the normal and, for
triangles, the barycentric coordinates for the interpolated vertex normal and colour: Phong (1975)
normal interpolation), and the samples are averaged: 2 x 2 supersampling antialiases every edge.
Lighting: Lambert's cosine law from a key light plus a fill light from the camera and an ambient term,
and a Blinn (1977) highlight: c = base (ambient + k_key max(n.l, 0) + k_fill max(-n.d, 0)) +
k_spec max(n.h, 0)^shininess. Triangles whose geometric normal faces away from the eye show their back:
the normal flips and the back colour is used (two-sided cloth). Lines are unlit.

Arrays are NumPy float32 / int32 passed as Taichi ndarrays, so a new size never recompiles a kernel.
The four kernels compile without Taichi's CFG passes and advanced optimisation: with an empty cache the
cloth demo's shade, triangles and lines took 0.29-0.31 s instead of 0.47-0.49 s; the pictures of the
blobs, cloth and spheres demos are the same pixels, and a 960 x 720 one did not render slower (blobs
34-36 against 35-38 ms, cloth 40-46 against 36-45, pour 87-92 against 81-88: medians of 9, two
alternating runs each, within their spread).
"""

import taichi as ti

from ..runtime import compile_with

# Camera array layout (float32, CAMERA_SIZE): [0:3] eye, [3:6] right, [6:9] up, [9:12] forward,
# [12] tan(fov/2) * aspect, [13] tan(fov/2), [14] width and [15] height in samples, [16] near,
# [17:20] light direction (unit, towards the light), [20] ambient, [21] key, [22] fill, [23] specular,
# [24] shininess, [25] line depth bias (a fraction of the depth).
CAMERA_SIZE = 26
EMPTY = (1 << 63) - 1  # a sample nothing covers
ID_MASK = 0xFFFFFFFF

F2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
I2 = ti.types.ndarray(dtype=ti.i32, ndim=2)
F1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
VIS = ti.types.ndarray(dtype=ti.i64, ndim=2)
IMG = ti.types.ndarray(dtype=ti.u8, ndim=3)


@ti.func
def _v3(a: ti.template(), i, k):
    return ti.Vector([a[i, k], a[i, k + 1], a[i, k + 2]], dt=ti.f32)


@ti.func
def _c3(cam: ti.template(), k):
    return ti.Vector([cam[k], cam[k + 1], cam[k + 2]], dt=ti.f32)


@ti.func
def _ray_d(cam: ti.template(), px, py):
    """Direction forward + x right + y up of the ray through the centre of sample (column px, row py
    from the top): not unit; its dot product with forward is 1."""
    x = ((ti.cast(px, ti.f32) + 0.5) / cam[14] * 2.0 - 1.0) * cam[12]
    y = (1.0 - (ti.cast(py, ti.f32) + 0.5) / cam[15] * 2.0) * cam[13]
    return _c3(cam, 9) + x * _c3(cam, 3) + y * _c3(cam, 6)


@ti.func
def _ray(cam: ti.template(), px, py):
    """Unit direction of the ray through the centre of sample (column px, row py from the top)."""
    d = _ray_d(cam, px, py)
    return d / d.norm()


@ti.func
def _key(depth, pid):
    return (ti.cast(ti.bit_cast(ti.cast(depth, ti.f32), ti.i32), ti.i64) << 32) | ti.cast(pid, ti.i64)


@ti.func
def _sphere_t(o, d, c, r):
    """Distance along the unit ray o + t d to the sphere's near side, or -1 for a miss (or an eye inside)."""
    oc = c - o
    tc = oc.dot(d)
    q = oc - tc * d
    h2 = r * r - q.dot(q)
    t = -1.0
    if h2 >= 0.0:
        t = tc - ti.sqrt(h2)
    return t


@ti.func
def _triangle_hit(o, d, a, b, c):
    """Moller-Trumbore: (t, b1, b2) of the ray's hit on triangle abc, t = -1 for a miss."""
    e1 = b - a
    e2 = c - a
    p = d.cross(e2)
    det = e1.dot(p)
    t = -1.0
    u = 0.0
    v = 0.0
    if ti.abs(det) > 1e-20:
        inv = 1.0 / det
        s = o - a
        u = s.dot(p) * inv
        qv = s.cross(e1)
        v = d.dot(qv) * inv
        # A small tolerance closes cracks along shared edges (both neighbours may claim a sample there;
        # the depth test keeps one).
        tol = -1e-5
        if u >= tol and v >= tol and u + v <= 1.0 - tol:
            t = e2.dot(qv) * inv
    return t, u, v


@ti.func
def _to_pixels(cam: ti.template(), xz, yz):
    """Image-plane slopes (x/z, y/z) -> sample coordinates (column, row from the top), continuous."""
    return (xz / cam[12] + 1.0) * 0.5 * cam[14], (1.0 - yz / cam[13]) * 0.5 * cam[15]


@compile_with(cfg_optimization=False, advanced_optimization=False)
@ti.kernel
def raster_spheres(vis: VIS, cam: F1, sph: F2, n: ti.i32, offset: ti.i32):
    """sph (n, 4): centre [m], radius [m]; writes keys with ids offset + i."""
    w = ti.cast(cam[14], ti.i32)
    h = ti.cast(cam[15], ti.i32)
    eye = _c3(cam, 0)
    for i in range(n):
        c = _v3(sph, i, 0)
        r = sph[i, 3]
        rel = c - eye
        cx = rel.dot(_c3(cam, 3))
        cy = rel.dot(_c3(cam, 6))
        cz = rel.dot(_c3(cam, 9))
        if cz - r > cam[16] and r > 0.0:
            den = cz * cz - r * r
            sx = ti.sqrt(ti.max(cx * cx + cz * cz - r * r, 0.0))
            sy = ti.sqrt(ti.max(cy * cy + cz * cz - r * r, 0.0))
            x0, y1 = _to_pixels(cam, (cx * cz - r * sx) / den, (cy * cz + r * sy) / den)
            x1, y0 = _to_pixels(cam, (cx * cz + r * sx) / den, (cy * cz - r * sy) / den)
            c0 = ti.max(ti.cast(ti.floor(x0), ti.i32) - 1, 0)
            c1 = ti.min(ti.cast(ti.floor(x1), ti.i32) + 1, w - 1)
            r0 = ti.max(ti.cast(ti.floor(y1), ti.i32) - 1, 0)
            r1 = ti.min(ti.cast(ti.floor(y0), ti.i32) + 1, h - 1)
            r2 = r * r
            for py in range(r0, r1 + 1):
                for px in range(c0, c1 + 1):
                    # The unnormalised ray D = forward + x right + y up has D . forward = 1, so its
                    # parameter t is the view depth itself: no square root for the direction.
                    dd = _ray_d(cam, px, py)
                    a = dd.dot(dd)
                    tc = rel.dot(dd) / a
                    q = rel - tc * dd
                    h2 = r2 - q.dot(q)
                    if h2 >= 0.0:
                        t = tc - ti.sqrt(h2 / a)
                        key = _key(t, offset + i)
                        if t > 0.0 and key < vis[py, px]:  # most samples lose: skip the atomic
                            ti.atomic_min(vis[py, px], key)


@compile_with(cfg_optimization=False, advanced_optimization=False)
@ti.kernel
def raster_triangles(vis: VIS, cam: F1, verts: F2, tris: I2, n: ti.i32, offset: ti.i32):
    """verts (V, 3) [m], tris (n, 3) indices; writes keys with ids offset + f. Triangles reaching behind
    the near plane are skipped (scenes keep their meshes in front of the camera)."""
    w = ti.cast(cam[14], ti.i32)
    h = ti.cast(cam[15], ti.i32)
    eye = _c3(cam, 0)
    for f in range(n):
        a = _v3(verts, tris[f, 0], 0)
        b = _v3(verts, tris[f, 1], 0)
        c = _v3(verts, tris[f, 2], 0)
        lo = ti.Vector([1e30, 1e30])
        hi = ti.Vector([-1e30, -1e30])
        ok = True
        for k in ti.static(range(3)):
            p = (a, b, c)[k] - eye
            z = p.dot(_c3(cam, 9))
            if z <= cam[16]:
                ok = False
            else:
                sx, sy = _to_pixels(cam, p.dot(_c3(cam, 3)) / z, p.dot(_c3(cam, 6)) / z)
                lo = ti.min(lo, ti.Vector([sx, sy]))
                hi = ti.max(hi, ti.Vector([sx, sy]))
        if ok:
            c0 = ti.max(ti.cast(ti.floor(lo[0]), ti.i32) - 1, 0)
            c1 = ti.min(ti.cast(ti.floor(hi[0]), ti.i32) + 1, w - 1)
            r0 = ti.max(ti.cast(ti.floor(lo[1]), ti.i32) - 1, 0)
            r1 = ti.min(ti.cast(ti.floor(hi[1]), ti.i32) + 1, h - 1)
            for py in range(r0, r1 + 1):
                for px in range(c0, c1 + 1):
                    d = _ray(cam, px, py)
                    t, _, _ = _triangle_hit(eye, d, a, b, c)
                    if t > 0.0:
                        ti.atomic_min(vis[py, px], _key(t * d.dot(_c3(cam, 9)), offset + f))


@compile_with(cfg_optimization=False, advanced_optimization=False)
@ti.kernel
def raster_lines(vis: VIS, cam: F1, seg: F2, n: ti.i32, offset: ti.i32, width: ti.i32):
    """seg (n, 6): both ends [m], already clipped to lie in front of the near plane; a square stamp of
    `width` samples along the segment."""
    w = ti.cast(cam[14], ti.i32)
    h = ti.cast(cam[15], ti.i32)
    eye = _c3(cam, 0)
    bias = 1.0 - cam[25]
    for i in range(n):
        p0 = _v3(seg, i, 0) - eye
        p1 = _v3(seg, i, 3) - eye
        z0 = p0.dot(_c3(cam, 9))
        z1 = p1.dot(_c3(cam, 9))
        if z0 > 0.0 and z1 > 0.0:
            x0, y0 = _to_pixels(cam, p0.dot(_c3(cam, 3)) / z0, p0.dot(_c3(cam, 6)) / z0)
            x1, y1 = _to_pixels(cam, p1.dot(_c3(cam, 3)) / z1, p1.dot(_c3(cam, 6)) / z1)
            steps = ti.cast(ti.min(ti.max(ti.abs(x1 - x0), ti.abs(y1 - y0)), 1e5), ti.i32) + 1
            half = width // 2
            for k in range(steps + 1):
                s = ti.cast(k, ti.f32) / ti.cast(steps, ti.f32)
                cx = ti.cast(ti.floor(x0 + s * (x1 - x0)), ti.i32)
                cy = ti.cast(ti.floor(y0 + s * (y1 - y0)), ti.i32)
                depth = bias / ((1.0 - s) / z0 + s / z1)
                for dy, dx in ti.ndrange(width, width):
                    py = cy - half + dy
                    px = cx - half + dx
                    if 0 <= px < w and 0 <= py < h:
                        ti.atomic_min(vis[py, px], _key(depth, offset + i))


@ti.func
def _light(cam: ti.template(), base, n, d):
    l_key = _c3(cam, 17)
    hv = l_key - d
    hv = hv / ti.max(hv.norm(), 1e-12)
    diffuse = cam[20] + cam[21] * ti.max(n.dot(l_key), 0.0) + cam[22] * ti.max(-n.dot(d), 0.0)
    spec = cam[23] * ti.pow(ti.max(n.dot(hv), 0.0), cam[24])
    return base * diffuse + spec


@compile_with(cfg_optimization=False, advanced_optimization=False)
@ti.kernel
def shade(
    img: IMG,
    vis: VIS,
    cam: F1,
    ss: ti.i32,
    bg_top: F1,
    bg_bottom: F1,
    sph: F2,
    sph_col: F2,
    n_sph: ti.i32,
    verts: F2,
    normals: F2,
    vcol: F2,
    tris: I2,
    tback: F2,
    n_tri: ti.i32,
    lcol: F2,
):
    """img (H, W, 3) uint8 from the visibility buffer (H*ss, W*ss): each pixel the mean of its samples."""
    eye = _c3(cam, 0)
    height = img.shape[0]
    for row, col in ti.ndrange(img.shape[0], img.shape[1]):
        acc = ti.Vector([0.0, 0.0, 0.0])
        grade = ti.cast(row, ti.f32) / ti.cast(ti.max(height - 1, 1), ti.f32)
        bg = (1.0 - grade) * _c3(bg_top, 0) + grade * _c3(bg_bottom, 0)
        for sy, sx in ti.ndrange(ss, ss):
            py = row * ss + sy
            px = col * ss + sx
            key = vis[py, px]
            color = bg
            if key != ti.i64(EMPTY):
                pid = ti.cast(key & ti.i64(ID_MASK), ti.i32)
                d = _ray(cam, px, py)
                if pid < n_sph:
                    c = _v3(sph, pid, 0)
                    r = sph[pid, 3]
                    t = _sphere_t(eye, d, c, r)
                    nrm = (eye + t * d - c) / r
                    color = _light(cam, _v3(sph_col, pid, 0), nrm, d)
                elif pid < n_sph + n_tri:
                    f = pid - n_sph
                    i0, i1, i2 = tris[f, 0], tris[f, 1], tris[f, 2]
                    a = _v3(verts, i0, 0)
                    b = _v3(verts, i1, 0)
                    c = _v3(verts, i2, 0)
                    _, u, v = _triangle_hit(eye, d, a, b, c)
                    w0 = 1.0 - u - v
                    nrm = w0 * _v3(normals, i0, 0) + u * _v3(normals, i1, 0) + v * _v3(normals, i2, 0)
                    geo = (b - a).cross(c - a)
                    if nrm.norm() < 1e-12:  # vertices without normals: the face's own
                        nrm = geo
                    nrm = nrm / ti.max(nrm.norm(), 1e-20)
                    base = w0 * _v3(vcol, i0, 0) + u * _v3(vcol, i1, 0) + v * _v3(vcol, i2, 0)
                    if geo.dot(d) > 0.0:  # the back of the sheet faces the eye
                        nrm = -nrm
                        base = _v3(tback, f, 0)
                    color = _light(cam, base, nrm, d)
                else:
                    color = _v3(lcol, pid - n_sph - n_tri, 0)
            acc += color
        acc = acc / ti.cast(ss * ss, ti.f32)
        for k in ti.static(range(3)):
            img[row, col, k] = ti.cast(ti.min(ti.max(acc[k], 0.0), 1.0) * 255.0 + 0.5, ti.u8)
