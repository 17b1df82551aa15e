"""The fluid kind's builder part: one incompressible liquid per scene (`add_fluid`: its particle
spacing, rest density and pressure solver), blocks of it (`add_fluid_block`) and particle sets
(`add_fluid_particles`). Liquid particles are particles (bodies/particles/) of radius 0: gravity, the
integrator, the exporters and the renderer treat them as such, colliders and bodies only stop them
crossing a surface; the liquid's solver (dfsph.py) makes them incompressible and keeps them half a
spacing from every surface."""

from __future__ import annotations

import math

import numpy as np

from ... import validate
from ...errors import ParameterError
from .sph_kernel import lattice_sum

METHODS = ("dfsph",)
SUPPORT_PER_SPACING = 2.0  # support radius H = 2 spacings (= 4 particle radii, as in SPlisHSPlasH)


class FluidBuilder:
    """Builder methods of the fluid kind: add_fluid, add_fluid_block, add_fluid_particles."""

    def _init_fluid(self) -> None:
        self._fluid: dict | None = None
        self._fluid_particles: list[range] = []

    def add_fluid(
        self,
        *,
        spacing: float,
        density: float = 1000.0,
        method: str = "dfsph",
        tolerance: float = 5e-4,
        divergence_tolerance: float = 1e-3,
        min_iterations: int = 2,
        max_iterations: int = 100,
        viscosity: float = 0.01,
        cfl: float = 0.4,
        max_step: float = 0.005,
        max_substeps: int = 64,
        domain=None,
    ) -> None:
        """The scene's liquid: particles `spacing` [m] apart at rest (support radius 2 spacings), rest
        `density` [kg/m^3], made incompressible by `method` "dfsph" (divergence-free SPH, Bender &
        Koschier 2015): each step's pressure solve iterates until the mean predicted density error is
        below `tolerance` (a fraction of the rest density: 5e-4 = 0.05 %, SPlisHSPlasH's dam break), the
        divergence solve until the mean density change over a step is below `divergence_tolerance`,
        with at least `min_iterations` (the divergence solve at most one) and at most `max_iterations`
        each; `viscosity`: XSPH's coefficient in [0, 1] (Monaghan 1989: each particle takes that
        fraction of its neighbours' kernel-weighted velocity difference per step); `cfl`: a substep
        moves no particle more than this fraction of a spacing, and lasts at most `max_step` [s] (the
        solver splits a step into at most `max_substeps`); `domain` (lo, hi) [m]: where the liquid can
        go (default: the container box, else 3 times the blocks' extent), which bounds the neighbour
        grid and the boundary samples of planes."""
        if self._fluid is not None:
            raise ParameterError("add_fluid was already called: a scene holds one liquid")
        validate.choice("method", method, list(METHODS))
        if domain is not None:
            if len(domain) != 2:
                raise ParameterError(f"domain must be (lo, hi), got {domain!r}")
            domain = validate.box("domain", *domain)
        self._fluid = dict(
            spacing=validate.positive("spacing", spacing),
            density=validate.positive("density", density),
            method=method,
            tolerance=validate.in_range("tolerance", tolerance, 1e-7, 0.5),
            divergence_tolerance=validate.in_range("divergence_tolerance", divergence_tolerance, 1e-7, 0.5),
            min_iterations=validate.count("min_iterations", min_iterations, 0),
            max_iterations=validate.count("max_iterations", max_iterations, 1),
            viscosity=validate.in_range("viscosity", viscosity, 0.0, 1.0),
            cfl=validate.in_range("cfl", cfl, 1e-3, 1.0),
            max_step=validate.positive("max_step", max_step),
            max_substeps=validate.count("max_substeps", max_substeps, 1),
            domain=domain,
        )
        if self._fluid["min_iterations"] > self._fluid["max_iterations"]:
            raise ParameterError(
                f"min_iterations ({min_iterations}) must not exceed max_iterations ({max_iterations})"
            )

    def add_fluid_block(self, lo, hi, *, velocity=(0.0, 0.0, 0.0)) -> range:
        """Fill the box lo..hi [m] with the liquid (add_fluid first): a cubic lattice of the fluid's
        spacing, centred in the box, moving at `velocity` [m/s]. Returns the particles' indices."""
        if self._fluid is None:
            raise ParameterError("add_fluid_block needs the liquid: call add_fluid(spacing=...) first")
        lo, hi = validate.box("add_fluid_block", lo, hi)
        d = self._fluid["spacing"]
        counts = np.floor((hi - lo) / d + 1e-9).astype(np.int64)
        if np.any(counts < 1):
            raise ParameterError(
                f"the box lo={lo.tolist()}, hi={hi.tolist()} is thinner than the spacing {d} on some axis"
            )
        total = int(np.prod(counts))
        validate.capacity("add_fluid_block", self.particle_count + total, bytes_each=0, unit="particles")
        start = lo + 0.5 * ((hi - lo) - (counts - 1) * d)
        axes = [start[a] + d * np.arange(counts[a]) for a in range(3)]
        x = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        v = np.broadcast_to(np.asarray(validate.vec3("velocity", velocity)), x.shape)
        idx = self.add_particles(x, v, self.fluid_particle_mass())
        self._fluid_particles.append(idx)
        return idx

    def add_fluid_particles(self, x, v=None) -> range:
        """Add liquid particles at x (N,3) [m] with velocities v (N,3) [m/s] (default 0), e.g. another
        tool's particle set; they should lie about a spacing apart, as add_fluid_block's lattice does
        (each gets the mass of a lattice particle). Returns their indices."""
        if self._fluid is None:
            raise ParameterError("add_fluid_particles needs the liquid: call add_fluid(spacing=...) first")
        idx = self.add_particles(x, v, self.fluid_particle_mass())
        self._fluid_particles.append(idx)
        return idx

    def fluid_particle_mass(self) -> float:
        """[kg] the mass that gives an interior particle of the rest lattice exactly the rest density."""
        if self._fluid is None:
            raise ParameterError("the scene has no liquid: call add_fluid first")
        d = self._fluid["spacing"]
        return self._fluid["density"] / lattice_sum(d, SUPPORT_PER_SPACING * d)

    def fluid_arrays(self) -> dict:
        """The fluid kind's arrays for finalize (init_model's keyword arguments)."""
        if self._fluid is None or not self._fluid_particles:
            return dict(particles=np.zeros(0, np.int64), options=None)
        idx = np.concatenate([np.arange(r.start, r.stop) for r in self._fluid_particles])
        options = dict(self._fluid, domain=self._fluid_domain(idx), mass=self.fluid_particle_mass())
        return dict(particles=idx, options=options)

    def fluid_settings(self) -> dict:
        """run.json's record of the liquid (its options and particle count)."""
        if self._fluid is None:
            return {}
        out = {k: v for k, v in self._fluid.items() if k != "domain"}
        return {"fluid": {**out, "particles": sum(len(r) for r in self._fluid_particles)}}

    def _fluid_domain(self, idx) -> tuple:
        """(lo, hi) [m] the liquid can reach: add_fluid's domain, else the container boxes, else the
        blocks' box grown by its extent on every side."""
        if self._fluid["domain"] is not None:
            return self._fluid["domain"]
        if self._containers:
            lo = np.min([c[0] for c in self._containers], axis=0)
            hi = np.max([c[1] for c in self._containers], axis=0)
            return lo, hi
        x = np.concatenate(self._x)[idx]
        lo, hi = x.min(axis=0), x.max(axis=0)
        pad = np.maximum(hi - lo, math.sqrt(3.0) * self._fluid["spacing"])
        return lo - pad, hi + pad
