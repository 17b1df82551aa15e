"""The benchmark's sheets, built through taichi_anim's public API, and the NumPy geometry around them:
grid indices, perturbed positions for the force check, distances between answers.

The catalogue's cloth scene (`taichi_anim.scenes.cloth.build`) is not reused for the sheets: it hangs a
sheet from two corners at 1.2 m with air drag, stiffer bending springs (50 N/m) and FABRIC's default
damping (1e-3 s), none of which this benchmark measures; its fabric, FABRIC, is (config.MEMBRANE)."""

from __future__ import annotations

import math

import numpy as np

import taichi_anim as ta

from .config import FORCE_AMPLITUDE, GRAVITY, HEIGHT, IN_PLANE, OUT_OF_PLANE, SIDE


class Sheet:
    """A built cloth: model, one reusable state (the kernels take the state as a template argument, so a
    new state would recompile them), initial positions, masses, free vertices, triangles.
    pins: "edge" (the whole edge j = 0) or "corners" (its two ends)."""

    def __init__(self, material, n: int, pins: str = "edge"):
        self.n = n
        self.rk4 = None  # measure.rk4_run's integrator, made on first use
        b = ta.Builder()
        handle = b.add_cloth_grid(
            origin=(0.0, HEIGHT, 0.0),
            size=(SIDE, SIDE),
            resolution=(n, n),
            plane="xz",
            material=material,
            thickness=0.005,
            pinned=list(range(n)) if pins == "edge" else [0, n - 1],
        )
        b.add_force_gravity((0.0, -GRAVITY, 0.0))
        self.model = b.finalize(seed=0)
        self.state = self.model.state()
        x0 = self.state.particle_x.to_numpy()
        self.dtype = x0.dtype
        self.x0 = x0.astype(np.float64)
        self.mass = self.model.particle_masses()
        self.free = self.mass > 0.0
        self.triangles = np.asarray(handle.triangles)
        self.pinned = np.asarray(handle.pinned)

    def set(self, integ, x: np.ndarray, v: np.ndarray) -> None:
        """Positions and velocities; time, step count and divergence watch cleared; an implicit
        integrator's warm start cleared."""
        st = self.state
        st.particle_x.from_numpy(np.asarray(x, dtype=self.dtype))
        st.particle_v.from_numpy(np.asarray(v, dtype=self.dtype))
        st.time = 0.0
        st.step_count = 0
        st.nonfinite_count[None] = 0
        st.nonfinite_step[None] = 2**31 - 1
        if getattr(integ, "system", None) is not None:
            integ.system.solution.fill(0.0)

    def reset(self, integ) -> None:
        self.set(integ, self.x0, np.zeros_like(self.x0))

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        return (
            self.state.particle_x.to_numpy().astype(np.float64),
            self.state.particle_v.to_numpy().astype(np.float64),
        )

    def positions(self) -> np.ndarray:
        return self.state.particle_x.to_numpy().astype(np.float64)


def errors(x: np.ndarray, ref: np.ndarray, free: np.ndarray) -> tuple[float, float]:
    """(max, RMS) over free vertices of |x - ref| [m]; NaN if not finite."""
    with np.errstate(all="ignore"):
        e = np.linalg.norm(x[free] - ref[free], axis=1)
    if not np.all(np.isfinite(e)):
        return float("nan"), float("nan")
    return float(e.max()), float(np.sqrt(np.mean(e**2)))


def worst_vertex(x: np.ndarray, ref: np.ndarray, free: np.ndarray, n: int) -> str:
    """Grid vertex (i, j) of the largest |x - ref| among free vertices (j = 0: the pinned edge)."""
    d = np.where(free, np.linalg.norm(x - ref, axis=1), -1.0)
    k = int(np.argmax(d))
    return f"({k % n}, {k // n})"


def coarse_index(n: int, factor: int) -> np.ndarray:
    """Indices, on the (n-1) factor + 1 grid, of the n x n grid's vertices (row-major j n + i)."""
    nf = (n - 1) * factor + 1
    j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return (factor * j * nf + factor * i).ravel()


def interior(n: int, margin: int = 2) -> np.ndarray:
    j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    keep = (i >= margin) & (i < n - margin) & (j >= margin) & (j < n - margin)
    return keep.ravel()


def force_configs(x0: np.ndarray) -> dict:
    """Perturbed positions for the mapping check, zero at the pinned edge: an in-plane displacement (the
    membrane's forces; bending stays flat) and an out-of-plane one (for the bending-only cloths: with a
    membrane, f32 round-off of Newton's membrane forces, ~0.5 m/s² per vertex at 32², would swamp the
    bending forces of any out-of-plane displacement small enough to keep the membrane's own part
    negligible)."""
    u, w = x0[:, 0] / SIDE, x0[:, 2] / SIDE
    a = FORCE_AMPLITUDE[IN_PLANE]
    d = np.zeros_like(x0)
    d[:, 0] = a * np.sin(math.pi * w) * np.cos(2 * math.pi * u)
    d[:, 2] = a * np.sin(math.pi * w) * np.sin(math.pi * u)
    b = FORCE_AMPLITUDE[OUT_OF_PLANE]
    bump = np.zeros_like(x0)
    bump[:, 1] = b * np.sin(1.5 * math.pi * w) * np.sin(1.5 * math.pi * u) * w
    return {IN_PLANE: x0 + d, OUT_OF_PLANE: x0 + bump}
