"""The fluid kind's builder part: one incompressible liquid per scene (`add_fluid`: its particle
spacing, rest density and pressure solver), and where it comes from: blocks (`add_fluid_block`),
particle sets (`add_fluid_particles`), closed meshes filled (`add_fluid_mesh`) and nozzles
(`add_fluid_emitter`: the particle kind's emitters, emitting whole lattice layers). Liquid particles
are particles (bodies/particles/) of radius 0: gravity, the integrator, the exporters and the renderer
treat them as such, colliders and bodies only stop them crossing a surface; the liquid's solver
(dfsph.py) makes them incompressible and keeps them half a spacing from every surface."""

from __future__ import annotations

import math

import numpy as np

from ... import validate
from ...errors import ParameterError
from ...geometry import load_mesh
from ...particles.emitters import EmitterSettings, EmitterShape, disc_lattice
from ...shapes import _check_closed
from ...spatial.mesh_query import check_mesh, inside_closed_mesh
from ..particles.state import ALIVE_FOREVER
from .sph_kernel import lattice_sum

METHODS = ("dfsph", "pbf")
SUPPORT_PER_SPACING = 2.0  # support radius H = 2 spacings (= 4 particle radii, as in SPlisHSPlasH)


class FluidBuilder:
    """Builder methods of the fluid kind: add_fluid, add_fluid_block, add_fluid_particles."""

    def _init_fluid(self) -> None:
        self._fluid: dict | None = None
        self._fluid_particles: list[range] = []
        self._fluid_emitters: list[int] = []  # indices into the particle kind's emitters

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
        surface_tension: float = 0.0,
        cfl: float = 0.4,
        max_step: float = 0.005,
        max_substeps: int = 64,
        domain=None,
    ) -> None:
        """The scene's liquid: particles `spacing` [m] apart at rest (support radius 2 spacings), rest
        `density` [kg/m^3], made incompressible by `method` "dfsph" (divergence-free SPH, Bender & Koschier
        2015) or "pbf" (position-based fluids, Macklin & Müller 2013: density constraints on predicted
        positions, no divergence solve): each step's pressure solve iterates until the mean predicted density
        error is below `tolerance` (a fraction of the rest density: 5e-4 = 0.05 %, SPlisHSPlasH's dam break),
        the divergence solve until the mean density change over a step is below `divergence_tolerance`, with
        at least `min_iterations` (the divergence solve at most one) and at most `max_iterations` each;
        `viscosity`: XSPH's coefficient in [0, 1] (Monaghan 1989: each particle takes that fraction of its
        neighbours' kernel-weighted velocity difference per step); `surface_tension`: the gamma of Akinci et
        al.'s (2013) cohesion and curvature forces between neighbours (0: none; SPlisHSPlasH's examples use
        0.1 to 1); `cfl`: a substep moves no particle more than this fraction of a spacing, and lasts at most
        `max_step` [s] (the solver splits a step into at most `max_substeps`); `domain` (lo, hi) [m]: where
        the liquid can go (default: the container box, else 3 times the blocks' extent), which bounds the
        neighbour grid and the boundary samples of planes."""
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
            surface_tension=validate.non_negative("surface_tension", surface_tension),
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

    def add_fluid_mesh(self, mesh, *, velocity=(0.0, 0.0, 0.0)) -> range:
        """Fill a closed mesh with the liquid (add_fluid first): the points of add_fluid_block's lattice
        over the mesh's bounding box (a box's mesh fills as the box does) whose generalized winding
        number (Jacobson et al., "Robust Inside-Outside Segmentation using Generalized Winding
        Numbers", SIGGRAPH 2013) is at least 1/2, moving at `velocity` [m/s]. Each particle stands for
        a spacing^3, so the liquid's volume is the mesh's to within its surface's share of a lattice
        cell. `mesh`: an Open3D TriangleMesh, a file, or (vertices, triangles), closed and consistently
        oriented. Returns the particles' indices."""
        if self._fluid is None:
            raise ParameterError("add_fluid_mesh needs the liquid: call add_fluid(spacing=...) first")
        v, f = load_mesh(mesh, name="add_fluid_mesh", check=check_mesh)
        _check_closed(f)
        lo, hi = v.min(axis=0), v.max(axis=0)
        d = self._fluid["spacing"]
        counts = np.maximum(np.floor((hi - lo) / d + 1e-9).astype(np.int64), 1)  # add_fluid_block's lattice
        # The lattice of the bounding box is at most twice the liquid: refused before it is made.
        validate.capacity("add_fluid_mesh", self.particle_count + int(np.prod(counts)), bytes_each=0,
                          unit="lattice points in the mesh's bounding box")  # fmt: skip
        start = lo + 0.5 * ((hi - lo) - (counts - 1) * d)
        axes = [start[a] + d * np.arange(counts[a]) for a in range(3)]
        x = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        x = x[inside_closed_mesh(v, f, x)]  # NumPy for a small mesh and lattice: no kernel to compile
        if not len(x):
            raise ParameterError(f"add_fluid_mesh: the mesh holds no lattice point of spacing {d}")
        return self.add_fluid_particles(x, np.broadcast_to(validate.vec3("velocity", velocity), x.shape))

    def add_fluid_particles(self, x, v=None) -> range:
        """Add liquid particles at x (N,3) [m] with velocities v (N,3) [m/s] (default 0), e.g. another
        tool's particle set; they should lie about a spacing apart, as add_fluid_block's lattice does
        (each gets the mass of a lattice particle). Returns their indices."""
        if self._fluid is None:
            raise ParameterError("add_fluid_particles needs the liquid: call add_fluid(spacing=...) first")
        idx = self.add_particles(x, v, self.fluid_particle_mass())
        self._fluid_particles.append(idx)
        return idx

    def add_fluid_emitter(
        self,
        *,
        center,
        radius: float,
        speed: float,
        direction=(0.0, -1.0, 0.0),
        start_time: float = 0.0,
        stop_time: float | None = None,
        capacity: int | None = None,
    ) -> int:
        """A nozzle (add_fluid first): a disc of `radius` [m] at `center` facing `direction` emits the
        liquid at `speed` [m/s], one layer of the rest lattice (the disc's points a spacing apart) each
        time the last has moved a spacing, from `start_time` until `stop_time` [s] (None: for as long as
        its slots last). Its `capacity` of particle slots defaults to what it emits until stop_time; it
        then stops. The flow is speed x (points per layer x spacing^2) [m^3/s]. Emitted particles are
        liquid like a block's (they do not die). Returns the emitter index (particles' emitters)."""
        if self._fluid is None:
            raise ParameterError("add_fluid_emitter needs the liquid: call add_fluid(spacing=...) first")
        d = self._fluid["spacing"]
        radius = validate.non_negative("radius", radius)
        speed = validate.positive("speed", speed)
        start_time = validate.non_negative("start_time", start_time)
        points = len(disc_lattice(radius, d))
        if stop_time is not None:
            stop_time = validate.positive("stop_time", stop_time)
            if stop_time <= start_time:
                raise ParameterError(f"stop_time ({stop_time}) must exceed start_time ({start_time})")
        if capacity is None:
            if stop_time is None:
                raise ParameterError("add_fluid_emitter needs stop_time or capacity (the particle slots)")
            capacity = points * (math.ceil(speed * (stop_time - start_time) / d) + 1)
        capacity = validate.count("capacity", capacity, points)
        validate.capacity("capacity", self.particle_count + capacity, bytes_each=0, unit="particles")
        settings = EmitterSettings(
            shape=EmitterShape.DISC, center=validate.vec3("center", center), size=(radius, 0.0, 0.0),
            direction=validate.unit3("direction", direction), rate=points * speed / d, speed=speed,
            speed_jitter=0.0, spread=0.0, lifetime=ALIVE_FOREVER, lifetime_jitter=0.0,
            mass=self.fluid_particle_mass(), capacity=capacity, color_start=(0.3, 0.5, 0.9),
            color_end=(0.3, 0.5, 0.9), lattice=d, start_time=start_time, stop_time=stop_time,
        )  # fmt: skip
        self._emitters.append(settings)
        self._fluid_emitters.append(len(self._emitters) - 1)
        return len(self._emitters) - 1

    def fluid_particle_mass(self) -> float:
        """[kg] the mass that gives an interior particle of the rest lattice exactly the rest density."""
        if self._fluid is None:
            raise ParameterError("the scene has no liquid: call add_fluid first")
        d = self._fluid["spacing"]
        return self._fluid["density"] / lattice_sum(d, SUPPORT_PER_SPACING * d)

    def fluid_arrays(self) -> dict:
        """The fluid kind's arrays for finalize (init_model's keyword arguments)."""
        if self._fluid is None or not (self._fluid_particles or self._fluid_emitters):
            return dict(particles=np.zeros(0, np.int64), options=None)
        added = [np.arange(r.start, r.stop) for r in self._fluid_particles]
        slots, start = [], self.particle_count  # emitters' slots follow the added particles (particle kind)
        for k, es in enumerate(self._emitters):
            if k in self._fluid_emitters:
                slots.append(np.arange(start, start + es.capacity))
            start += es.capacity
        idx = np.concatenate([np.zeros(0, np.int64), *added, *slots])
        domain = self._fluid_domain(np.concatenate([np.zeros(0, np.int64), *added]))
        for k in self._fluid_emitters:  # a nozzle outside would emit where the neighbour grid is not
            c = np.asarray(self._emitters[k].center)
            if np.any(c < domain[0]) or np.any(c > domain[1]):
                raise ParameterError(
                    f"add_fluid_emitter: center {c.tolist()} lies outside the liquid's domain "
                    f"{np.asarray(domain[0]).tolist()} .. {np.asarray(domain[1]).tolist()} "
                    "(add_fluid(domain=...))"
                )
        options = dict(self._fluid, domain=domain, mass=self.fluid_particle_mass())
        return dict(particles=idx, options=options)

    def fluid_settings(self) -> dict:
        """run.json's record of the liquid (its options and particle count)."""
        if self._fluid is None:
            return {}
        out = {k: v for k, v in self._fluid.items() if k != "domain"}
        slots = sum(self._emitters[k].capacity for k in self._fluid_emitters)
        added = sum(len(r) for r in self._fluid_particles)
        return {"fluid": {**out, "particles": added, "emitter_slots": slots}}

    def _fluid_domain(self, idx) -> tuple:
        """(lo, hi) [m] the liquid can reach: add_fluid's domain, else the container boxes, else the box
        of the blocks' particles `idx` and the nozzles' centres grown by its extent on every side."""
        if self._fluid["domain"] is not None:
            return self._fluid["domain"]
        if self._containers:
            lo = np.min([c[0] for c in self._containers], axis=0)
            hi = np.max([c[1] for c in self._containers], axis=0)
            return lo, hi
        x = np.concatenate([np.zeros((0, 3)), *self._x])[idx]
        x = np.concatenate([x, np.reshape([self._emitters[k].center for k in self._fluid_emitters], (-1, 3))])
        lo, hi = x.min(axis=0), x.max(axis=0)
        pad = np.maximum(hi - lo, math.sqrt(3.0) * self._fluid["spacing"])
        return lo - pad, hi + pad
