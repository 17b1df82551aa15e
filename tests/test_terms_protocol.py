"""The term protocol and the static model: a scene holds (and its solvers allocate) only the terms it
added; solvers own their scratch; element terms mix under every integrator; the implicit system of mixed
terms is the linearisation of their forces; and the continuum cloth's energy behaviour."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim.scenes import make_scene

G = (0.0, -9.81, 0.0)
FABRIC = ta.FabricMaterial(youngs_modulus=1e3, poisson_ratio=0.3, bending_stiffness=1e-4, damping=0.0)
# Explicit Euler grows every undamped oscillation: with Rayleigh damping beta it is stable for dt < beta.
DAMPED = ta.FabricMaterial(youngs_modulus=1e3, bending_stiffness=1e-4, damping=1e-3, bending_damping=1e-2)


def sheet(material, n=6, *, aero=False, pinned=(0,), springs_too=False):
    """An n x n vertical 0.3 m sheet with gravity (and aerodynamics), pinned at `pinned`."""
    b = ta.Builder()
    b.add_force_gravity(G)
    cloth = b.add_cloth_grid(
        origin=(0, 1, 0), size=(0.3, 0.3), resolution=(n, n), plane="xy", material=material, pinned=pinned
    )
    if springs_too:  # springs on the same vertices as the membrane: a mixed model
        tri = cloth.triangles
        edges = np.unique(
            np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1), axis=0
        )
        b.add_springs(edges, stiffness=200.0, damping=0.01)
    if aero:
        b.add_force_aerodynamics(cloth, wind=(3.0, 0.0, 2.0), drag_coefficient=1.0, lift_coefficient=0.5)
    return b.finalize()


def test_only_the_terms_a_scene_adds_are_in_its_model_and_solvers():
    particles = ta.Builder()
    particles.add_particles(np.zeros((4, 3)))
    particles.add_force_gravity(G)
    model = particles.finalize()
    integ = ta.make_integrator("implicit_euler")
    ta.Stepper(model, integ)
    assert [type(t).__name__ for t in model.terms] == ["Gravity"]
    assert model.element_terms == () and not model.coupled and integ.caches == () and integ.system is None

    model = sheet(ta.ClothMaterial())
    integ = ta.make_integrator("implicit_euler")
    ta.Stepper(model, integ)
    assert [type(t).__name__ for t in model.element_terms] == ["Springs"]
    assert len(integ.caches) == 1 and integ.caches[0].ab is not None  # implicit: a linearisation cache

    model = sheet(FABRIC, aero=True)
    names = [type(t).__name__ for t in model.element_terms]
    assert names == ["MembraneStVK", "BendingDihedral", "AeroTriangles"] and model.springs is None
    explicit = ta.make_integrator("symplectic_euler")
    ta.Stepper(model, explicit)
    assert all(c.kxv is None for c in explicit.caches)  # explicit methods allocate forces only
    kinds = [f["type"] for f in model.settings["forces"]]
    assert kinds == ["gravity", "membrane_stvk", "bending_dihedral", "aero_triangles"]


def test_two_integrators_on_one_model_share_no_scratch():
    """Implicit PCG warm-starts from its own last solution: stepping two states of one model with two
    integrators, interleaved, gives bit for bit what each gives alone (shared scratch would mix them)."""
    model = sheet(ta.ClothMaterial())  # springs: the PCG warm start is the scratch under test
    kick = np.zeros((model.particle_count, 3))
    kick[-1] = (0.0, 0.0, 2.0)
    starts = (np.zeros_like(kick), kick)
    integs = [ta.make_integrator("implicit_euler", tol=1e-3) for _ in starts]

    def fresh(v0, integ):
        s = model.state()
        s.particle_v.from_numpy(v0)
        integ.stepper_for(model)  # bound: its warm start can be cleared
        integ.system.solution.fill(0.0)
        return s

    alone = []
    for v0, integ in zip(starts, integs, strict=True):
        s = fresh(v0, integ)
        for _ in range(6):
            integ.step(model, s, 1 / 120)
        alone.append(s.positions())
    states = [fresh(v0, integ) for v0, integ in zip(starts, integs, strict=True)]
    for _ in range(6):
        for s, integ in zip(states, integs, strict=True):
            integ.step(model, s, 1 / 120)
    for s, x in zip(states, alone, strict=True):
        assert np.array_equal(s.positions(), x)
    assert not np.array_equal(alone[0], alone[1])


@pytest.mark.slow  # eight integrators compiled for four mixed terms (~100 s); cloth orders: default run
def test_mixed_terms_converge_under_every_integrator():
    """Springs + membrane + bending + aerodynamics on one sheet, 0.05 s: every explicit method against
    an RK4 reference at a 16x smaller step, errors ordered by the methods' orders; implicit Euler with
    Jacobi, CG and PCG at the same step agree with each other to their tolerance."""
    model = sheet(DAMPED, aero=True, springs_too=True)
    x0 = model.state().positions()
    T, h = 0.02, 1e-4

    def run(name, dt, **opts):
        s = model.state()
        integ = ta.make_integrator(name, **opts)
        for _ in range(round(T / dt)):
            integ.step(model, s, dt)
        return s.positions()

    ref = run("rk4", h / 4)  # RK4's error at h/4 is ~1/256 of its error at h
    moved = np.abs(ref - x0).max()
    assert moved > 1e-3  # the sheet moved: the comparison means something
    err = {
        m: np.abs(run(m, h) - ref).max() for m in ("explicit_euler", "symplectic_euler", "midpoint", "rk4")
    }
    assert err["rk4"] < err["midpoint"] < err["symplectic_euler"]
    assert err["rk4"] < 1e-8 * moved and err["midpoint"] < 1e-4 * moved
    assert err["symplectic_euler"] < 1e-2 * moved and err["explicit_euler"] < 1e-2 * moved
    # implicit Euler: first order; the three linear solvers solve the same system
    implicit = {
        s: run("implicit_euler", h, linear_solver=s, tol=1e-9, max_iterations=2000)
        for s in ("jacobi", "cg", "pcg")
    }
    assert np.abs(implicit["cg"] - implicit["pcg"]).max() < 1e-7 * moved  # both to rel. residual 1e-9
    assert np.abs(implicit["jacobi"] - implicit["pcg"]).max() < 1e-6 * moved
    assert np.abs(implicit["pcg"] - ref).max() < 1e-2 * moved


# with springs is the membrane, hinges and springs together; the membrane and hinges alone under slow
@pytest.mark.parametrize("with_springs", [pytest.param(False, marks=pytest.mark.slow), True])
def test_implicit_system_is_the_linearisation_of_the_forces(with_springs):
    """A p = M p - h df/dv p - h^2 df/dx p with the Jacobians by central differences of model.forces, at a
    flat, uniformly stretched sheet at rest (every projection exact there: membrane stress positive,
    hinges at their rest angle, springs stretched); pinned rows are 0."""
    model = sheet(
        ta.FabricMaterial(youngs_modulus=1e3, bending_stiffness=1e-4, damping=2e-3), springs_too=with_springs
    )
    rng = np.random.default_rng(1)
    x0 = model.state().positions()
    x = x0 * np.array([1.02, 1.01, 1.0])  # stretched 2% in x and 1% in y, still flat (z = 0)
    # At rest: the damping forces' x-derivative (left out of the system, as Baraff & Witkin do) is 0 there.
    v = np.zeros_like(x)
    h = 1e-2
    integ = ta.make_integrator("implicit_euler")
    ta.Stepper(model, integ)
    integ.system.assemble(x, v, h)
    p = rng.normal(size=x.shape)
    ap = integ.system.matvec(p)
    eps = 1e-6
    dfdx_p = (model.forces(x + eps * p, v) - model.forces(x - eps * p, v)) / (2 * eps)
    dfdv_p = (model.forces(x, v + eps * p) - model.forces(x, v - eps * p)) / (2 * eps)
    m = model.particle_masses()[:, None]
    expect = m * p - h * dfdv_p - h * h * dfdx_p
    free = model.particle_masses() > 0
    assert np.all(ap[~free] == 0.0)
    scale = np.abs(expect[free]).max()
    assert np.abs(ap[free] - expect[free]).max() < 1e-6 * scale


def test_undamped_membrane_keeps_its_energy_under_symplectic_euler():
    """No damping, no dissipation: kinetic + membrane + bending + gravity energy of a swinging sheet
    stays within 1% of its start over 1 s at dt well under the stability limit (symplectic Euler's
    energy error is bounded and O(dt))."""
    model = sheet(FABRIC, n=8)
    s = model.state()
    integ = ta.make_integrator("symplectic_euler", check_every=100)
    masses = model.particle_masses()

    def total():
        x, v = s.positions().astype(np.float64), s.velocities().astype(np.float64)
        e = model.energy(x, v)
        return e["kinetic"] + e["membrane_stvk"] + e["bending_dihedral"] - float(masses @ (x @ np.array(G)))

    e0 = total()
    drift = []
    for _ in range(50):
        for _ in range(50):
            integ.step(model, s, 4e-4)
        drift.append(total() - e0)
    fallen = float(masses @ (model.state().positions() - s.positions())[:, 1])
    assert fallen > 0.0  # it swung down: energy moved from gravity into motion and strain
    scale = float(masses.sum() * 9.81 * 0.3)  # the sheet's potential energy range [J]
    assert np.max(np.abs(drift)) < 0.01 * scale


@pytest.mark.slow  # ~1.5 min; the flag demo and the hard cases cover implicit frame steps by default
def test_implicit_euler_never_diverges_at_frame_steps_on_the_stiffest_demo_fabric():
    """The flag's fabric (E = 2e3 N/m) and a 10x stiffer one, in wind, at dt = 1/60 for 3 s: finite,
    every edge within 1.5x its rest length, no vertex faster than the wind allows."""
    for youngs in (2e3, 2e4):
        ta.init("cpu", precision="f32")
        scene = make_scene("flag", resolution=12, youngs_modulus=youngs)
        model, state = scene.model, scene.state
        integ = ta.make_integrator("implicit_euler", tol=1e-3)
        x0, tri, _ = scene.cloth_mesh()
        e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        rest = np.linalg.norm(x0[e[:, 0]] - x0[e[:, 1]], axis=1)
        for _ in range(180):
            integ.step(model, state, 1 / 60)
        x = state.positions()
        v = state.velocities()
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(v))
        assert np.all(np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) < 1.5 * rest)
        assert np.abs(v).max() < 30.0


def test_curved_mesh_fabric_keeps_its_rest_shape():
    """A half-cylinder garment panel from add_cloth_mesh with a FabricMaterial: at its rest shape the
    membrane and bending forces vanish (rest lengths and rest angles come from the input mesh), so only
    gravity acts; a flattened copy of the same mesh is pushed back towards the curve."""
    nu, nv, radius = 9, 4, 0.2
    u, v = np.meshgrid(np.linspace(0.0, np.pi, nu), np.linspace(0.0, 0.3, nv))
    x = np.stack([radius * np.cos(u.ravel()), radius * np.sin(u.ravel()), v.ravel()], axis=1)
    tri = []
    for j in range(nv - 1):
        for i in range(nu - 1):
            a, b, c, d = j * nu + i, j * nu + i + 1, (j + 1) * nu + i, (j + 1) * nu + i + 1
            tri += [(a, b, d), (a, d, c)]
    b = ta.Builder()
    b.add_cloth_mesh((x, np.array(tri)), material=FABRIC, pinned=[0])
    model = b.finalize()
    kinds = [t.settings()["type"] for t in model.element_terms]
    assert kinds == ["membrane_stvk", "bending_dihedral"]
    f = model.forces(x, np.zeros_like(x))
    assert np.abs(f).max() < 1e-9
    e = model.energy(x)
    assert e["membrane_stvk"] < 1e-18 and e["bending_dihedral"] < 1e-18
    bent = x.copy()
    bent[:, 1] *= 0.9  # flatten the curve by 10%: bending (and membrane) push back
    f = model.forces(bent, np.zeros_like(x))
    assert model.energy(bent)["bending_dihedral"] > 0.0
    top = np.argmax(x[:, 1] - 1e-3 * np.abs(x[:, 0]))  # a vertex on the crown
    assert f[top, 1] > 0.0  # pushed up, back towards the rest curve
