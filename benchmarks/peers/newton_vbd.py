"""Newton's Vertex Block Descent cloth with self-contact on the CPU: the peer of the stacked-sheets scene.

Newton (https://github.com/newton-physics/newton, `pip install newton`, built on NVIDIA Warp) is driven
through its public API, configured as its own VBD cloth examples are (newton/examples/cloth/
example_cloth_hanging.py with `--solver vbd`, example_cloth_twist.py): `ModelBuilder.add_cloth_mesh`,
`builder.color(include_bending=True)` (VBD solves one colour of vertices at a time), `finalize`,
`model.soft_contact_ke/kd/mu`, `SolverVBD(model, iterations=..., particle_enable_self_contact=...,
particle_self_contact_margin=..., particle_self_contact_gap=...)`, and per substep `state.clear_forces()`,
`CollisionPipeline.collide(state, contacts)` (particle–shape contacts with the ball and the floor),
`solver.step(state_in, state_out, control, contacts, dt)` and a swap; the self-contact BVH is rebuilt
once per frame (`solver.rebuild_bvh`, as the twist example does), and a frame is replayed from a Warp
graph captured on the CPU (`wp.ScopedCapture`, as the examples do) when capture succeeds. Methods: VBD
(Chen et al., "Vertex Block Descent", ACM TOG 43(4) 2024) with Offset Geometric Contact (Chen et al.,
ACM TOG 44(4) 2025: a C2 log-barrier between vertex–triangle and edge–edge pairs within the margin, and
per-vertex motion truncation that keeps every step penetration-free).

Scene (the engine's stacked-sheets scene): two horizontal 1 m x 1 m sheets of 32 x 32 cells (33 x 33
vertices; the engine's own grid, `taichi_anim.geometry.cloth_grid`, so the triangles are the same), areal
density 0.2 kg/m^2 with masses lumped by area (`density=`), the lower at height 0.6 m and the upper 3 cm
above it, both centred on the vertical axis through a ball of radius 0.25 m at (0, 0.25, 0) resting on
the floor y = 0; gravity 9.81 m/s^2; 1/60 s frames of 10 substeps x 10 VBD iterations. Axes: the model is
built with `up_axis=newton.Axis.Y` and gravity (0, -9.81, 0), so Newton's coordinates are the engine's
(y up) and no remapping is needed (Newton's default is z up; its ground plane follows the up axis).

Material: the membrane and bending stiffness of Newton's VBD hanging-cloth example (tri_ke = tri_ka =
1e3 N/m, stable neo-Hookean; edge_ke = 10, dihedral bending), with smaller damping (tri_kd = 1e-2,
edge_kd = 1e-2: the example's tri_kd = 1e2 was chosen for a 10 kg/m^2 cloth of 10 cm cells and would
make this 50 times lighter cloth treacle-like; the Newton maintainers advise starting from ~1e-4).
Contact: soft_contact_ke = 1e3 N/m, kd = 1e-2, mu = 0.5 (self-contact and particle–shape); each vertex's
radius against the ball and the floor 5 mm (`particle_radius`), detection slack 5 mm
(`soft_contact_gap`); self-contact interaction distance (the thickness) `margin` = 5 mm and detection
slack `gap` = 5 mm (the docstring's advice: gap ~0.5–1 x margin). Every value is in `Settings` and is
written next to the figures.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import newton  # noqa: E402,F401  (a missing peer fails here, where harness.peer reports it)
import numpy as np
import warp  # noqa: E402,F401

GRAVITY = 9.81
FRAME_DT = 1.0 / 60.0


@dataclass(frozen=True)
class Settings:
    """The scene and Newton's options (module docstring); lengths [m], stiffness [N/m]."""

    cells: int = 32
    size: float = 1.0
    density: float = 0.2  # [kg/m^2]
    lower_height: float = 0.6
    spacing: float = 0.03
    ball_radius: float = 0.25
    substeps: int = 10
    iterations: int = 10
    tri_ke: float = 1.0e3
    tri_ka: float = 1.0e3
    tri_kd: float = 1.0e-2
    edge_ke: float = 10.0
    edge_kd: float = 1.0e-2
    contact_ke: float = 1.0e3
    contact_kd: float = 1.0e-2
    contact_mu: float = 0.5
    particle_radius: float = 0.005
    shape_contact_gap: float = 0.005
    self_contact_margin: float = 0.005
    self_contact_gap: float = 0.005
    rebuild_bvh_every_frame: bool = True
    graph: bool = True


def available() -> str | None:
    """None when newton and warp import, else why not (one line)."""
    try:
        import newton  # noqa: F401
        import warp  # noqa: F401
    except Exception as e:  # ImportError, or a warp that fails to load its native library
        return f"{type(e).__name__}: {e}"
    return None


def versions() -> dict[str, str]:
    import warp as wp

    return {"newton": newton.__version__, "warp-lang": wp.__version__}


def sheets(s: Settings) -> tuple[np.ndarray, np.ndarray]:
    """Both sheets' vertices (V, 3) [m] and triangles (F, 3), the engine's grid, lower sheet first."""
    from taichi_anim.geometry import cloth_grid

    n, half = s.cells + 1, 0.5 * s.size
    parts = [
        cloth_grid(origin=(-half, h, -half), size=(s.size, s.size), resolution=(n, n), plane="xz")
        for h in (s.lower_height, s.lower_height + s.spacing)
    ]
    (va, ta), (vb, tb) = parts
    return np.concatenate([va, vb]), np.concatenate([ta, tb + len(va)])


class NewtonLayers:
    """The two sheets, the ball and the floor in Newton, with VBD, on the CPU."""

    def __init__(self, s: Settings, *, self_contact: bool):
        import warp as wp

        wp.config.quiet = True
        wp.init()
        wp.set_device("cpu")
        self.wp, self.s = wp, s
        vertices, triangles = sheets(s)
        b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -GRAVITY, 0.0))
        b.default_shape_cfg.ke = s.contact_ke
        b.default_shape_cfg.kd = s.contact_kd
        b.default_shape_cfg.mu = s.contact_mu
        b.add_cloth_mesh(
            pos=wp.vec3(0.0, 0.0, 0.0),
            rot=wp.quat_identity(),
            scale=1.0,
            vel=wp.vec3(0.0, 0.0, 0.0),
            vertices=vertices,
            indices=triangles.reshape(-1).tolist(),
            density=s.density,
            tri_ke=s.tri_ke,
            tri_ka=s.tri_ka,
            tri_kd=s.tri_kd,
            edge_ke=s.edge_ke,
            edge_kd=s.edge_kd,
            particle_radius=s.particle_radius,
        )
        ball = wp.transform(wp.vec3(0.0, s.ball_radius, 0.0), wp.quat_identity())
        b.add_shape_sphere(-1, xform=ball, radius=s.ball_radius)  # body -1: static, part of the world
        b.add_ground_plane()
        b.color(include_bending=True)
        self.model = b.finalize(device="cpu")
        self.model.soft_contact_ke = s.contact_ke
        self.model.soft_contact_kd = s.contact_kd
        self.model.soft_contact_mu = s.contact_mu
        self.pipeline = newton.CollisionPipeline(self.model, soft_contact_gap=s.shape_contact_gap)
        self.contacts = self.pipeline.contacts()
        self.solver = newton.solvers.SolverVBD(
            self.model,
            iterations=s.iterations,
            particle_enable_self_contact=self_contact,
            particle_self_contact_margin=s.self_contact_margin,
            particle_self_contact_gap=s.self_contact_gap,
        )
        self.control = self.model.control()
        self.state_0, self.state_1 = self.model.state(), self.model.state()
        self.triangles = self.model.tri_indices.numpy().astype(np.int64)
        self.self_contact = self_contact
        self.graph = None
        if s.graph:
            try:
                with wp.ScopedCapture() as capture:
                    self._substeps()
                self.graph = capture.graph
            except Exception as e:  # capture unsupported: run eagerly, and say so
                self.graph_error = f"{type(e).__name__}: {e}"

    def _substeps(self) -> None:
        dt = FRAME_DT / self.s.substeps
        for _ in range(self.s.substeps):
            self.state_0.clear_forces()
            self.pipeline.collide(self.state_0, self.contacts)
            self.solver.step(self.state_0, self.state_1, self.control, self.contacts, dt)
            self.state_0, self.state_1 = self.state_1, self.state_0

    def frame(self) -> None:
        if self.self_contact and self.s.rebuild_bvh_every_frame:
            self.solver.rebuild_bvh(self.state_0)
        if self.graph is not None:
            self.wp.capture_launch(self.graph)  # an even substep count leaves state_0 as the output
        else:
            self._substeps()
        self.wp.synchronize()

    def positions(self) -> np.ndarray:
        self.wp.synchronize()
        return self.state_0.particle_q.numpy().astype(np.float64)


def run(frames: int, self_contact: bool, *, settings: Settings | None = None, every: int = 1) -> dict:
    """Simulate `frames` frames and time each one.

    A first instance is built and run for one frame to compile Warp's modules (warmup_s, reported
    apart); the timed run uses a fresh instance (build_s). Returns frame_s (frames,) [s] wall time per
    frame (wp.synchronize before reading the clock) and frame_cpu_s, the process's CPU time (on a
    shared machine the wall time counts other processes' turns; Warp runs CPU kernels on one thread),
    x (frames // every + 1, V, 3) [m] positions at frames 0, every, 2 every, ..., triangles (F, 3),
    the settings and whether a captured graph was replayed."""
    s = settings or Settings()
    if s.substeps % 2:
        raise ValueError(f"substeps must be even (graph replay swaps the states), got {s.substeps}")
    t0 = time.perf_counter()
    warm = NewtonLayers(s, self_contact=self_contact)
    warm.frame()
    warmup_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim = NewtonLayers(s, self_contact=self_contact)
    build_s = time.perf_counter() - t0
    xs, times, cpu = [sim.positions()], [], []
    for f in range(1, frames + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        sim.frame()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if f % every == 0:
            xs.append(sim.positions())
    return {
        "frame_s": np.array(times),
        "frame_cpu_s": np.array(cpu),
        "warmup_s": warmup_s,
        "build_s": build_s,
        "x": np.array(xs),
        "every": every,
        "triangles": sim.triangles,
        "settings": asdict(s),
        "self_contact": self_contact,
        "graph": sim.graph is not None,
        "graph_error": getattr(sim, "graph_error", None),
    }


def crossings_per_frame(result: dict) -> np.ndarray:
    """Intersecting non-adjacent triangle pairs in each recorded frame (taichi_anim.spatial.crossings)."""
    from taichi_anim.spatial import intersecting_triangle_pairs

    return np.array([len(intersecting_triangle_pairs(x, result["triangles"])) for x in result["x"]])
