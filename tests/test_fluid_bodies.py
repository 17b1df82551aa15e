"""Rigid bodies in the liquid, two ways: a plank floats at Archimedes' draft, a heavy box sinks, and the
momentum the liquid gives a body is the momentum it loses."""

import numpy as np
import pytest

import taichi_anim as ta

from .helpers import momentum_exchange

RHO = 1000.0


def plank_in_tank(density: float, *, d=0.02, width=0.4, depth=0.24, size=(0.16, 0.06, 0.16), method="dfsph"):
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (width, 0.6, width), restitution=0.0)
    b.add_fluid(spacing=d, method=method)
    b.add_fluid_block((0.0, 0.0, 0.0), (width, depth, width))
    half = np.asarray(size) / 2.0
    b.add_rigid_body(ta.shapes.Box(tuple(half)), density=density,
                     position=(width / 2, depth + half[1] + 0.005, width / 2))  # fmt: skip
    model = b.finalize()
    return model, model.state(), ta.make_integrator("symplectic_euler").stepper_for(model)


def water_level(x, columns, spacing: float, support: float) -> float:
    """The free surface's height: where the liquid's volume fraction sum_j V W(|p - x_j|) (Shepard's
    colour field, V = spacing^3) falls to one half, averaged over vertical lines at `columns` (x, z)."""
    from taichi_anim.bodies.fluid.sph_kernel import cubic_w_numpy

    levels = []
    top = x[:, 1].max()
    heights = np.arange(top - 3 * spacing, top + 2 * spacing, spacing / 40)
    for cx, cz in columns:
        near = x[np.hypot(x[:, 0] - cx, x[:, 2] - cz) < support]
        p = np.stack([np.full_like(heights, cx), heights, np.full_like(heights, cz)], 1)
        r = np.linalg.norm(p[:, None, :] - near[None, :, :], axis=2)
        c = cubic_w_numpy(r, support).sum(axis=1) * spacing**3
        levels.append(np.interp(0.5, c[::-1], heights[::-1]))  # c falls with height
    return float(np.mean(levels))


def drafts(density: float, seconds: float, *, d=0.02, width=0.4, depth=0.24, size=(0.16, 0.06, 0.16)):
    """Every 4th frame (1/60 s) from 1 s on, the plank's draft below two water levels: (a) the level
    the liquid's volume gives, N d^3 (the liquid at rest density fills the tank's floor around the
    plank's submerged part: level = (N d^3 + A_plank draft) / A_tank, solved for the draft), and (b)
    the surface where Shepard's colour field falls to a half near the tank's corners (water_level)."""
    model, state, stepper = plank_in_tank(density, d=d, width=width, depth=depth, size=size)
    corners = [(a, c) for a in (3 * d, width - 3 * d) for c in (3 * d, width - 3 * d)]
    plank, tank = size[0] * size[2], width * width
    volume = model.fluid_count * d**3
    out = []
    for frame in range(round(seconds * 60)):
        stepper.advance(state, 1.0 / 60.0, 1)
        if frame >= 60 and frame % 4 == 0:
            x = state.positions()[model.fluid_particles]
            bottom = state.rigid_snapshot().com[0, 1] - size[1] / 2
            by_volume = (volume / tank - bottom) / (1.0 - plank / tank)
            out.append((by_volume, water_level(x, corners, d, model.fluid_support) - bottom))
    return np.array(out)


def test_a_box_is_sampled_half_a_spacing_inside_every_face():
    """A body's boundary samples lie on its surface moved half a spacing inside (boundary.py), edges and
    corners included: a 16 x 6 x 16 cm box at 2 cm is sampled on the surface of the 14 x 4 x 14 cm box
    inside it, none nearer than half a spacing to any face, every lattice point of that surface among
    them (the triangles' diagonals add more). (Each face's grid moved along its own normal put the rims
    of the faces on the neighbouring faces' planes: samples on the box's edges.)"""
    from taichi_anim.bodies.fluid.boundary import mesh_samples

    d, half = 0.02, np.array([0.08, 0.03, 0.08])
    x = mesh_samples(*ta.shapes.Box(tuple(half)).triangles(), d)
    inner = half - 0.5 * d
    assert (np.abs(x) / inner).max(axis=1) == pytest.approx(1.0, abs=1e-12)  # on the inner box's faces
    axes = [np.arange(-h, h + 1e-9, d) for h in inner]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    lattice = lattice[(np.abs(lattice) / inner).max(axis=1) > 1.0 - 1e-9]
    assert len(lattice) == 8 * 3 * 8 - 6 * 1 * 6
    gap = np.linalg.norm(lattice[:, None, :] - x[None, :, :], axis=2).min(axis=1)
    assert gap.max() < 1e-12
    # The same box as an STL file gives it, every triangle with corners of its own: the same samples.
    v, f = ta.shapes.Box(tuple(half)).triangles()
    split = mesh_samples(v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3), d)
    assert np.array_equal(np.unique(np.round(split / 1e-9), axis=0), np.unique(np.round(x / 1e-9), axis=0))


@pytest.mark.parametrize("shape", ["glass", "sphere", "capsule"])
def test_curved_and_hollow_surfaces_are_sampled_half_a_spacing_inside(shape):
    """The inset holds on curved and hollow meshes too: every sample of a sphere's and a capsule's
    triangulation, and of the pour demo's glass (walls 1.5 spacings thick, a mesh collider), lies inside
    the solid, 95 % of them half a spacing deep to 1 % of a spacing (Open3D's signed distance), none
    less deep than 0.49 spacing or deeper than 0.75 (the glass's deepest: 0.71)."""
    import open3d as o3d

    from taichi_anim.bodies.fluid.boundary import mesh_samples
    from taichi_anim.scenes.pour import glass_mesh

    v, f, d = {
        "glass": (*glass_mesh(0.06, 0.15, 0.012), 0.008),
        "sphere": (*ta.shapes.Sphere(0.05).triangles(), 0.01),
        "capsule": (*ta.shapes.Capsule(0.03, 0.05).triangles(), 0.01),
    }[shape]
    x = mesh_samples(v, f, d)
    mesh = o3d.t.geometry.TriangleMesh(o3d.core.Tensor(np.asarray(v, np.float32)),
                                       o3d.core.Tensor(np.asarray(f, np.int32)))  # fmt: skip
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    depth = -scene.compute_signed_distance(o3d.core.Tensor(x.astype(np.float32))).numpy() / d
    assert depth.min() > 0.49 and depth.max() < 0.75
    assert np.percentile(np.abs(depth - 0.5), 95) < 0.01


@pytest.mark.slow  # 90 s each on 2 cores (16,400 particles for 2.5 s)
@pytest.mark.parametrize("density", [500.0, 750.0])
def test_a_plank_floats_at_archimedes_draft(density):
    """A plank (16 x 6 x 16 cm, wide enough to float upright) dropped on water floats at the draft where
    the water it displaces weighs what it weighs, draft / height = rho_b / rho_w, within 5 % at 1 cm
    spacing (drafts of 3 and 4.5 spacings), averaged over 1-2.5 s (it still heaves): measured 1.002
    (500 kg/m^3) and 1.020 (750) below the colour field's surface near the tank's corners; at 2 cm
    spacing 1.022 and 1.060, and 0.87 and 0.89 with the samples' rims on the body's surface (before
    they were inset at edges and corners, boundary.py).

    Below the level the liquid's volume gives (N d^3 over the tank's floor) the drafts read 1.09 and
    1.07: a settled tank's surface (the colour field's) lies 0.11-0.13 spacing below that level (its top
    layers sit closer than a spacing; measured without a plank), 4 % of these drafts."""
    by_volume, by_surface = drafts(density, 2.5, d=0.01, width=0.32, depth=0.16).mean(axis=0) / (
        density / RHO * 0.06
    )
    assert by_surface == pytest.approx(1.0, abs=0.05)
    assert 1.0 < by_volume < 1.15


def test_a_heavy_box_sinks_and_a_light_one_stays_up():
    """Two-way, both outcomes in one tank: a box of 2000 kg/m^3 reaches the floor, one of 300 kg/m^3
    floats with most of itself above the water (its draft is 0.3 of its height)."""
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (0.32, 0.4, 0.16), restitution=0.0)
    b.add_fluid(spacing=0.02)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.32, 0.12, 0.16))
    for x, density in ((0.08, 2000.0), (0.24, 300.0)):
        b.add_rigid_body(ta.shapes.Box((0.04, 0.04, 0.04)), density=density, position=(x, 0.165, 0.08))
    model = b.finalize()
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    for _ in range(45):
        stepper.advance(state, 1.0 / 60.0, 1)
    bottoms = state.rigid_snapshot().com[:, 1] - 0.04
    assert bottoms[0] < 0.02  # on the floor (within a spacing)
    assert bottoms[1] > 0.12 - 0.5 * 0.08  # less than half of it under the water's first level


def test_the_liquid_and_a_body_exchange_momentum_exactly():
    """No gravity, no walls: a box shot into a block of liquid. The body's momentum change is the
    liquid's, opposite (each pair's pressure correction goes to the body whole), to round-off."""
    b = ta.Builder()
    b.add_fluid(spacing=0.02)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.2, 0.2, 0.2))
    b.add_rigid_body(ta.shapes.Box((0.04, 0.04, 0.04)), density=800.0, position=(-0.08, 0.1, 0.1),
                     velocity=(1.0, 0.0, 0.0))  # fmt: skip
    model = b.finalize()
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    m_body = float(model.rigid_mass[0])

    def momentum():
        return model.fluid_mass * state.velocities()[model.fluid_particles].sum(axis=0), m_body * (
            state.rigid_snapshot().velocity[0]
        )

    fluid0, body0 = momentum()
    for _ in range(12):
        stepper.advance(state, 1.0 / 120.0, 1)
    fluid1, body1 = momentum()
    assert body1[0] < 0.9 * body0[0]  # the liquid slowed it
    total0, total1 = fluid0 + body0, fluid1 + body1
    assert np.abs(total1 - total0).max() < 1e-10 * np.abs(body0).max()


def spheres_in_tank(frames: int):
    """A sphere of 500 and one of 2000 kg/m^3 (4 cm radius) dropped into 20 cm of water, as NumPy: the
    spheres' centres, the liquid's top layer's height and the solver's totals."""
    d, r = 0.02, 0.04
    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (0.3, 0.5, 0.3), restitution=0.0)
    b.add_fluid(spacing=d)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.3, 0.2, 0.3))
    volume = 4.0 / 3.0 * np.pi * r**3
    balls = b.add_particles(
        [[0.08, 0.25, 0.15], [0.22, 0.25, 0.15]], mass=[500 * volume, 2000 * volume], radius=r
    )
    model = b.finalize()
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler").stepper_for(model)
    for _ in range(frames):
        stepper.advance(state, 1.0 / 60.0, 1)
    x = state.positions()
    top = np.sort(x[model.fluid_particles, 1])[-50:].mean()
    return x[np.asarray(balls)], top, next(s for s in stepper.solvers if s.name == "fluid").stats()


@pytest.mark.slow  # exhaustive; covered by spheres in the liquid: their momentum exchange, default
def test_a_heavy_sphere_sinks_and_a_light_one_floats_half_in():
    """Hard spheres (particles of radius > 0) meet the liquid through boundary samples on a sphere half a
    spacing inside theirs, two ways: after 1.5 s the 2000 kg/m^3 sphere lies on the floor and the
    500 kg/m^3 one floats with its centre at the water's surface (the top layer plus half a spacing)
    to within half a spacing (measured 0.24 of a spacing below it at 1.5 s: it still bobs)."""
    centres, top, stats = spheres_in_tank(90)
    assert centres[1, 1] == pytest.approx(0.04, abs=1e-3)
    assert abs(centres[0, 1] - (top + 0.01)) < 0.5 * 0.02
    assert stats["unconverged_steps"] == 0


def test_a_sphere_and_the_liquid_exchange_momentum_exactly():
    """No gravity, no walls: a sphere shot into a block of liquid gives it exactly the momentum it loses
    (f64 round-off), and is slowed."""
    b = ta.Builder()
    b.add_fluid(spacing=0.02, domain=((-0.3, -0.3, -0.3), (0.5, 0.5, 0.5)))
    b.add_fluid_block((0.0, 0.0, 0.0), (0.16, 0.16, 0.16))
    ball = b.add_particles([[-0.06, 0.08, 0.08]], [[2.0, 0.0, 0.0]], mass=0.2, radius=0.04)
    change, scale, v = momentum_exchange(b.finalize(), 12, 1.0 / 120.0)
    assert change < 1e-12 * scale
    assert v[ball[0], 0] < 0.9 * 2.0
