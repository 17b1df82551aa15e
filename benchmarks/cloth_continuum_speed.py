"""Springs against membrane + bending on the same fabric: speed against error, distance from the continuum
answer, implicit steps/s at frame-size steps, and Newton's semi-implicit triangle FEM as a peer.

Scene (parts 1 and 3): a square cloth of side 1 m, n x n vertices (`Builder.add_cloth_grid`, plane "xz",
origin (0, 1, 0): flat, horizontal, at rest), areal density 0.2 kg/m^2 lumped by triangle area, gravity
(0, -9.81, 0) m/s^2, the whole edge j = 0 pinned (vertices 0 ... n-1), no colliders, no drag. It swings
down about that edge, passing the vertical near t = 0.45 s. The edge rather than two corners: with two
corners pinned the sheet compresses between the pins and buckles, and no affordable reference converges
(benchmarks/cloth_solvers.py, "Why not two corners"). Two models of one fabric, same stretch stiffness:
- springs: `ClothMaterial()` defaults (Provot's springs; stretch 1e3 N/m, shear 1e2, bend 10; damping
  0.05, 0.01, 0.005 kg/s along the springs; stretch beta = c / k = 5e-5 s);
- membrane: `FabricMaterial` = the demos' `scenes.cloth.FABRIC` (StVK membrane E = 1e3 N/m areal, nu = 0.3,
  dihedral bending D = 5e-5 N m, bending damping 1e-2 s) with its Rayleigh damping set to the springs'
  stretch beta, 5e-5 s, instead of FabricMaterial's default 1e-3 s. Why: with 1e-3 s the damping of the
  highest membrane modes (zeta = beta omega / 2 ~ 3 at 32^2) caps an explicit step near 4e-5 s whatever
  the stiffness (measured below, "Default membrane damping"), so an explicit comparison would measure the
  damping constant, not the model; and on finer meshes that cap falls like the cell squared, which makes
  a fine-mesh reference unaffordable. Matching beta gives both models the same damping of stretching.

Part 1, speed against error (32^2, T = 0.5 s, float64). For each model: a converged reference of THAT
model (RK4 at dt = 5e-5 s, checked against RK4 at 1e-4 s: RK4's error falls ~16x per halving, so the
reference's own error is ~1/15 of that difference); symplectic Euler at dt = 1/20000, 1/10000, 1/5000,
1/4000, 1/3000 ... s in that order until a run fails (non-finite, a vertex above 50 m/s, or the engine's
divergence error); implicit Euler (linearised
backward Euler, block-Jacobi PCG, warm start, max 1000 iterations) at dt = 1/60 ... 1/960 s and relative
residual tol 1e-4 and 1e-6. Error: max and RMS over the free vertices of |x(T) - x_ref(T)| [m], against
wall time per simulated second (`ti.sync()` before every clock read, positions read back 5 times per run
outside the timed segments; runs under 0.3 s repeated, fastest kept; each integrator warmed up first, the
compile reported apart). The continuum answer: the membrane on 2x and 3x refined meshes (63^2 and 94^2
vertices, so every coarse vertex is a fine vertex: sampled, not interpolated), RK4 at dt = 1e-4 s and
1/15000 s (the same dt / cell; the 63^2 run repeated at half its step shows what the step contributes).
Not 125^2: its RK4 run (dt = 5e-5 s, stable) took 152 s in f32 on this shared machine during
development, a third of the budget of the whole benchmark. Every model's converged 32^2 answer, the 63^2
membrane and springs on the 63^2 mesh are measured against the 94^2 membrane at the coarse material
points; every run of the sweep too (second plot panel): how far its
cloth is from the continuum answer per unit of wall time.

Part 2, implicit steps/s at dt = 1/60 s (float32, Taichi's default threads): membrane and springs at
64^2 and 128^2, the same fabric pinned at the two corners of one edge (the demos' and
benchmarks/cloth_implicit.py's layout; one step per frame), PCG at tol 1e-3 and 1e-4 (max 1000
iterations, warm start, check_every 10). One integrator per model and size: its first step (JIT compile
included) and a second step timed apart; each tol then resets the state in place (no recompile) and times
60 steps one by one; runs past RUN_BUDGET_S of timed steps are cut. Iterations per step: mean, max,
steps that reached the cap. Compile: first step minus second step, with Taichi's offline cache as the
machine has it (each model and size is a new compile: the kernels are specialised on the model's fields);
the three cache conditions of common.compile_times are not measured here (about a minute more, mostly
the membrane's implicit step, ~20-25 s per cold compile).

Part 3, Newton (`benchmarks/peers/newton_fem.py`): the part-1 scene (membrane, 32^2, edge pinned),
Newton's `SolverSemiImplicit` with triangle FEM + edge bending on the CPU (`wp.set_device("cpu")`, one
thread), same vertices, triangles, masses, pins, gravity, frame 1/60 s x NEWTON_SUBSTEPS symplectic steps,
T = 0.5 s (30 frames, positions copied to NumPy each frame), against taichi_anim's symplectic Euler on the
same scene at the same dt in float32 (Newton is float32), in the same process. Parameter mapping in the
peer's docstring (tri_ke = mu_L, tri_ka = lambda_L + mu_L, edge_ke = D / a^3, tri_kd = 2 beta mu_L,
edge_kd = beta_b edge_ke / a^2); Newton runs with that damping and with none. Checks of the mapping:
accelerations of both engines at the same perturbed positions (an in-plane displacement of the membrane
cloths; an out-of-plane bump of bending-only cloths, each minus its acceleration at rest), and the NumPy
check of the linearised energy. Our membrane also runs undamped, the counterpart of Newton's undamped
run. Reported: ms per frame (first frame with the cold compile apart: Warp's kernel cache in a fresh
folder), CPU cores busy, and the final shape against our runs (same dt, f32) and against the converged
f64 membrane reference.

    .venv/bin/python benchmarks/cloth_continuum_speed.py          # full run (~8 min), benchmarks/results/
    .venv/bin/python benchmarks/cloth_continuum_speed.py --quick  # smoke run (~2 min), benchmarks/out/
"""

from continuum.run import main

if __name__ == "__main__":
    main(__doc__)
