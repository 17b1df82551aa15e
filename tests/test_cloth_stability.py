"""Cloth stability: a hanging cloth's static equilibrium, implicit Euler across five decades of stiffness,
symplectic Euler's step limit against 2 / omega_max, and a fast cloth hitting a sphere."""

import functools

import numpy as np
import pytest

import taichi_anim as ta

G = np.array([0.0, -9.81, 0.0])
GRAVITY = 9.81


def masses(model):
    return model.particle_masses()


def scaled_material(scale, damping=True):
    """Every spring family at `scale` x the default stiffness (stretch 1e3, shear 1e2, bend 10 N/m)."""
    c = 1.0 if damping else 0.0
    return ta.ClothMaterial(
        stretch_stiffness=1e3 * scale,
        stretch_damping=0.05 * c,
        shear_stiffness=1e2 * scale,
        shear_damping=0.01 * c,
        bend_stiffness=10.0 * scale,
        bend_damping=0.005 * c,
    )


def energy(model, m, x, v):
    """E = sum m v^2 / 2 - sum m g.x + sum_s k (l - L)^2 / 2 [J] (kinetic, gravity, spring potential)."""
    sp = model.springs
    length = np.linalg.norm(x[sp.pairs[:, 0]] - x[sp.pairs[:, 1]], axis=1)
    return (
        0.5 * np.sum(m * np.sum(v * v, axis=1))
        - np.sum(m * (x @ G))
        + 0.5 * np.sum(sp.stiffness * (length - sp.rest_length) ** 2)
    )


# ---------------------------------------------------------------- static equilibrium


def test_hanging_cloth_reaches_static_equilibrium():
    # A vertical 1 m cloth pinned at its two top corners. Backward Euler's fixed point (v = 0, dv = 0)
    # needs b = h f(x, 0) = 0: static equilibrium. Damping and drag take the motion out, then every free
    # vertex carries its weight through its springs, |f_i| <= 1e-3 m_i g, and the pins hold the weight:
    # sum over pins of the spring force = -W (third law), each pin half of it (mirror symmetry).
    nx = 12
    pins = [(nx - 1) * nx, nx * nx - 1]
    b = ta.Builder()
    cloth = b.add_cloth_grid(origin=(0, 0, 0), size=(1.0, 1.0), resolution=(nx, nx), plane="xy", pinned=pins)
    b.add_force_gravity(G)
    b.add_force_drag(0.002)
    model = b.finalize()
    state = model.state()
    m = masses(model)
    free = m > 0
    assert np.array_equal(np.flatnonzero(~free), cloth.pinned)
    x0 = state.positions()
    integ = ta.IntegratorImplicitEuler(tol=1e-8, max_iterations=500)
    for _ in range(90):  # 1.5 s
        integ.step(model, state, 1.0 / 60.0)
    x = state.positions()
    v = state.velocities()
    np.testing.assert_array_equal(x[~free], x0[~free])  # pins did not move
    assert np.abs(x - x0).max() > 1e-3  # the cloth did sag: equilibrium is not the start
    assert np.linalg.norm(v, axis=1).max() < 1e-6
    f = model.forces(x, np.zeros_like(x))
    weight = m * GRAVITY
    assert np.all(np.linalg.norm(f[free], axis=1) <= 1e-3 * weight[free])
    w = weight.sum()
    pin_force = f[~free]
    np.testing.assert_allclose(pin_force[:, 1].sum(), -w, rtol=1e-2)
    np.testing.assert_allclose(pin_force[:, 1], -w / 2, rtol=1e-2)
    np.testing.assert_allclose(pin_force[0, 0], -pin_force[1, 0], rtol=1e-2, atol=1e-6 * w)


# ---------------------------------------------------------------- implicit Euler across stiffnesses

SCALES = [0.1, 1.0, 10.0, 100.0, 1000.0]  # stretch stiffness 1e2 ... 1e6 N/m
SWEEP_N = 16
SWEEP_STEPS = 600
SWEEP_DT = 1.0 / 60.0


NEWTON = (("newton_iterations", 10), ("line_search", True), ("policy", (("nonconvergence", "ignore"),)))


@functools.cache
def stiffness_sweep_run(scale, options=(), steps=SWEEP_STEPS):
    """A horizontal 16x16, 1 m cloth pinned at two corners falls and swings for 10 s (implicit Euler,
    PCG at its default tol, dt = 1/60 s; `options` of the integrator as a tuple of pairs). Returns
    NumPy records only (cached across Taichi runtimes)."""
    b = ta.Builder()
    b.add_cloth_grid(
        origin=(0, 1, 0),
        size=(1.0, 1.0),
        resolution=(SWEEP_N, SWEEP_N),
        material=scaled_material(scale),
        pinned=[0, SWEEP_N - 1],
    )
    b.add_force_gravity(G)
    model = b.finalize()
    state = model.state()
    m = masses(model)
    x = state.positions()
    x0 = x.copy()
    options = {k: dict(v) if isinstance(v, tuple) else v for k, v in options}
    integ = ta.IntegratorImplicitEuler(**options)
    energies = [energy(model, m, x, np.zeros_like(x))]
    speed = []
    reach = []
    sp = model.springs
    stretch_shear = sp.family <= 1
    strain = []
    pins = np.flatnonzero(m == 0)
    # Rest distance along the grid from each pin (8-neighbour paths of stretch and shear springs).
    h = 1.0 / (SWEEP_N - 1)
    cells = np.abs(x0[:, None, [0, 2]] - x0[None, pins][:, :, [0, 2]]) / h
    octile = h * (cells.max(-1) - cells.min(-1) + np.sqrt(2) * cells.min(-1))  # (N, pins)
    for _ in range(steps):
        integ.step(model, state, SWEEP_DT)
        x = state.positions()
        v = state.velocities()
        energies.append(energy(model, m, x, v))
        speed.append(np.linalg.norm(v, axis=1).max())
        length = np.linalg.norm(x[sp.pairs[:, 0]] - x[sp.pairs[:, 1]], axis=1)
        strain.append(np.max(length[stretch_shear] / sp.rest_length[stretch_shear]) - 1.0)
        dist = np.linalg.norm(x[:, None, :] - x[None, pins], axis=-1)
        reach.append(np.max(dist[octile > 0] / octile[octile > 0]))
    return {
        "energy": np.array(energies),
        "speed": np.array(speed),
        "strain": np.array(strain),
        "reach": np.array(reach),
        "scale": float(np.sum(m) * GRAVITY * 1.0),  # W L [J]: weight x size, the energy scale
    }


ENERGY_XFAIL = (
    "linearised backward Euler (one Newton step per frame) lets stiff springs that rotate lengthen by "
    "~(h v)^2 / 2L, storing ~k (h v)^4 / 8L^2 of spring energy; at k >= 1e5 N/m and dt = 1/60 s this "
    "exceeds the dissipation for a few frames (E - E0 = +0.03 J at 1e5, +0.32 J at 1e6, +65 J at 1e6 and "
    "dt = 1/30 s; none at dt = 1/120 s)"
)


def sweep_params(*, energy):
    """The five stiffnesses; 1e2 and 1e4 only with -m slow (each run is ~5 s)."""
    params = []
    for s in SCALES:
        marks = [pytest.mark.slow] if s in (0.1, 10.0) else []
        if energy and s >= 100.0:
            marks.append(pytest.mark.xfail(strict=True, raises=AssertionError, reason=ENERGY_XFAIL))
        params.append(pytest.param(s, marks=marks, id=f"k{1e3 * s:.0e}"))
    return params


@pytest.mark.parametrize("scale", sweep_params(energy=False))
def test_implicit_cloth_stays_bounded_at_every_stiffness(scale):
    # Backward Euler has no step limit: dt = 1/60 s is 20 (k = 1e2) to 2000 (k = 1e6) times the explicit
    # limit 2/omega_max here. The run finishes (DivergenceError would stop it); speeds stay near the
    # free-fall bound sqrt(2 g 1.4 m) = 5.3 m/s (20 m/s allowed: the whip of the free corners can exceed
    # it); and no vertex gets farther from a pin than the stretched spring path between them allows,
    # |x_i - x_p| <= (1 + max strain) x octile rest distance (a path of stretch and shear springs).
    run = stiffness_sweep_run(scale)
    print(
        f"max speed {run['speed'].max():.3g} m/s, max strain {run['strain'].max():.3g}, "
        f"max reach {run['reach'].max():.4g}"
    )
    assert np.all(np.isfinite(run["energy"]))
    assert run["speed"].max() < 20.0
    assert run["strain"].max() < 0.5
    assert np.all(run["reach"] <= 1.0 + np.maximum(run["strain"], 0.0) + 1e-9)
    # Net dissipation: after 10 s far less energy than at the start (spring damping only, no drag).
    assert run["energy"][-1] < run["energy"][0] - 0.1 * run["scale"]


@pytest.mark.parametrize("scale", sweep_params(energy=True))
def test_implicit_cloth_energy_never_exceeds_its_initial_value(scale):
    # Backward Euler is dissipative on linear(ised) damped springs: E_n <= E_0 at every step; the slack
    # 1e-3 W L (W the weight, L = 1 m) covers the spring energy of the PCG residual (tol 1e-4).
    run = stiffness_sweep_run(scale)
    excess = run["energy"].max() - run["energy"][0]
    print(f"max E - E0 = {excess:.4g} J (W L = {run['scale']:.3g} J)")
    assert excess <= 1e-3 * run["scale"]


@pytest.mark.parametrize(
    "scale, steps",
    [
        pytest.param(1000.0, 60, id="k1e+06-1s"),
        pytest.param(100.0, SWEEP_STEPS, id="k1e+05-10s", marks=pytest.mark.slow),
        pytest.param(1000.0, SWEEP_STEPS, id="k1e+06-10s", marks=pytest.mark.slow),
    ],
)
def test_newton_line_search_energy_never_exceeds_its_initial_value(scale, steps):
    # The xfails above with Newton iterations and the line search (implicit_euler.py): the step solves
    # the nonlinear backward-Euler system instead of its linearisation, so the energy that rotating
    # stiff springs store in the linearised step is gone: E_n <= E_0 + 1e-3 W L at every step. The
    # linearised step gains energy within the first 15 steps; 60 steps (1 s) in the default run.
    run = stiffness_sweep_run(scale, NEWTON, steps)
    excess = run["energy"].max() - run["energy"][0]
    print(f"max E - E0 = {excess:.4g} J (W L = {run['scale']:.3g} J)")
    assert excess <= 1e-3 * run["scale"]
    assert run["energy"][-1] < run["energy"][0]


# ---------------------------------------------------------------- explicit stability limit


def free_cloth(scale, copies=1):
    """An 8x8, 0.5 m cloth with no pins, gravity or damping: its rest state is an equilibrium."""
    b = ta.Builder()
    for _ in range(copies):
        b.add_cloth_grid(
            origin=(0, 1, 0),
            size=(0.5, 0.5),
            resolution=(8, 8),
            material=scaled_material(scale, damping=False),
        )
    return b.finalize()


def omega_max(scale):
    """Largest eigenfrequency of M^-1 K, K = -df/dx at rest by central differences of model.forces
    (all 3N columns at once on a model of 6N cloth copies)."""
    model = free_cloth(scale)
    n = model.particle_count
    x0 = model.state().positions()
    e = 1e-6
    basis = np.eye(3 * n).reshape(3 * n, n, 3)
    xs = np.concatenate([x0 + e * basis, x0 - e * basis]).reshape(-1, 3)
    f = free_cloth(scale, copies=6 * n).forces(xs, np.zeros_like(xs)).reshape(6 * n, 3 * n)
    k = -((f[: 3 * n] - f[3 * n :]) / (2 * e)).T
    assert np.abs(k - k.T).max() <= 1e-6 * np.abs(k).max()
    s = np.repeat(1.0 / np.sqrt(masses(model)), 3)
    return float(np.sqrt(np.linalg.eigvalsh(0.5 * (k + k.T) * s[:, None] * s[None, :]).max()))


def largest_stable_dt(scale, lo, hi, bisections=6, steps=2000):
    """Bisection on dt for symplectic Euler from rest plus a 1e-7 m random perturbation: stable if the
    displacement stays below 1e3 x the perturbation for `steps` steps (linear growth |lambda|^n of an
    unstable mode passes that within a few hundred steps; a stable mode's amplitude is bounded by
    1 / sqrt(1 - (h w / 2)^2), < 1e3 unless h w / 2 is within 1e-6 of 1)."""
    model = free_cloth(scale)
    state = model.state()
    integ = ta.IntegratorSymplecticEuler()
    integ.stepper_for(model).watchdog.disable()  # unstable runs are the point: this test stops them itself
    x0 = state.positions()
    pert = 1e-7 * np.random.default_rng(0).normal(size=x0.shape)
    limit = 1e3 * np.abs(pert).max()

    def stable(dt):
        # Checked every 20 steps, so an unstable run is stopped long before it overflows (a state that
        # went non-finite would keep reporting divergence).
        state.particle_x.from_numpy(x0 + pert)
        state.particle_v.from_numpy(np.zeros_like(x0))
        for k in range(steps):
            integ.step(model, state, dt)
            if k % 20 == 19 and np.abs(state.positions() - x0).max() > limit:
                return False
        return True

    assert stable(lo) and not stable(hi)
    for _ in range(bisections):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return lo, hi


def test_symplectic_euler_step_limit_is_two_over_omega_max():
    # Symplectic Euler on x'' = -M^-1 K x is stable iff h w < 2 for every mode (amplification matrix
    # [[1 - h^2 w^2, h], [-h w^2, 1]] has |trace| < 2), so h_max = 2 / w_max with w_max^2 = max eig M^-1 K.
    # All stiffnesses x100 -> w x10 -> h_max / 10.
    limits = {}
    for scale in (0.1, 10.0):
        w = omega_max(scale)
        predicted = 2.0 / w
        lo, hi = largest_stable_dt(scale, 0.8 * predicted, 1.25 * predicted)
        print(f"k x{scale}: w_max {w:.1f} rad/s, predicted {predicted:.4g} s, bracket [{lo:.4g}, {hi:.4g}]")
        # The bracket (0.7 % wide after 6 bisections) must hold the prediction.
        assert lo <= predicted * 1.001 and hi >= predicted * 0.999
        limits[scale] = 0.5 * (lo + hi)
    np.testing.assert_allclose(limits[0.1] / limits[10.0], 10.0, rtol=0.02)


# ---------------------------------------------------------------- fast cloth against a sphere

CENTER = np.array([0.0, 0.0, 0.0])
RADIUS = 0.3
THICKNESS = 0.005


def sphere_drop(name, mode, dt, steps):
    """A 12x12, 1 m cloth 5 cm above a ball of radius 0.3 m, all vertices at -20 m/s; gravity; the
    ball has friction 0.3. Returns per step the smallest |x - c| - R - thickness, the number of
    vertices over the ball's footprint (at the start) that are below its centre, the number in contact,
    and the smallest distance from the centre to any vertex's path over the step (segment from its start
    to its end) minus R + thickness."""
    b = ta.Builder()
    b.add_cloth_grid(
        origin=(-0.5, RADIUS + 0.05, -0.5),
        size=(1.0, 1.0),
        resolution=(12, 12),
        thickness=THICKNESS,
        velocity=(0.0, -20.0, 0.0),
    )
    b.add_force_gravity(G)
    b.add_collider_sphere(CENTER, RADIUS, friction=0.3)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator(name, collision_mode=mode)
    x0 = state.positions()
    over = np.linalg.norm(x0[:, [0, 2]] - CENTER[[0, 2]], axis=1) < RADIUS
    gap, below, contact, path = [], [], [], []
    x_prev = x0
    for _ in range(steps):
        integ.step(model, state, dt)
        x = state.positions()
        d = np.linalg.norm(x - CENTER, axis=1) - RADIUS - THICKNESS
        gap.append(d.min())
        contact.append(int(np.sum(d < 1e-6)))
        below.append(int(np.sum(x[over, 1] < CENTER[1])))
        seg = x - x_prev
        u = np.clip(
            np.sum((CENTER - x_prev) * seg, axis=1) / np.maximum(np.sum(seg * seg, axis=1), 1e-30), 0, 1
        )
        closest = x_prev + u[:, None] * seg
        path.append((np.linalg.norm(closest - CENTER, axis=1) - RADIUS - THICKNESS).min())
        x_prev = x
    return np.array(gap), np.array(below), np.array(contact), over.sum(), np.array(path)


@pytest.mark.parametrize("mode", ["projection", "backward"])
@pytest.mark.parametrize("name", ["symplectic_euler", "implicit_euler"])
def test_fast_cloth_never_penetrates_or_tunnels_through_a_sphere(name, mode):
    # dt = 2e-4 s is a quarter of symplectic Euler's limit for this cloth at rest (2 / w_max = 8.4e-4 s,
    # as in the test above; stretched springs lower it), and a vertex moves 4 mm per step at 20 m/s.
    # After every step each vertex (a sphere of radius thickness) is outside the ball,
    # |x - c| >= R + thickness up to round-off, and none of the vertices that start over the ball ends a
    # step below its centre (tunnelling). The frame-size step is the next test.
    steps = 250  # 50 ms: the cloth hits the ball after 2.5 ms and wraps it
    gap, below, contact, over, _ = sphere_drop(name, mode, 2e-4, steps)
    assert over > 0
    assert contact.max() > over // 2  # the cloth did hit the ball
    assert gap.min() >= -1e-12, gap.min()
    assert below.max() == 0


@pytest.mark.parametrize("mode", ["projection", "backward"])
def test_implicit_cloth_at_frame_steps_never_penetrates_the_sphere(mode):
    # The same drop at dt = 1/60 s: a vertex moves 0.33 m per step at 20 m/s, more than the ball's
    # radius. Backward mode sweeps each vertex's path; projection alone only sees where a step ends, so
    # it is checked for depth only (a vertex that jumps past the centre is pushed out the far side).
    gap, below, contact, over, path = sphere_drop("implicit_euler", mode, 1 / 60, 30)
    assert gap.min() >= -1e-12, gap.min()
    if mode == "backward":
        # No vertex's path over a step comes inside the grown ball (cloth may slide down its sides, so
        # "below the centre" is no test of tunnelling at these steps).
        assert contact.max() > over // 2 and path.min() >= -1e-9, path.min()
    else:
        assert below.max() > 0  # what the sweep is for: projection lets the cloth through


def test_backward_sweep_stops_particles_that_start_on_the_surface_by_round_off():
    # Three particles on the ball's grown surface |x - c| = R + r + eps (eps = +1e-14, 0, -1e-14 m: what
    # the projection leaves behind), each moving radially inward at 40 m/s, dt = 1/60 s: the segment
    # crosses the whole ball. The swept test must stop every one of them on its own side.
    directions = np.array([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0], [0.0, 0.8, -0.6]])
    eps = np.array([1e-14, 0.0, -1e-14])
    r = THICKNESS
    b = ta.Builder()
    b.add_particles(directions * (RADIUS + r + eps)[:, None], v=-40.0 * directions, mass=1.0, radius=r)
    b.add_collider_sphere(CENTER, RADIUS, restitution=0.0)
    model = b.finalize()
    state = model.state()
    ta.make_integrator("symplectic_euler", collision_mode="backward").step(model, state, 1.0 / 60.0)
    x = state.positions()
    side = np.sum(x * directions, axis=1)  # > 0: still on the side it started
    assert np.all(side > 0), side


def test_backward_collision_stops_a_particle_the_step_would_carry_through_the_ball():
    # 1 cm above the ball at 10 m/s, with an acceleration of 3000 m/s^2 (a stand-in for the spring
    # forces of a cloth at a large step): v1 = -60 m/s, the unconstrained step ends 1 m lower, past
    # the ball. It must end the step on top of the ball, not below it.
    r = THICKNESS
    b = ta.Builder()
    b.add_particles([[0.0, RADIUS + r + 0.01, 0.0]], v=[[0.0, -10.0, 0.0]], mass=1.0, radius=r)
    b.add_force_gravity((0.0, -3000.0, 0.0))
    b.add_collider_sphere(CENTER, RADIUS)
    model = b.finalize()
    state = model.state()
    ta.make_integrator("symplectic_euler", collision_mode="backward").step(model, state, 1.0 / 60.0)
    x = state.positions()[0]
    assert x[1] > CENTER[1] and np.linalg.norm(x - CENTER) >= RADIUS + r - 1e-12, x
