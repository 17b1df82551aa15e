"""Hard spheres: closed-form collisions (momentum, restitution, energy, Coulomb friction), Newton's
cradle, continuous contacts against tunnelling, a 10^4-sphere pile that comes to rest, and the grid
against brute force."""

import numpy as np
import pytest

import taichi_anim as ta


def spheres(x, v, *, mass=1.0, radius=0.1, gravity=False, box=None, **contacts):
    b = ta.Builder()
    if gravity:
        b.add_force_gravity()
    b.add_particles(np.asarray(x, float), np.asarray(v, float), mass=mass, radius=radius)
    if box is not None:
        b.add_collider_box(*box, restitution=0.5, friction=0.3)
    b.add_sphere_contacts(**contacts)
    model = b.finalize()
    return model, model.state()


def run(model, state, dt, steps, integrator="symplectic_euler", **options):
    integ = ta.make_integrator(integrator, **options)
    for _ in range(steps):
        integ.step(model, state, dt)
    LAST["contacts"] = integ.stepper_for(model).contacts
    return state.positions(), state.velocities()


LAST: dict = {}  # the contact solver of the last run (its neighbour structure and contact lists)


def contact_solver(model):
    """A sphere-contact solver of `model` (what a Stepper builds), for diagnostics between steps."""
    return ta.make_integrator("symplectic_euler").stepper_for(model).contacts


@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_head_on_unequal_masses(e):
    """m1 v1 + m2 v2 is conserved exactly and v2' - v1' = -e (v2 - v1) (Newton's law of restitution)."""
    m = np.array([1.0, 3.0])
    v0 = np.array([[2.0, 0, 0], [-1.0, 0, 0]])
    model, state = spheres([[-0.5, 0, 0], [0.5, 0, 0]], v0, mass=m, restitution=e, rest_speed=0.0)
    x, v = run(model, state, 0.01, 60)
    assert np.abs((m[:, None] * v).sum(0) - (m[:, None] * v0).sum(0)).max() < 1e-12
    assert (v[1, 0] - v[0, 0]) == pytest.approx(e * 3.0, abs=1e-12)
    v1 = (m @ v0[:, 0] - m[1] * e * 3.0) / m.sum()  # closed form: v1' = (p - m2 e (v1 - v2)) / M
    assert v[0, 0] == pytest.approx(v1, abs=1e-12)
    if e == 0.0:  # perfectly inelastic: they stay in contact, projected to exactly r1 + r2 apart
        assert x[1, 0] - x[0, 0] == pytest.approx(0.2, abs=1e-12)


def test_newtons_cradle_passes_the_impulse_down_the_row():
    """Five equal balls with 0.1 mm gaps, e = 1: the first stops, the last leaves with its speed."""
    r = 0.05
    x = [[k * (2 * r + 1e-4), 0, 0] for k in range(5)]
    v = np.zeros((5, 3))
    v[0, 0] = 1.0
    model, state = spheres(x, v, radius=r, restitution=1.0, rest_speed=0.0)
    _, v = run(model, state, 1e-3, 200)
    assert v[4, 0] == pytest.approx(1.0, abs=1e-9)
    assert np.abs(v[:4]).max() < 1e-9
    assert np.abs(v[:, 1:]).max() == 0.0


def test_oblique_elastic_collision_conserves_energy_and_momentum():
    """e = 1, frictionless, impact parameter half the contact distance, masses 1 and 2."""
    m = np.array([1.0, 2.0])
    v0 = np.array([[3.0, 0, 0], [0.0, 0, 0]])
    x0 = [[-0.6, 0.1, 0.0], [0.0, 0.0, 0.0]]
    model, state = spheres(x0, v0, mass=m, restitution=1.0, rest_speed=0.0)
    x, v = run(model, state, 1e-3, 400)
    ke0 = 0.5 * (m * (v0**2).sum(1)).sum()
    ke = 0.5 * (m * (v**2).sum(1)).sum()
    assert abs(ke - ke0) < 1e-12 * ke0
    assert np.abs((m[:, None] * (v - v0)).sum(0)).max() < 1e-12
    assert v[1, 1] < -0.1 and v[1, 0] > 0.1  # it really was oblique: the struck sphere moves off-axis
    # Frictionless: the struck sphere moves along the line of centres at impact, which is 30 degrees
    # below the x axis (impact parameter 0.1 = half the contact distance 0.2). The step detects the
    # contact up to 3 mm deep (v dt), which tilts the normal by a few mrad.
    n = np.array([np.cos(np.pi / 6), -np.sin(np.pi / 6), 0.0])
    assert np.arccos(v[1] @ n / np.linalg.norm(v[1])) < 0.01


@pytest.mark.parametrize("mu", [0.05, 2.0])
def test_friction_removes_at_most_mu_times_the_normal_change(mu):
    """Coulomb: |dv_t| = min(mu |dv_n|, |v_t|) on the relative velocity (sticks when mu is large)."""
    e = 0.5
    n = np.array([1.0, 0.0, 0.0])
    vrel0 = np.array([-2.0, 1.5, 0.0])  # relative velocity of sphere 1 w.r.t. sphere 0 (along -n: closing)
    model, state = spheres([[0, 0, 0], [0.2 - 1e-3, 0, 0]], [[0, 0, 0], vrel0], restitution=e, friction=mu)
    x, v = run(model, state, 1e-4, 1)
    # The projection moves the spheres along their line of centres, so the step's normal is the final one
    # (tilted 0.75 mrad from x by the step's tangential motion).
    n = (x[1] - x[0]) / np.linalg.norm(x[1] - x[0])
    vn0 = vrel0 @ n
    vt0 = vrel0 - vn0 * n
    vrel = v[1] - v[0]
    assert vrel @ n == pytest.approx(-e * vn0, abs=1e-12)
    vt = vrel - (vrel @ n) * n
    assert np.linalg.norm(vt) == pytest.approx(max(np.linalg.norm(vt0) + mu * (1 + e) * vn0, 0.0), abs=1e-12)


def test_sphere_rests_on_the_floor_at_its_radius():
    model, state = spheres([[0, 1.0, 0]], [[0, 0, 0]], radius=0.1, gravity=True, box=((-1, 0, -1), (1, 2, 1)))
    x, v = run(model, state, 1 / 240, 600)
    assert x[0, 1] == pytest.approx(0.1, abs=1e-9)
    assert np.abs(v).max() < 1e-9


def test_continuous_contacts_stop_fast_spheres_passing_through_each_other():
    """Two 1 cm spheres closing at 60 m/s with dt = 1/60: a step moves them 1 m, 50 diameters."""
    x = [[-0.5, 0, 0], [0.45, 0, 0]]
    v = [[30.0, 0, 0], [-30.0, 0, 0]]
    model, state = spheres(x, v, radius=0.01, restitution=1.0, rest_speed=0.0)
    xa, _ = run(model, state, 1 / 60, 1)
    assert xa[0, 0] > xa[1, 0]  # discrete contacts: they tunnelled through each other
    model, state = spheres(x, v, radius=0.01, restitution=1.0, rest_speed=0.0, continuous=True)
    xb, vb = run(model, state, 1 / 60, 1)
    assert contact_solver(model).substeps(model, state, 1 / 60) in (200, 201)  # 2 v dt / (r / 2), rounded up
    assert xb[0, 0] < xb[1, 0]
    assert vb[:, 0] == pytest.approx([-30.0, 30.0], abs=1e-9)


def test_continuous_contacts_stop_a_fast_sphere_at_a_thin_wall():
    b = ta.Builder()
    b.add_particle((0, 0, 0), (50.0, 0, 0), radius=0.01)
    b.add_collider_box((0.3, -1, -1), (0.302, 1, 1), solid=True, restitution=1.0)
    b.add_sphere_contacts(continuous=True, max_substeps=512)
    model = b.finalize()
    state = model.state()
    x, v = run(model, state, 1 / 60, 1)
    assert x[0, 0] <= 0.3 - 0.01 + 1e-9
    assert v[0, 0] == pytest.approx(-50.0)


def test_too_few_substeps_is_a_warning_naming_the_limit():
    model, state = spheres([[0, 0, 0]], [[50.0, 0, 0]], radius=0.01, continuous=True, max_substeps=8)
    with pytest.warns(RuntimeWarning, match="capped at max_substeps=8"):
        run(model, state, 1 / 60, 1)


def pile(n_side, layers, r, seed=0):
    """Spheres on a jittered lattice above the floor of a box n_side spheres wide, random velocities."""
    g = np.stack(np.meshgrid(*(np.arange(k) for k in (n_side, layers, n_side)), indexing="ij"), -1)
    g = g.reshape(-1, 3)
    half = n_side * 1.1 * r + r
    rng = np.random.default_rng(seed)
    x = (
        g * 2.2 * r
        + np.array([-half + 2 * r, 2 * r, -half + 2 * r])
        + rng.uniform(-0.1 * r, 0.1 * r, g.shape)
    )
    v = rng.normal(0.0, 0.3, g.shape)
    return x, v, ((-half, 0.0, -half), (half, 1.0, half))


@pytest.mark.parametrize("side, layers", [(25, 4), pytest.param(45, 5, marks=pytest.mark.slow)])
def test_a_pile_of_spheres_comes_to_rest(side, layers):
    """side x side x layers spheres (r = 1 cm; 2,500, and 10,125 in the slow run) fall into a box: no
    NaN, kinetic energy decays to a small fraction of the potential energy they lost, the largest overlap
    ends below 1% of the radius."""
    r, m = 0.01, 1e-3
    x, v, box = pile(side, layers, r)
    assert len(x) == side * side * layers
    model, state = spheres(x, v, mass=m, radius=r, gravity=True, box=box, friction=0.3)
    assert contact_solver(model).neighbors.method.value == "grid"
    integ = ta.make_integrator("symplectic_euler", check_every=100)
    dt = 1 / 3600
    kinetic = []
    for step in range(2700):  # 0.75 s
        integ.step(model, state, dt)  # raises DivergenceError on any NaN
        if step % 300 == 299:
            vs = state.velocities()
            kinetic.append(0.5 * m * (vs**2).sum())
    xs = state.positions()
    released = m * 9.81 * (x[:, 1] - xs[:, 1]).sum()
    assert released > 0.5
    assert kinetic[-1] < 0.01 * released and kinetic[-1] < kinetic[2]
    overlap, contacts = contact_solver(model).overlap_stats(model, state)
    assert contacts > 2 * len(x)  # a real pile: every sphere touches several others
    assert overlap < 0.01 * r
    lo, hi = np.array(box[0]), np.array(box[1])
    assert np.all(xs >= lo + r - 1e-6) and np.all(xs <= hi - r + 1e-6)


@pytest.mark.slow  # 18 s on 2 cores; test_neighbors.py checks every structure against brute force
def test_grid_hash_grid_and_brute_force_agree():
    """The same falling pile with each neighbour structure: the same contacts, so the same motion."""
    r = 0.01
    x, v, box = pile(12, 6, r, seed=3)
    out = {}
    for method in ("brute", "grid", "hash_grid"):
        model, state = spheres(x, v, radius=r, gravity=True, box=box, neighbor_search=method)
        assert contact_solver(model).neighbors.method.value == method
        out[method], _ = run(model, state, 1 / 1200, 150)
    moved = np.abs(out["brute"] - x).max()
    assert moved > 2 * r
    # Each structure lists a sphere's neighbours in another order, so the contact sums differ in round-off
    # (f64: ~1e-17 m), which 150 steps of a pile's collisions amplify: up to 4e-8 m seen on a loaded
    # machine (1e-9 held on an idle one). A contact one structure missed would differ by a step's
    # overlap push, ~1e-4 m: the bound sits between, at 1e-6 m.
    assert np.abs(out["grid"] - out["brute"]).max() < 1e-6
    assert np.abs(out["hash_grid"] - out["brute"]).max() < 1e-6


@pytest.mark.slow  # 14 s on 2 cores; the mixed-sphere case below checks the same at one and two threads
def test_same_result_on_one_and_two_threads():
    r = 0.01
    x, v, box = pile(20, 4, r, seed=5)

    def result(threads):
        ta.init("cpu", precision="f32", cpu_threads=threads)
        model, state = spheres(x, v, radius=r, gravity=True, box=box, iterations=2)
        return run(model, state, 1 / 1200, 100)[0]

    assert np.array_equal(result(1), result(2))


def test_bad_sphere_input_is_rejected():
    with pytest.raises(ta.ParameterError, match="radius > 0"):
        spheres([[0, 0, 0]], [[0, 0, 0]], radius=0.0)
    with pytest.raises(ta.ParameterError, match="radius"):
        spheres([[0, 0, 0]], [[0, 0, 0]], radius=-0.1)
    with pytest.raises(ta.ParameterError, match="relaxation"):
        spheres([[0, 0, 0]], [[0, 0, 0]], relaxation=3.0)
    with pytest.raises(ta.ParameterError, match="neighbor_search"):
        spheres([[0, 0, 0]], [[0, 0, 0]], neighbor_search="octree")
    with pytest.raises(ta.ParameterError, match="restitution"):
        spheres([[0, 0, 0]], [[0, 0, 0]], restitution=1.5)
    with pytest.raises(ta.ParameterError, match="radius must be a scalar or one value per particle"):
        spheres([[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [0, 0, 0]], radius=[0.1, 0.1, 0.1])
    with pytest.raises(ta.ParameterError, match="neighbor_search='grid' needs a container"):
        spheres([[0, 0, 0]], [[0, 0, 0]], neighbor_search="grid")


def test_velocity_sweep_contact_list_and_its_fallback_agree(monkeypatch):
    """The velocity sweep walks each sphere's listed contacts, or its cells when it has more than the
    list holds: both visit the same pairs in the same order (differences are round-off only: the two
    loops are compiled with different fused multiply-adds)."""
    import taichi_anim.collision.spheres as spheres_module

    r = 0.01
    x, v, box = pile(10, 5, r, seed=7)

    def result():
        model, state = spheres(x, v, radius=r, gravity=True, box=box, neighbor_search="grid")
        out = run(model, state, 1 / 600, 120)  # coarse steps: deep overlaps, many contacts each
        return out, LAST["contacts"].slot_contact_count.to_numpy().max()

    listed, most = result()
    ta.init("cpu", precision="f64")
    monkeypatch.setattr(spheres_module, "CONTACTS_KEPT", 1)  # spheres with 2+ contacts fall back
    fallback, _ = result()
    assert most >= 4
    assert np.abs(listed[0] - fallback[0]).max() < 1e-11
    assert np.abs(listed[1] - fallback[1]).max() < 1e-9
    assert np.abs(listed[0] - x).max() > 2 * r


def test_unequal_spheres_starting_in_contact_conserve_momentum():
    """Per-particle radii and masses (the solver's per-slot path), 5 cm overlapped at rest: one step
    separates them to r1 + r2 by inverse-mass shares without creating momentum."""
    m = np.array([1.0, 3.0])
    model, state = spheres([[0, 0, 0], [0.25, 0, 0]], [[0, 0, 0], [0, 0, 0]], mass=m, radius=[0.1, 0.2])
    x, v = run(model, state, 0.01, 1)
    assert np.abs(m @ v).max() < 1e-12
    assert x[1, 0] - x[0, 0] == pytest.approx(0.3, abs=1e-12)
    assert x[0, 0] == pytest.approx(-0.05 * 3 / 4, abs=1e-12)  # the light sphere moves 3/4 of it


def test_mixed_spheres_same_result_on_one_and_two_threads():
    r = 0.01
    x, v, box = pile(16, 4, r, seed=9)
    rng = np.random.default_rng(1)
    radius = r * rng.uniform(0.7, 1.0, len(x))
    mass = rng.uniform(0.5, 2.0, len(x)) * 1e-3

    def result(threads):
        ta.init("cpu", precision="f32", cpu_threads=threads)
        model, state = spheres(x, v, mass=mass, radius=radius, gravity=True, box=box, neighbor_search="grid")
        return run(model, state, 1 / 1200, 100)[0]

    a = result(2)
    assert np.array_equal(a, result(1)) and np.array_equal(a, result(2))


def test_coincident_spheres_come_apart():
    model, state = spheres([[0, 0, 0], [0, 0, 0]], [[0, 0, 0], [0, 0, 0]], radius=0.1)
    x, _ = run(model, state, 0.01, 1)
    assert np.linalg.norm(x[1] - x[0]) == pytest.approx(0.2, abs=1e-9)  # along x, from a 1e-12 seed gap


def test_points_and_spheres_share_a_scene_with_continuous_contacts():
    b = ta.Builder()
    b.add_particles([[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [0, 0, 0]], radius=[0.0, 0.1])
    b.add_sphere_contacts(continuous=True)
    model = b.finalize()
    assert contact_solver(model).min_radius == 0.1
    state = model.state()
    run(model, state, 0.01, 2)
    assert contact_solver(model).overlap_stats(model, state) == (0.0, 0)


@pytest.mark.parametrize("iterations", [1, 2, 8, 16])
def test_dense_random_pile_conserves_momentum_for_any_number_of_sweeps(iterations):
    """300 spheres of random radii (3.5-5 cm) and masses (0.5-2 kg), dropped at random into a 0.4 m cube
    (deep overlaps; some spheres touch more than the contact list holds), random velocities, no gravity,
    no walls: total momentum is conserved to round-off by every step, whatever the number of sweeps
    (each pair's correction is scaled the same on both sides; Baraff's equal and opposite impulses)."""
    rng = np.random.default_rng(11)
    n = 300
    x = rng.uniform(0.0, 0.4, (n, 3))
    v = rng.normal(0.0, 1.0, (n, 3))
    m = rng.uniform(0.5, 2.0, n)
    model, state = spheres(x, v, mass=m, radius=rng.uniform(0.035, 0.05, n), iterations=iterations)
    p0 = m @ v
    scale = m @ np.linalg.norm(v, axis=1)
    integ = ta.make_integrator("symplectic_euler")
    most = 0
    for _ in range(20):
        integ.step(model, state, 1e-3)
        assert np.abs(m @ state.velocities() - p0).max() < 1e-13 * scale
        most = max(most, integ.stepper_for(model).contacts.slot_contact_count.to_numpy().max())
    assert most > 16  # the cells fallback ran too
    moved = np.abs(state.positions() - x - 0.02 * v).max()
    assert moved > 0.01  # the contacts really moved the spheres


def test_near_lists_and_the_cells_agree(monkeypatch):
    """Later sweeps walk each sphere's near list (candidates within r_i + r_j + a margin in the
    prediction) while no pair can have closed the margin, else its cells: the same pairs in the same
    order, so the same motion to round-off (the loops are compiled with different fused multiply-adds),
    both in a pile settling (lists used: the sweeps drift less than the margin) and from deep overlaps
    (the first sweeps move spheres past the margin: cells used)."""
    from taichi_anim.collision.spheres import ContactSpheres

    r = 0.01
    x, v, box = pile(10, 5, r, seed=11)
    deep = x.copy()
    deep[1::2] = x[0::2] + [0.3 * r, 0.0, 0.0]  # sphere pairs 0.3 r apart: overlaps of 1.7 r

    def result(start, use_lists):
        ta.init("cpu", precision="f64")
        monkeypatch.setattr(ContactSpheres, "use_near_lists", use_lists)
        model, state = spheres(
            start, v, radius=r, gravity=True, box=box, neighbor_search="grid", iterations=4
        )
        integ = ta.make_integrator("symplectic_euler")
        drift = []
        for _ in range(60):  # a chaotic pile: later, round-off differences grow past the tolerance
            integ.step(model, state, 1 / 1200)
            drift.append(float(integ.stepper_for(model).contacts.drift[None]))
        return state.positions(), state.velocities(), np.array(drift)

    for start in (x, deep):
        xl, vl, drift = result(start, True)
        xc, vc, _ = result(start, False)
        assert np.abs(xl - xc).max() < 1e-11
        assert np.abs(vl - vc).max() < 1e-9
        assert np.abs(xl - start).max() > r
        margin = 0.45 * 0.5 * r  # a sphere's own drift + the largest < 0.9 x NEAR_MARGIN x r
        if start is x:
            assert (drift < margin).mean() > 0.9  # the lists served most steps
        else:
            assert drift[0] > margin  # the first step's sweeps went past the margin: cells
