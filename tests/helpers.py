"""Small scene builders shared by the tests (public API only)."""

from types import SimpleNamespace

import numpy as np
import taichi as ti

import taichi_anim as ta


def spring_particle(*, k: float, m: float = 1.0, c: float = 0.0, rest: float = 10.0, x0: float = 10.5):
    """One particle on the x axis tied to the origin by a spring: m x'' = -k (x - L0) - c x'."""
    b = ta.Builder()
    b.add_particle((x0, 0.0, 0.0), (0.0, 0.0, 0.0), mass=m)
    b.add_force_anchor_spring(0, (0.0, 0.0, 0.0), stiffness=k, rest_length=rest, damping=c)
    model = b.finalize()
    return model, model.state()


def run(model, state, integrator, dt: float, steps: int, record=None):
    """Step `steps` times; return (steps+1, N, 3) positions and velocities if `record`."""
    xs, vs = [state.positions()], [state.velocities()]
    for _ in range(steps):
        integrator.step(model, state, dt)
        if record:
            xs.append(state.positions())
            vs.append(state.velocities())
    return np.array(xs), np.array(vs)


def spring_energy(xs, vs, k, m, rest):
    """E = m v^2 / 2 + k (x - L0)^2 / 2 for the particle of `spring_particle`."""
    return 0.5 * m * (vs[:, 0] ** 2).sum(-1) + 0.5 * k * (np.linalg.norm(xs[:, 0], axis=-1) - rest) ** 2


def kernel_eps() -> float:
    """Machine epsilon of the precision the kernels run in (f32 or f64)."""
    from taichi_anim.runtime import np_float

    return float(np.finfo(np_float()).eps)


def ulp_tolerance(scale: float, ulps: int = 64) -> float:
    """An absolute tolerance of `ulps` units in the last place of the kernels' precision at `scale`.

    For comparing two differently compiled kernels that evaluate the same floating-point expression:
    LLVM may fuse multiply-adds, reorder or vectorise them differently in each (1-2 ulp per operation
    on AVX-512 CPUs), so only bitwise comparisons of the same kernel (determinism) are exact. 64 ulp
    covers the tens of roundings of a closest-point or ray-triangle evaluation with a margin."""
    return ulps * kernel_eps() * scale


@ti.kernel
def _linear_pass(
    term: ti.template(),
    cache: ti.template(),
    xf: ti.template(),
    vf: ti.template(),
    pf: ti.template(),
    f: ti.template(),
    kxv: ti.template(),
    diag: ti.template(),
    sp: ti.template(),
    h: float,
):
    term.linearize(cache, xf, vf, 0.0, h, True)
    for i in range(xf.shape[0]):
        f[i], kxv[i], diag[i] = term.gather_linear(cache, i)
        sp[i] = term.apply(cache, i, pf)


def assert_passes_match_element_arrays(term, x, v, p, h: float, rel: float = 1e-13):
    """An element term's solver passes (linearize into its own cache, then the per-particle gathers and
    S p) against its element_linear arrays summed per particle in NumPy: the same forces, df/dx v, diagonal
    blocks and products, to `rel` of the largest entry (f64 round-off; the passes may factor S)."""
    n, k = len(x), term.arity
    xf, vf, pf, f, kxv, sp = (ti.Vector.field(3, float, n) for _ in range(6))
    diag = ti.Matrix.field(3, 3, float, n)
    for fld, val in ((xf, x), (vf, v), (pf, p)):
        fld.from_numpy(val)
    _linear_pass(term, term.make_cache(n, True), xf, vf, pf, f, kxv, diag, sp, h)
    _, FL, S, KV = term.element_arrays(x, v, h=h)
    ids = term.vertices
    want_f, want_kxv, want_sp = (np.zeros((n, 3)) for _ in range(3))
    want_diag = np.zeros((n, 3, 3))
    Sp = np.einsum("eij,ej->ei", S, p[ids].reshape(-1, 3 * k)).reshape(-1, k, 3)
    for a in range(k):
        np.add.at(want_f, ids[:, a], FL.reshape(-1, k, 3)[:, a])
        np.add.at(want_kxv, ids[:, a], KV.reshape(-1, k, 3)[:, a])
        np.add.at(want_sp, ids[:, a], Sp[:, a])
        np.add.at(want_diag, ids[:, a], S[:, 3 * a : 3 * a + 3, 3 * a : 3 * a + 3])
    for got, want in ((f, want_f), (kxv, want_kxv), (sp, want_sp), (diag, want_diag)):
        scale = max(np.abs(want).max(), np.finfo(float).tiny)
        assert np.abs(got.to_numpy() - want).max() <= rel * scale


def mesh_drop(*, rings: int, segments: int, frames_dt: float = 1.0 / 600.0):
    """A 10 x 10 grid of particles falling from 5 cm above a UV-sphere mesh collider (rings x segments) under
    gravity, symplectic Euler: the scene-like record the size-bucket tests step (model, integrator, state,
    dt, substeps)."""
    from taichi_anim.scenes.drape import uv_sphere

    b = ta.Builder()
    b.add_force_gravity()
    for i in range(10):
        for j in range(10):
            b.add_particle((0.02 * (i - 4.5), 0.45, 0.02 * (j - 4.5)), (0.0, 0.0, 0.0), mass=0.01)
    ball = uv_sphere((0.0, 0.2, 0.0), 0.2, rings=rings, segments=segments)
    b.add_collider_mesh(ball, restitution=0.0, friction=0.2)
    model = b.finalize()
    integrator = ta.make_integrator("symplectic_euler")
    return SimpleNamespace(model=model, integrator=integrator, state=model.state(), dt=frames_dt, substeps=1)


def fluid_tank(*, rows: int, method: str = "dfsph", frame_dt: float = 1.0 / 60.0):
    """A block of liquid at 2 cm spacing, 10 cm x `rows` layers x 6 cm (5 x rows x 3 particles), against
    a corner of a 20 x 20 x 6 cm tank, under gravity, solved by `method`: a small dam break, the
    scene-like record the size-bucket tests step (the tank, and so the colliders' constants and the
    neighbour grid's cells, the same at every count)."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (0.2, 0.2, 0.06), restitution=0.0)
    b.add_fluid(spacing=0.02, method=method)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.1, 0.02 * rows, 0.06))
    model = b.finalize()
    integrator = ta.make_integrator("symplectic_euler")
    return SimpleNamespace(model=model, integrator=integrator, state=model.state(), dt=frame_dt, substeps=1)


def momentum_exchange(model, frames: int, dt: float):
    """`model` stepped from its start by symplectic Euler for `frames` steps of dt [s]: (the largest
    component of the change of the total momentum sum m v, its scale sum m |v| after, the velocities
    after), what a check of momentum exchanged between kinds compares."""
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    mass = model.particle_masses()[:, None]
    p0 = (mass * state.velocities()).sum(axis=0)
    for _ in range(frames):
        stepper.advance(state, dt, 1)
    v = state.velocities()
    return float(np.abs((mass * v).sum(axis=0) - p0).max()), float((mass * np.abs(v)).sum()), v


@ti.func
def row_vec3(a: ti.template(), i, k: ti.template()):
    """Row i, columns 3k..3k+2 of a (N, 3m) array as a vector."""
    return ti.Vector([a[i, 3 * k], a[i, 3 * k + 1], a[i, 3 * k + 2]])
