"""Packs of a blocked frame (integrators/blocked.py, BlockedFrame.advance_pack): PACK particles through
the frame as vector lanes, quiet substeps ending at the update, and in the others the lanes that are not
quiet going through the particle loop's own substep.

The method is unchanged, so a pack's particles must end bit for bit where one particle per iteration
puts them; and `path_is_clear`, which lets a substep skip `collide`, must only ever vouch for paths on
which `collide` returns the update untouched."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
import taichi_anim.integrators.blocked as blocked
from taichi_anim.collision import ColliderPlane, ColliderSolidBox, ColliderSphere, CollisionMode
from taichi_anim.collision.response import collide, path_is_clear
from taichi_anim.runtime import np_float

from .test_blocked_frame import _fountain

FIELDS = ("particle_x", "particle_v", "particle_birth", "particle_death", "particle_free")


def _frames(make, packed, monkeypatch, frames=12, substeps=10, h=1.0 / 600.0):
    monkeypatch.setattr(blocked, "PACKED", packed)
    model, state = make()
    stepper = ta.make_integrator("symplectic_euler", check_every=substeps).stepper_for(model)
    for _ in range(frames):
        stepper.advance(state, h, substeps)
    assert stepper.frame_mode()["mode"] == "blocked"
    assert stepper._blocked.packed == packed
    return model, state


def _piles(n=203):
    """Particles of radius 2 cm thrown into a box with a ball in it: bounces off walls, corners and the
    ball, and a layer coming to rest on the floor (slides, resting contacts). 203 = 25 packs and 3."""
    b = ta.Builder()
    rng = np.random.default_rng(7)
    b.add_particles(rng.uniform((-0.9, 0.05, -0.9), (0.9, 0.6, 0.9), (n, 3)), rng.normal(0, 2, (n, 3)), 0.01,
                    radius=0.02)  # fmt: skip
    b.add_force_gravity()
    b.add_force_drag(0.05)
    b.add_collider_box((-1, 0, -1), (1, 2, 1), restitution=0.4, friction=0.3)
    b.add_collider_sphere((0.3, 0.2, 0.0), 0.25, restitution=0.7, friction=0.1)
    model = b.finalize(seed=1)
    return model, model.state()


@pytest.mark.parametrize(
    "make, precision",
    [
        # A full pool whose births wait for deaths, in a box (restitution, friction): 500 = 62 packs and 4.
        (lambda: _fountain(capacity=500, lifetime=0.05, jitter=0.2), "f32"),
        # Slots born, dying and born again within a launch; two emitters sharing packs.
        (lambda: _fountain(capacity=300, lifetime=0.004, jitter=0.5, emitters=2), "f32"),
        (_piles, "f32"),
        (_piles, "f64"),
    ],
    ids=["full_pool", "short_lives", "piles", "piles_f64"],
)
def test_packs_equal_one_particle_per_iteration_bit_for_bit(make, precision, monkeypatch):
    ta.init("cpu", precision=precision)
    model, ref = _frames(make, False, monkeypatch)
    _, got = _frames(make, True, monkeypatch)
    names = [k for k in FIELDS if getattr(ref, k) is not None]  # lifetimes and free bits: emitters only
    assert len(names) == (5 if model.emitter_count else 2)
    for name in names:
        np.testing.assert_array_equal(getattr(got, name).to_numpy(), getattr(ref, name).to_numpy(), name)
    x = ref.positions()
    assert np.isfinite(x).all() and x[:, 1].min() >= -1e-6  # the colliders held them
    if model.emitter_count:
        assert 0.3 * model.particle_count < ref.alive_mask().sum()


def test_packs_stop_at_the_step_that_diverged_with_its_particle(monkeypatch):
    """A speed limit crossed inside a quiet run of substeps: the pack leaves it for the particle path,
    which records the same step and particle as one particle per iteration does."""
    v0 = np.zeros((37, 3))
    v0[:, 1] = -np.linspace(0.0, 2.0, 37)
    v0[29, 1] = -3.5

    def make():
        b = ta.Builder()
        b.add_particles(np.random.default_rng(2).uniform(0, 1, (37, 3)) + [0, 100, 0], v0, mass=0.01)
        b.add_force_gravity()
        model = b.finalize()
        return model, model.state()

    found = []
    for packed in (False, True):
        monkeypatch.setattr(blocked, "PACKED", packed)
        model, state = make()
        stepper = ta.make_integrator("symplectic_euler", check_every=40).stepper_for(model)
        stepper.watchdog.configure(speed=5.0, extent=float("inf"), energy_tolerance=float("inf"))
        with pytest.raises(ta.DivergenceError) as info:
            for _ in range(10):
                stepper.advance(state, 1e-3, 40)
        assert stepper._blocked.packed == packed
        found.append((info.value.step, info.value.particle, info.value.quantity))
    assert found[0] == found[1] and found[0][1] == 29 and found[0][2] == "speed"


def test_packs_only_where_they_apply_and_from_their_size(monkeypatch):
    """Packs by default from PACKS_FROM particles, never with trails (a store per substep) or a collider
    whose sdf does not bound its distance (a mesh), and never on a GPU (`packs_apply`)."""
    monkeypatch.setattr(blocked, "PACKED", None)
    for capacity, trails, packed in ((blocked.PACKS_FROM, 0, True), (blocked.PACKS_FROM - 1, 0, False),
                                     (blocked.PACKS_FROM, 3, False)):  # fmt: skip
        model, _ = _fountain(capacity=capacity, lifetime=0.05, jitter=0.2, trails=trails)
        assert blocked.BlockedFrame(model, ta.make_integrator("symplectic_euler")).packed == packed
    b = ta.Builder()
    b.add_particles(np.zeros((1, 3)) + [0, 1, 0])
    b.add_collider_mesh((np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1]]), np.array([[0, 2, 1]])))
    model = b.finalize()
    assert not blocked.packs_apply(model)


@ti.data_oriented
class _Probe:
    """collide and path_is_clear on a batch of paths, in one kernel."""

    def __init__(self, colliders, mode, n):
        self.colliders = colliders
        self.mode = mode
        for c in colliders:
            c.allocate(0.05)
        self.io = ti.Vector.field(3, float, (n, 6))  # x0, v0, x1, v1 in; x, v out
        self.clear = ti.field(ti.i32, n)

    @ti.kernel
    def run(self, r: float, h: float):
        for i in self.clear:
            x0, v0, x1, v1 = self.io[i, 0], self.io[i, 1], self.io[i, 2], self.io[i, 3]
            self.clear[i] = ti.cast(path_is_clear(self.colliders, x0, x1, 0.0, r), ti.i32)
            x, v = collide(self.colliders, self.mode, x0, v0, x1, v1, 0.0, h, r, 0.01)
            self.io[i, 4] = x
            self.io[i, 5] = v


@pytest.mark.parametrize("mode", [CollisionMode.BACKWARD, CollisionMode.PROJECTION])
@pytest.mark.parametrize("r", [0.0, 0.03])
def test_path_is_clear_only_where_collide_returns_the_update(mode, r):
    """Random paths of every length around a plane, a solid box (square corners grown by r) and a ball,
    many ending near or inside them: wherever path_is_clear vouches for a path, collide returns its end
    state bit for bit; and it does vouch for most of the paths that stay a path's length away."""
    colliders = (
        ColliderPlane((0.0, 1.0, 0.0), 0.0, 0.5, 0.2),
        ColliderSolidBox((0.2, 0.2, 0.2), (0.6, 0.5, 0.4), 0.5, 0.2),
        ColliderSphere((-0.4, 0.3, 0.0), 0.2, 0.5, 0.2),
    )
    n, h = 200_000, 1e-2
    rng = np.random.default_rng(11)
    x0 = rng.uniform((-0.8, -0.02, -0.3), (0.8, 0.8, 0.6), (n, 3))
    # Near the box's corners and edges, where a box grown with square corners reaches sqrt(3) r.
    x0[: n // 4] = rng.choice([0.2, 0.6], (n // 4, 3)) + rng.normal(0, 0.06, (n // 4, 3))
    length = 10.0 ** rng.uniform(-6, -0.5, n)
    d = rng.normal(size=(n, 3))
    x1 = x0 + d / np.linalg.norm(d, axis=1, keepdims=True) * length[:, None]
    v0, v1 = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    probe = _Probe(colliders, mode, n)
    probe.io.from_numpy(np.stack([x0, v0, x1, v1, x1, v1], axis=1).astype(np_float()))
    probe.run(r, h)
    io = probe.io.to_numpy()
    clear = probe.clear.to_numpy().astype(bool)
    np.testing.assert_array_equal(io[clear, 4], io[clear, 2])
    np.testing.assert_array_equal(io[clear, 5], io[clear, 3])
    # How much it vouches for: paths whose every point is 3 path lengths plus sqrt(3) r from every solid.
    sdf = np.minimum.reduce([_sdf(c, x0) for c in colliders])
    far = sdf - np.sqrt(3.0) * r > 3.0 * length + 1e-3
    assert clear[far].mean() > 0.99 and clear.sum() > n // 4
    # And collide really changes many of the others: the test is not vacuous.
    moved = np.any(io[~clear, 4] != io[~clear, 2], axis=1)
    assert moved.sum() > n // 20


def _sdf(c, x):
    if isinstance(c, ColliderPlane):
        return x @ np.array(c.n) - c.offset
    if isinstance(c, ColliderSphere):
        return np.linalg.norm(x - c.center, axis=1) - c.radius
    lo, hi = np.array(c.lo), np.array(c.hi)
    q = np.maximum(lo - x, x - hi)
    return np.where(q.max(axis=1) > 0, np.linalg.norm(np.maximum(q, 0), axis=1), q.max(axis=1))
