"""The liquid solver's report (dfsph.py): per frame for run.json and per run, the pressure iterations and
the density errors, both as the solves predict them after their iterations and as the positions the
steps reached have them (measured by the neighbourhood pass at each next substep's start, after the
walls' guard, which the predictions do not see). This mixin holds the reading, on FluidDynamics's
fields (`reached`, `overflow`) and step records (`_frame`, `totals`)."""

import taichi as ti

from ...runtime import data_oriented


@data_oriented
class FluidReport:
    """Mixin of FluidDynamics: frame_stats() and stats()."""

    def frame_stats(self) -> dict:
        """The steps since the last call, summed up for run.json's per-frame record: steps, pressure
        iterations (density and divergence), the largest mean and largest single density error after
        the density solves (as they predict them), the same at the positions the steps reached
        (`reached_...`: measured at each next substep's start, after the walls' guard), and the
        neighbours left out of full lists since the run started."""
        steps, self._frame = self._frame, []
        if not steps:
            return {}
        return dict(
            steps=len(steps),
            density_iterations=sum(s["density_iterations"] for s in steps),
            divergence_iterations=sum(s["divergence_iterations"] for s in steps),
            mean_density_error=max(s["mean_density_error"] for s in steps),
            max_density_error=max(s["max_density_error"] for s in steps),
            **self._reached(frame=True),
            neighbor_overflow=int(self.overflow[None]),
        )

    def _reached(self, frame: bool) -> dict:
        """The largest mean and largest single density error at the positions reached, over the steps
        since the last frame (and starts a new frame's) or over the run."""
        r = self._read_reached(frame)
        if frame:
            return dict(reached_density_error=float(r[0]), reached_max_density_error=float(r[1]))
        return dict(reached_mean_error_max=float(r[2]), reached_max_error_max=float(r[3]))

    # One serial launch: field.to_numpy() is a parallel loop (0.2 ms here for these four numbers, the
    # thread pool's wake-up), and the reset another launch.
    @ti.kernel
    def _read_reached(self, new_frame: ti.template()) -> ti.types.vector(4, float):
        """The reached errors (frame mean, frame max, run mean, run max); with new_frame, the frame's
        two start again from 0."""
        out = ti.Vector.zero(float, 4)
        ti.loop_config(serialize=True)
        for _ in range(1):
            out = self.reached[None]
            if ti.static(new_frame):
                self.reached[None][0] = 0.0
                self.reached[None][1] = 0.0
        return out

    def stats(self) -> dict:
        """Totals over the run: steps, iterations, steps that reached max_iterations above the
        tolerance, the largest mean and largest single density error after a solve (predicted) and at
        the positions reached (`reached_...`), and how many neighbours did not fit the lists (0 unless
        the liquid was compressed far beyond rest)."""
        return dict(self.totals, **self._reached(frame=False), neighbor_overflow=int(self.overflow[None]))
