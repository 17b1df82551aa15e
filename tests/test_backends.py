"""GPU backends give the same particles as the CPU (marked `gpu`: run with `pytest -m gpu` on a machine
with CUDA, or with Vulkan — Mesa's lavapipe counts)."""

import numpy as np
import pytest

import taichi_anim as ta
from taichi_anim import runtime
from taichi_anim.scenes import make_scene


@pytest.mark.gpu
@pytest.mark.parametrize("arch", ["auto", "gpu"])
def test_auto_and_gpu_choose_the_device_that_passes_its_probe(arch):
    """On a machine with a GPU, "auto" and "gpu" run on the first of CUDA and Vulkan whose probe
    passes (the fallback to the CPU is tested in hard_cases/test_backends.py)."""
    found = [a for a in runtime.GPU_CANDIDATES if runtime.probe_arch(a)["ok"]]
    if not found:
        pytest.skip("no GPU backend starts here")
    assert ta.init(arch) == found[0]
    choice = runtime.arch_choice()
    assert choice["requested"] == arch and choice["chosen"] == found[0]


def _require(arch: str) -> None:
    """Skip unless Taichi starts on `arch` here."""
    try:
        ta.init(arch)
    except RuntimeError as e:
        pytest.skip(f"{arch} not available here: {e}")


def fountain_positions(arch: str, frames: int = 30):
    ta.init(arch, precision="f32")
    scene = make_scene("fountain", particles=5000, seed=2)
    for _ in range(frames):
        scene.advance_frame()
    snap = scene.state.snapshot()
    return snap.index, snap.x


@pytest.mark.gpu
@pytest.mark.parametrize("arch", ["cuda", "vulkan"])
@pytest.mark.parametrize("scan", [None, True])
def test_gpu_backend_matches_cpu(monkeypatch, arch, scan):
    """The fountain on the GPU: the emitters' scan chosen by pool size (5,000 slots: the serial one)
    and forced to the parallel passes, against the CPU's serial scan."""
    _require(arch)
    import taichi_anim.particles.emitters as emitters_module

    monkeypatch.setattr(emitters_module, "PARALLEL_SCAN", scan)
    idx_gpu, x_gpu = fountain_positions(arch)
    monkeypatch.setattr(emitters_module, "PARALLEL_SCAN", None)
    idx_cpu, x_cpu = fountain_positions("cpu")
    # Same seed, same emission order: the same slots are alive. Positions agree to float32 round-off
    # amplified over 120 steps and a few bounces (fast-math differs between backends).
    np.testing.assert_array_equal(idx_gpu, idx_cpu)
    close = np.linalg.norm(x_gpu - x_cpu, axis=1) < 1e-3
    assert close.mean() > 0.99, close.mean()


def sphere_pile(arch: str, method: str, nudge: bool = False):
    """Positions while the column falls (6 frames) and (largest overlap, contacts) once it has landed;
    `nudge` moves every start position up by one float32 ulp (the precision's own spread)."""
    ta.init(arch, precision="f32")
    scene = make_scene("spheres", particles=4000, seed=1)
    b = ta.Builder()  # the same spheres with the neighbour structure under test
    b.add_force_gravity()
    x0 = scene.state.positions().astype(np.float32)
    if nudge:
        x0 = np.nextafter(x0, np.float32(np.inf))
    v0 = scene.state.velocities()
    b.add_particles(x0, v0, mass=1e-3, radius=scene.options["radius"])
    b.add_collider_box(*scene.bounds, restitution=0.3, friction=0.4)
    b.add_sphere_contacts(restitution=0.5, friction=0.4, neighbor_search=method)
    model = b.finalize()
    state = model.state()
    integ = ta.make_integrator("symplectic_euler")
    for _ in range(6 * scene.substeps):
        integ.step(model, state, scene.dt)
    falling = state.positions()
    for _ in range(6 * scene.substeps):
        integ.step(model, state, scene.dt)
    return falling, integ.stepper_for(model).contacts.overlap_stats(model, state)


@pytest.mark.gpu
@pytest.mark.parametrize("arch", ["cuda", "vulkan"])
@pytest.mark.parametrize("method", ["grid", "hash_grid"])
def test_gpu_sphere_contacts_match_cpu(arch, method):
    """The counting sort (block scan, per-cell sort) and the contact sweeps run on the GPU backends: the
    column falls the same way, and once it has landed (the splash makes the motion chaotic) it has as
    many contacts and small overlaps.

    "The same way" is measured against the precision: the CPU run started one ulp higher gives the
    spread that rounding alone makes over these 1,440 steps of a pile in contact (about 89 % of the
    spheres within 1 mm on the CPU here; the GPU runs gave 92-95 % on an H200). A GPU result no
    further from the CPU's than that, less 5 points, passes; a race or a wrong sum moves far more."""
    _require(arch)
    x_gpu, (overlap_gpu, contacts_gpu) = sphere_pile(arch, method)
    x_cpu, (overlap_cpu, contacts_cpu) = sphere_pile("cpu", method)
    x_ulp, _ = sphere_pile("cpu", method, nudge=True)
    spread = (np.linalg.norm(x_ulp - x_cpu, axis=1) < 1e-3).mean()
    close = (np.linalg.norm(x_gpu - x_cpu, axis=1) < 1e-3).mean()
    assert spread > 0.8, spread  # the pile is still falling: the comparison means something
    assert close > spread - 0.05, (close, spread)
    assert contacts_cpu > 1000  # the column has landed
    assert overlap_gpu < 0.25 * 0.006 and abs(contacts_gpu - contacts_cpu) < 0.1 * contacts_cpu


def hanging_cloth(arch: str, integrator: str, steps: int, dt: float):
    """A 24x24 cloth pinned at two corners, swinging down: positions and the last solve. (No collider:
    contact with friction makes which way the cloth slides a bifurcation, so runs drift apart.)"""
    ta.init(arch, precision="f32")
    b = ta.Builder()
    b.add_force_gravity()
    b.add_cloth_grid(origin=(0, 1, 0), size=(1, 1), resolution=(24, 24), pinned=[0, 23])
    model = b.finalize()
    state = model.state()
    options = dict(linear_solver="pcg", tol=1e-5) if integrator == "implicit_euler" else {}
    integ = ta.make_integrator(integrator, **options)
    for _ in range(steps):
        integ.step(model, state, dt)
    return state.positions(), getattr(integ, "last_solve", None)


@pytest.mark.gpu
@pytest.mark.parametrize("arch", ["cuda", "vulkan"])
@pytest.mark.parametrize(
    ("integrator", "steps", "dt"), [("implicit_euler", 30, 1 / 60), ("symplectic_euler", 400, 1 / 8000)]
)
def test_gpu_cloth_matches_cpu(arch, integrator, steps, dt):
    """Springs, the implicit system and the solvers' GPU reductions (atomics instead of CPU block sums):
    the same cloth ends within float32 round-off of the CPU run, and PCG converges the same way."""
    _require(arch)
    x_gpu, solve_gpu = hanging_cloth(arch, integrator, steps, dt)
    x_cpu, solve_cpu = hanging_cloth("cpu", integrator, steps, dt)
    assert np.abs(x_gpu - x_cpu).max() < 2e-3
    if solve_cpu is not None:
        assert solve_gpu.converged and solve_cpu.converged
        assert abs(solve_gpu.iterations - solve_cpu.iterations) <= max(3, solve_cpu.iterations // 5)


def falling_cloud(arch: str, frames: int = 20, substeps: int = 10):
    """Particles under gravity and drag bouncing in a box and off a sphere, a frame of substeps per
    `advance` (one blocked launch where the scene allows it), and the frame mode the stepper chose."""
    ta.init(arch, precision="f32")
    rng = np.random.default_rng(5)
    b = ta.Builder()
    b.add_particles(
        rng.uniform((-0.8, 0.5, -0.8), (0.8, 1.8, 0.8), (20_000, 3)), rng.normal(0, 1, (20_000, 3)), 0.01
    )
    b.add_force_gravity()
    b.add_force_drag(0.05)
    b.add_collider_box((-1, 0, -1), (1, 2, 1), restitution=0.5, friction=0.1)
    b.add_collider_sphere((0, 0.4, 0), 0.3, restitution=0.3, friction=0.2)
    model = b.finalize(seed=0)
    state = model.state()
    stepper = ta.make_integrator("symplectic_euler", check_every=substeps).stepper_for(model)
    for _ in range(frames):
        stepper.advance(state, 1 / 600, substeps)
    return state.positions(), stepper.frame_mode()["mode"]


@pytest.mark.gpu
@pytest.mark.parametrize("arch", ["cuda", "vulkan"])
def test_gpu_blocked_frames_match_cpu(arch):
    """Without emitters a frame of substeps runs as one blocked launch on every backend: on the GPU it
    gives the CPU's particles to float32 round-off amplified by the bounces (fast-math differs)."""
    _require(arch)
    x_gpu, mode_gpu = falling_cloud(arch)
    x_cpu, mode_cpu = falling_cloud("cpu")
    assert mode_gpu == mode_cpu == "blocked"
    close = np.linalg.norm(x_gpu - x_cpu, axis=1) < 1e-3
    assert close.mean() > 0.99, close.mean()
