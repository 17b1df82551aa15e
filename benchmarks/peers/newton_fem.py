"""Newton's semi-implicit triangle-FEM cloth on the CPU: the peer of benchmarks/cloth_continuum_speed.py.

Newton (https://github.com/newton-physics/newton, `pip install newton`; built on NVIDIA Warp) is driven
through its public API only: `newton.ModelBuilder(up_axis=Y, gravity=(0, -9.81, 0))`, `add_cloth_mesh`
(one FEM triangle per face and one bending element per edge, vertex masses lumped as density x area / 3,
the same lumping as taichi_anim's), `finalize(device="cpu")` and `newton.solvers.SolverSemiImplicit`,
stepped as Newton's own examples do (`state.clear_forces()`, `solver.step(state_in, state_out, control,
None, dt)`, swap). The mesh is the engine's own grid (the same vertices, triangles and winding as
`taichi_anim.Builder.add_cloth_grid`), not `add_cloth_grid`, which gives every vertex the same mass
(`mass` per particle) instead of lumping by area. Pinned vertices get mass 0 and lose
`ParticleFlags.ACTIVE`, as `add_cloth_grid(fix_*=True)` does. Contacts are off: `model.particle_grid =
None` (no particle-particle contact) and `enable_tri_contact=False` (the particle-triangle contact kernel
runs over triangles x particles); the engine's scene has no contacts either. Warp runs CPU kernels on
one thread.

What Newton's kernels compute (newton/_src/solvers/semi_implicit/kernels_particle.py, read from the
installed package):
- `eval_triangle`: per triangle of rest area A, F = Ds Dm^-1 (3x2), first Piola stress
  P = k_mu F + k_damp dF/dt, plus an area term k_lambda (J - alpha) dJ/dx with J = area / rest area and
  alpha = 1 + k_mu / k_lambda, and its damping k_damp dJ/dt; all times A. That is the 2D "stable
  neo-Hookean" energy psi = k_mu/2 (tr(F^T F) - 2) + k_lambda/2 (J - alpha)^2 per rest area (Smith, de
  Goes & Kim, "Stable Neo-Hookean Flesh Simulation", ACM TOG 37(2) 2018, in 2D). With tri_ke = k_mu and
  tri_ka = k_lambda.
- `eval_bending`: per interior edge e with wing normals n1^, n2^ and dihedral angle theta, forces
  -|e| (ke (theta - theta0) + kd sum_i d_i . v_i) d_i with d_wing = -n^ |e| (and d on the edge's
  vertices to balance).

Parameter mapping (`mapping`), from the engine's FabricMaterial (E [N/m] areal Young's modulus, nu,
bending stiffness D [N m], Rayleigh damping beta [s] on the membrane and beta_b [s] on bending) on a
square grid of cell a [m]:
- Membrane. Expanding psi to second order in H = F - I (in-plane): psi = k_mu/2 ((H00 - H11)^2 +
  (H01 + H10)^2) + k_lambda/2 (tr H)^2, i.e. linear elasticity with Lamé parameters mu_L = k_mu and
  lambda_L = k_lambda - k_mu. The engine's StVK membrane linearises to plane stress, mu_L = E / (2 (1 +
  nu)), lambda_L = E nu / (1 - nu^2). So tri_ke = E / (2 (1 + nu)) and tri_ka = E nu / (1 - nu^2) +
  E / (2 (1 + nu)) (= 384.6 and 714.3 N/m for E = 1e3 N/m, nu = 0.3). The two agree to first order in
  the strain; at large strain StVK and neo-Hookean differ (cloth strains here are ~1e-3).
- Bending. For a hinge on a grid-axis edge (|e| = a, both wing heights a, triangle areas a^2/2) the
  engine's discrete-shell hinge has stiffness k_h = D |e0|^2 / (A1 + A2) = D (energy k_h/2 theta^2),
  force D theta / a on a wing; Newton's wing force is ke a^2 theta, so ke = D / a^3. On the diagonals
  (|e| = a sqrt 2, heights a / sqrt 2) the engine's hinge stiffness is 2 D and Newton's sqrt(2) ke a^3 =
  sqrt(2) D: one ke cannot match both; ke = D / a^3 is exact for bending about the grid axes (the
  diagonals stay flat there). Newton's ke is mesh-dependent (ke a^3 must stay D): it is set per mesh.
- Damping. Newton damps k_damp dF/dt, i.e. a Rayleigh function k_damp/2 (|dF/dt|^2 + (dJ/dt)^2) per area,
  which also damps rigid rotation of a triangle (dF/dt = Omega F for a rotation); the engine's is
  beta K v, frame-invariant. Matching the in-plane shear part (beta mu_L gamma-dot^2 / 2 against
  k_damp gamma-dot^2 / 4) gives tri_kd = 2 beta mu_L. For bending, sum_i d_i . v_i = a^2 theta-dot on an
  axis edge, so Newton's damping coefficient is kd a^5 against the engine's beta_b D: edge_kd = beta_b
  ke / a^2. Because Newton's triangle damping also brakes the swing itself, the benchmark runs Newton both
  with this damping and with none.
"""

from __future__ import annotations

import time

import numpy as np

_WARP = None


def available() -> str | None:
    """None when newton and warp import, else why not (one line)."""
    try:
        import newton  # noqa: F401
        import warp  # noqa: F401
    except Exception as e:  # ImportError, or a warp that fails to load its native library
        return f"{type(e).__name__}: {e}"
    return None


def versions() -> dict[str, str]:
    import newton
    import warp as wp

    return {"newton": newton.__version__, "warp-lang": wp.__version__}


def init_warp(kernel_cache_dir: str | None = None) -> dict:
    """Initialise Warp on the CPU, with its kernel cache in `kernel_cache_dir` if given (a fresh folder
    makes the first launch of every module a cold compile). Returns {"init_s": seconds}."""
    global _WARP
    import warp as wp

    if _WARP is None:
        if kernel_cache_dir is not None:
            wp.config.kernel_cache_dir = kernel_cache_dir
        wp.config.quiet = True
        t0 = time.perf_counter()
        wp.init()
        _WARP = {"init_s": time.perf_counter() - t0, "kernel_cache_dir": str(wp.config.kernel_cache_dir)}
    wp.set_device("cpu")
    return _WARP


def mapping(
    *,
    youngs: float,
    poisson: float,
    bending: float,
    damping: float,
    bending_damping: float,
    cell: float,
    damped: bool = True,
) -> dict:
    """Newton's tri_ke, tri_ka, tri_kd, edge_ke, edge_kd for the engine's FabricMaterial on a grid of
    cell `cell` [m] (module docstring); damped=False sets both damping coefficients to 0."""
    mu = youngs / (2.0 * (1.0 + poisson))
    lam = youngs * poisson / (1.0 - poisson * poisson)
    ke = bending / cell**3
    return {
        "tri_ke": mu,
        "tri_ka": lam + mu,
        "tri_kd": 2.0 * damping * mu if damped else 0.0,
        "edge_ke": ke,
        "edge_kd": bending_damping * ke / cell**2 if damped else 0.0,
    }


def _check_stable_neo_hookean_linearisation(k_mu: float, k_lambda: float) -> float:
    """Largest relative difference between psi of Newton's triangle (module docstring) and
    mu_L |eps|^2 + lambda_L/2 tr(eps)^2 (mu_L = k_mu, lambda_L = k_lambda - k_mu) over random small
    in-plane H (|H| ~ 1e-4), both minus their value at H = 0: the mapping's algebra, checked in NumPy."""
    rng = np.random.default_rng(0)
    alpha = 1.0 + k_mu / k_lambda
    mu_l, lam_l = k_mu, k_lambda - k_mu
    worst = 0.0
    for _ in range(20):
        h = 1e-4 * rng.standard_normal((2, 2))
        f = np.eye(2) + h
        psi = k_mu / 2 * (np.sum(f * f) - 2.0) + k_lambda / 2 * (np.linalg.det(f) - alpha) ** 2
        psi0 = k_lambda / 2 * (1.0 - alpha) ** 2
        eps = 0.5 * (h + h.T)
        lin = mu_l * np.sum(eps * eps) + lam_l / 2 * np.trace(eps) ** 2
        worst = max(worst, abs((psi - psi0) - lin) / lin)
    return worst


class NewtonCloth:
    """One cloth in Newton on the CPU: vertices (V,3) [m], triangles (F,3) (the engine's winding),
    pinned vertex indices, areal density [kg/m^2], `params` from `mapping`, gravity [m/s^2] along -y."""

    def __init__(self, vertices, triangles, pinned, *, density: float, params: dict, gravity: float):
        import newton
        import warp as wp

        init_warp()
        self.wp = wp
        t0 = time.perf_counter()
        b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -gravity, 0.0))
        b.add_cloth_mesh(
            pos=wp.vec3(0.0, 0.0, 0.0),
            rot=wp.quat_identity(),
            scale=1.0,
            vel=wp.vec3(0.0, 0.0, 0.0),
            vertices=np.asarray(vertices, dtype=np.float64),
            indices=np.asarray(triangles, dtype=np.int64).reshape(-1).tolist(),
            density=density,
            tri_ke=params["tri_ke"],
            tri_ka=params["tri_ka"],
            tri_kd=params["tri_kd"],
            tri_drag=0.0,
            tri_lift=0.0,
            edge_ke=params["edge_ke"],
            edge_kd=params["edge_kd"],
            particle_radius=0.005,
        )
        for i in np.asarray(pinned, dtype=np.int64).tolist():
            b.particle_mass[i] = 0.0
            b.particle_flags[i] = b.particle_flags[i] & ~newton.ParticleFlags.ACTIVE
        self.build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        self.model = b.finalize(device="cpu")
        self.finalize_s = time.perf_counter() - t0  # includes the compile of Newton's mesh/BVH modules
        self.model.particle_grid = None  # no particle-particle contact
        self.solver = newton.solvers.SolverSemiImplicit(self.model, enable_tri_contact=False)
        self.control = self.model.control()
        self.states = [self.model.state(), self.model.state()]
        self.x0 = self.states[0].particle_q.numpy().copy()
        self.mass = self.model.particle_mass.numpy().astype(np.float64)
        self.counts = {
            "particles": int(self.model.particle_count),
            "triangles": int(self.model.tri_count),
            "edges (bending elements, boundary ones inactive)": int(self.model.edge_count),
        }
        self.params = dict(params)

    def set_state(self, x: np.ndarray, v: np.ndarray) -> None:
        for s in self.states:
            s.particle_q.assign(np.asarray(x, dtype=np.float32))
            s.particle_qd.assign(np.asarray(v, dtype=np.float32))

    def reset(self) -> None:
        self.set_state(self.x0, np.zeros_like(self.x0))

    def step(self, dt: float) -> None:
        s0, s1 = self.states
        s0.clear_forces()
        self.solver.step(s0, s1, self.control, None, dt)
        self.states = [s1, s0]

    def frame(self, dt: float, substeps: int) -> np.ndarray:
        """`substeps` steps of dt, then the positions copied to NumPy (as Warp's cloth benchmark does)."""
        for _ in range(substeps):
            self.step(dt)
        return self.positions()

    def positions(self) -> np.ndarray:
        self.wp.synchronize()
        return self.states[0].particle_q.numpy().astype(np.float64)

    def velocities(self) -> np.ndarray:
        self.wp.synchronize()
        return self.states[0].particle_qd.numpy().astype(np.float64)

    def accelerations(self, x: np.ndarray, v: np.ndarray, gravity: float) -> np.ndarray:
        """Internal-force acceleration f(x, v) / m at (x, v) [m/s^2] (gravity removed), from one
        semi-implicit step of dt = 1 s: v1 = v + (f / m + g)."""
        self.set_state(x, v)
        self.step(1.0)
        a = self.velocities() - np.asarray(v, dtype=np.float32).astype(np.float64)
        a[:, 1] += gravity
        return a


def timed_frames(cloth: NewtonCloth, dt: float, substeps: int, frames: int, clock) -> dict:
    """First frame (module compile included) apart, then `frames` frames from the start, each timed;
    returns times and the final positions."""
    cloth.reset()
    t0 = clock()
    cloth.frame(dt, substeps)
    first = clock() - t0
    cloth.reset()
    times = []
    x = None
    for _ in range(frames):
        t0 = clock()
        x = cloth.frame(dt, substeps)
        times.append(clock() - t0)
    finite = bool(np.isfinite(x).all())
    return {"first_frame": first, "frame_times": times, "x": x, "finite": finite}


def describe_mapping(params: dict, cell: float) -> str:
    return (
        f"tri_ke = {params['tri_ke']:.4g} N/m, tri_ka = {params['tri_ka']:.4g} N/m, tri_kd = "
        f"{params['tri_kd']:.3g} N s/m, edge_ke = {params['edge_ke']:.4g} (D / a^3, a = {cell:.4g} m), "
        f"edge_kd = {params['edge_kd']:.3g}"
    )


def linearisation_check(params: dict) -> float:
    return _check_stable_neo_hookean_linearisation(params["tri_ke"], params["tri_ka"])


__all__ = [
    "NewtonCloth",
    "available",
    "describe_mapping",
    "init_warp",
    "linearisation_check",
    "mapping",
    "timed_frames",
    "versions",
]
