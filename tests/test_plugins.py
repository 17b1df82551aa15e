"""Parts written outside the package — a force term, a collider and an integrator defined here — are
guarded by the watchdog, exported to USD and bounded by the stability guard exactly like the built-in
ones, because those ask the part (its energy and bounds, its points, surface and speed, its stability
region), never its class; a part that lacks what they need is refused with a message naming it."""

import math
import warnings

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim import stability
from taichi_anim.collision.colliders import GRAZING, NO_HIT, ON_SURFACE, ColliderAnalytic, plane_square
from taichi_anim.stability import StabilityRegion


@ti.data_oriented
class ToySpringToOrigin(ta.PointTerm):
    """f = -k x: a spring from every particle to the origin, energy k |x|^2 / 2."""

    energy_kind = "potential"

    def __init__(self, k: float):
        self.k = float(k)

    @ti.func
    def force(self, i, m, x, v, t):
        return -self.k * x

    @ti.func
    def jacobian(self, i, m, x, v, t):
        return -self.k * ti.Matrix.identity(float, 3), ti.Matrix.zero(float, 3, 3)

    def energy(self, x, masses) -> float:
        return 0.5 * self.k * float(np.sum(np.asarray(x, dtype=np.float64) ** 2))


@ti.data_oriented
class ToyTiltedPlane(ColliderAnalytic):
    """The half-space direction . x < height is solid (attribute names of its own, so that nothing can
    recognise it by them)."""

    kind = "tilted_plane"

    def __init__(self, direction, height: float, motion=None):
        d = np.asarray(direction, dtype=np.float64)
        self.direction = tuple(float(c) for c in d / np.linalg.norm(d))
        self.height = float(height)
        self.restitution = 0.0
        self.friction = 0.0
        self.motion = motion

    def settings(self) -> dict:
        return self._settings(type="tilted_plane", direction=self.direction, height=self.height)

    def local_points(self):
        return np.asarray(self.direction)[None, :] * self.height

    def surface(self, bounds=None):
        return plane_square(np.asarray(self.direction), self.height, bounds)

    @ti.func
    def _sdf(self, x):
        return ti.Vector(self.direction, dt=float).dot(x) - self.height

    @ti.func
    def _normal(self, x):
        return ti.Vector(self.direction, dt=float)

    @ti.func
    def _sweep(self, x0, x1, r):
        d0 = self._sdf(x0) - r
        d1 = self._sdf(x1) - r
        tau = NO_HIT
        if d0 >= -ON_SURFACE and d1 < 0.0 and d0 - d1 > GRAZING * (x1 - x0).norm():
            tau = ti.max(d0, 0.0) / (ti.max(d0, 0.0) - d1)
        return tau, ti.Vector(self.direction, dt=float)


def adjoint_euler_map(h, w, c):
    """One step of ToyAdjointEuler on y'' = -w^2 y - c y': y1 = y + h v, v1 = v + h (-w^2 y1 - c v)."""
    m = np.empty((len(w), 2, 2))
    m[:, 0, 0], m[:, 0, 1] = 1.0, h
    m[:, 1, 0], m[:, 1, 1] = -h * w * w, 1.0 - h * c - h * h * w * w
    return m


@ti.data_oriented
class ToyAdjointEuler(ta.Integrator):
    """Symplectic Euler's adjoint (position first): x1 = x0 + h v0, v1 = v0 + h a(x1, v0); pointwise
    forces only. Its stability region is given by its one-step matrix."""

    name = "toy_adjoint_euler"
    order = 1
    stability_region = StabilityRegion.from_step_matrix(adjoint_euler_map)

    @ti.func
    def update(self, model: ti.template(), i, x0, v0, t, h):
        x1 = x0 + h * v0
        return x1, v0 + h * model.accel(i, x1, v0, t + h)


def add_collider(builder, collider):
    """Builder.add_collider(collider): the public way in for a user's collider."""
    builder.add_collider(collider)


def spring_scene(k: float):
    b = ta.Builder()
    b.add_particles([[1.0, 0.0, 0.0]], mass=1.0)
    b.add_force(ToySpringToOrigin(k))
    return b.finalize()


# ---------------------------------------------------------------------------------------------- term


def test_toy_term_is_guarded_by_the_watchdog():
    """The term's energy enters the watchdog: v_ref = sqrt(2 E_el / m) = sqrt(k) (E_el = k/2 at |x| = 1,
    m = 1), above the 1 m/s floor; the energy check is on and E = KE + k |x|^2 / 2."""
    model = spring_scene(100.0)
    state = model.state()
    integ = ta.make_integrator("symplectic_euler")
    integ.step(model, state, 1e-3)
    wd = integ.stepper_for(model).watchdog
    assert wd.derived["v_ref"] == pytest.approx(10.0, rel=1e-12)
    assert wd.describe()["energy_checked"] is True
    x, v = state.positions(), state.velocities()
    assert wd._energy(state) == pytest.approx(0.5 * (v**2).sum() + 50.0 * (x**2).sum(), rel=1e-12)


def test_toy_term_diverging_raises_before_anything_is_non_finite():
    """Symplectic Euler at h w = 2.5 (beyond its limit 2): the amplitude grows geometrically and the
    watchdog stops the run on a finite value."""
    model = spring_scene(100.0)
    state = model.state()
    integ = ta.make_integrator("symplectic_euler")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ta.StabilityWarning)
        with pytest.raises(ta.DivergenceError) as info:
            for _ in range(200):
                integ.step(model, state, 0.25)
    assert info.value.quantity in ("speed", "energy", "position")
    assert math.isfinite(info.value.value)


def test_toy_term_passes_the_finite_difference_check():
    x = np.random.default_rng(1).standard_normal((4, 3))
    errors = ta.terms.check_term(ToySpringToOrigin(3.0), x, np.ones((4, 3)))
    assert errors["jacobian_x"] < 1e-8 and errors["jacobian_v"] == 0.0
    assert errors["energy_gradient"] < 1e-8


# ------------------------------------------------------------------------------------------ collider


def test_toy_collider_stops_particles_and_bounds_the_watchdog():
    """A particle falling onto the tilted plane ends on it (sdf >= -1e-9), and the plane moving at
    3 m/s makes the watchdog's reference speed 3 m/s."""
    n = np.array([0.3, 1.0, 0.0]) / np.linalg.norm([0.3, 1.0, 0.0])
    b = ta.Builder()
    b.add_particles([[0.0, 0.5, 0.0]], mass=1.0)
    b.add_force_gravity()
    add_collider(b, ToyTiltedPlane(n, 0.0))
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator("symplectic_euler")
    for _ in range(100):
        integ.step(model, state, 1e-2)
    assert float(state.positions()[0] @ n) >= -1e-9

    b = ta.Builder()
    b.add_particles([[0.0, 0.5, 0.0]], mass=1.0)
    add_collider(
        b, ToyTiltedPlane(n, 0.0, motion=ta.RigidMotion([0.0, 1.0], [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]))
    )
    model = b.finalize()
    integ = ta.make_integrator("symplectic_euler")
    integ.step(model, model.state(), 1e-3)
    wd = integ.stepper_for(model).watchdog
    assert wd.derived["v_ref"] == pytest.approx(3.0, rel=1e-12)
    assert "ToyTiltedPlane" in wd.describe()["energy_unchecked"]


def test_toy_collider_is_exported_to_usd(tmp_path):
    """The stage holds /World/colliders/tilted_plane0: a mesh of the collider's own surface, with its
    kind in the custom data, and its motion as transform samples."""
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    from taichi_anim.io.usd import write_usd

    n = (0.0, 1.0, 1.0)
    motion = ta.RigidMotion([0.0, 1.0], [[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    toy = ToyTiltedPlane(n, 0.5, motion=motion)
    bounds = (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))
    path = write_usd(tmp_path / "toy.usda", [(1.0, [])], fps=1.0, colliders=[toy], bounds=bounds)
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/World/colliders/tilted_plane0")
    assert prim.IsValid() and prim.IsA(UsdGeom.Mesh)
    assert prim.GetCustomDataByKey("taichi_anim:collider")["kind"] == "tilted_plane"
    points = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(), dtype=np.float64)
    np.testing.assert_allclose(points, toy.surface(bounds)[0], atol=1e-6)
    world = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(1.0)
    assert world.ExtractTranslation()[1] == pytest.approx(2.0)


# ---------------------------------------------------------------------------------------- integrator


def test_toy_integrator_is_bounded_by_its_declared_region():
    """Its step matrix has symplectic Euler's trace and determinant, so its undamped limit is 2 / w; the
    guard reports a step beyond it, and below it the method keeps the oscillator's energy bounded."""
    w = 10.0
    toy = ToyAdjointEuler()
    # At h w = 2 the eigenvalues of the step matrix coincide: a defective matrix's eigenvalues carry
    # sqrt(machine epsilon) of error, so the limit from them is good to ~1e-7, not to round-off.
    assert stability.stability_limit(toy, w) == pytest.approx(2.0 / w, rel=1e-6)
    assert stability.stability_limit(toy, w, 0.05) == pytest.approx(
        stability.stability_limit("symplectic_euler", w, 0.05), rel=1e-6
    )
    model = spring_scene(w * w)
    with pytest.warns(
        ta.StabilityWarning, match="toy_adjoint_euler: dt = 0.22 s exceeds the stability limit 0.2 s"
    ):
        toy.step(model, model.state(), 0.22)
    state = model.state()
    period = 2.0 * math.pi / w
    for _ in range(round(period / 0.01)):
        toy.step(model, state, 0.01)
    x, v = state.positions()[0], state.velocities()[0]
    energy = 0.5 * v @ v + 0.5 * w * w * x @ x  # starts at k / 2 = 50 J
    assert abs(energy - 50.0) <= 50.0 * 0.1  # bounded: symplectic, h w = 0.1


# ------------------------------------------------------------------------------------ missing parts


def test_parts_lacking_the_protocol_are_refused_with_their_names():
    class NoKind(ToySpringToOrigin):
        energy_kind = None

    @ti.data_oriented
    class Stirrer(ta.PointTerm):
        energy_kind = "source"

        @ti.func
        def force(self, i, m, x, v, t):
            return ti.Vector([-x[2], 0.0, x[0]])

        @ti.func
        def jacobian(self, i, m, x, v, t):
            return ti.Matrix.zero(float, 3, 3), ti.Matrix.zero(float, 3, 3)

    b = ta.Builder()
    b.add_particles([[1.0, 0.0, 0.0]], mass=1.0)
    with pytest.raises(ta.ParameterError, match="NoKind lacks: energy_kind"):
        b.add_force(NoKind(1.0))
    with pytest.raises(ta.ParameterError, match=r"Stirrer lacks: speed_bound\(\)"):
        b.add_force(Stirrer())

    class Shapeless(ToyTiltedPlane):
        surface = None
        kind = None

    with pytest.raises(ta.ParameterError, match="collider Shapeless lacks: surface, kind"):
        add_collider(b, Shapeless((0.0, 1.0, 0.0), 0.0))  # refused when added, before finalize()

    class Unbounded(ToyAdjointEuler):
        stability_region = None

    model = spring_scene(1.0)
    with pytest.raises(ta.ParameterError, match="integrator Unbounded declares no stability_region"):
        Unbounded().step(model, model.state(), 0.01)
