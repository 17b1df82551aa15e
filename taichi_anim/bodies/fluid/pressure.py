"""The liquid's pressure solves (dfsph.py, steps 1 and 3 of its docstring): the divergence solve and the
density solve of divergence-free SPH (Bender & Koschier, SCA 2015, alg. 2 and 3; TVCG 2017, eq. 8-12),
iterated until the mean error is under the tolerance. This mixin holds them, on FluidDynamics's fields
(the neighbour lists, alpha, kappa) and its neighbourhood pass.

A solve is a launch for its warm start and first prediction and one per iteration, each returning the
errors' fixed-point sum (2^-40 units: its atomic sum does not depend on thread timing); for a small
liquid whose loops run serially, part of its substep's launch (serial_substep.py, through _solve_pass);
for a larger one on the CPU's workers, one launch whose passes meet at barriers (worker_solve.py)."""

import functools

import numpy as np
import taichi as ti

from ...runtime import data_oriented

DIVERGENCE_MIN_NEIGHBORS = 20  # sparser particles (spray, the free surface) skip the divergence solve
ERROR_SCALE = float(1 << 40)  # fixed-point unit of the summed errors


@functools.lru_cache(maxsize=1024)  # asked every substep, for a few tolerances and counts
def first_sum_above(tolerance: float, count: int) -> int:
    """The least fixed-point error sum e whose mean, e / ERROR_SCALE / count in floating point as _solve
    computes it, is above `tolerance`: comparing e >= it in a kernel stops where that mean would."""
    return int(first_sums_above(tolerance, np.array([count]))[0])


def first_sums_above(tolerance: float, counts: np.ndarray) -> np.ndarray:
    """first_sum_above(tolerance, n) for every n > 0 of `counts`, in float64 as Python's floats compute
    it: also the thresholds a kernel looks up when the live count is known only inside it (a liquid fed
    by nozzles, serial_substep.py). A bisection over the integers (int64 to float64 rounds as Python's
    int / float does): stepping a float64 sum by 1 stalls once it passes 2^53 (tolerance x count from
    8,192), which a large liquid's solve reaches."""
    n = np.asarray(counts, dtype=np.float64)

    def above(e):
        return e.astype(np.float64) / ERROR_SCALE / n > tolerance

    lo = np.zeros(n.shape, np.int64)  # 0 / S / n > tolerance is false for tolerance >= 0
    hi = np.floor(tolerance * ERROR_SCALE * n).astype(np.int64) + 2
    while not above(hi).all():
        hi = np.where(above(hi), hi, 2 * hi)
    while (hi - lo > 1).any():
        mid = lo + (hi - lo) // 2
        up = above(mid)
        hi, lo = np.where(up, mid, hi), np.where(up, lo, mid)
    return hi


# Warm starts: the share of the last step's summed stiffness a solve starts from. A kappa summed over
# iterations can only grow (each iteration's is clamped to compression), so too much of it overshoots:
# the whole of it made a settling column diverge within 4 steps of 4.2 ms (the corner particles, with
# few neighbours and large alpha, overshoot first); half of it, where a particle is headed into
# compression, takes 10 density iterations per step against 14.5 without (the column of
# tests/test_fluid.py at 2 cm spacing).
WARM_DENSITY, WARM_DIVERGENCE = 0.5, 0.0


@data_oriented
class PressureSolves:
    """Mixin of FluidDynamics: the divergence and density solves."""

    def _divergence_step(self, h: float, state) -> tuple[int, float]:
        """The divergence solve on the velocities at the substep's start: (iterations, mean error)."""
        iterations, mean, _ = self._solve(h, divergence=True, state=state)
        self._write_velocities(state, self.model, h)
        return iterations, mean

    def _density_step(self, h: float, state) -> tuple[int, float, float]:
        """The density solve on the velocities v* (self.sv): (iterations, mean, largest error)."""
        return self._solve(h, divergence=False, state=state)

    def _solve(self, h: float, *, divergence: bool, state) -> tuple[int, float, float]:
        """Iterate until the mean error is below the tolerance (at least min_iterations; the divergence
        solve at most one of them, as SPlisHSPlasH's): (iterations, mean error, largest error) of the
        final velocities."""
        n = int(self.grid.size[None]) if self.emitted else self.model.fluid_count
        if n == 0:  # nothing emitted yet
            return 0, 0.0, 0.0
        if self.coupled:
            self.bodies.move(self.model, state)  # the bodies' velocities now (the samples' speeds)
        tol = self.divergence_tolerance if divergence else self.tolerance
        least = min(self.min_iterations, 1) if divergence else self.min_iterations
        # Each launch returns the errors' fixed-point sum: reading the field after it would be one more
        # launch per iteration (a small liquid's frame made about 60 such reads).
        if self.workers:  # the whole solve in one launch (worker_solve.py)
            above = first_sum_above(tol, n)
            out = self._solve_by_workers(state, h, int(divergence), above, least, self.max_iterations)
            it, mean = int(out[0]), int(out[1]) / ERROR_SCALE / n
        else:
            mean = self._start(state, self.model, h, int(divergence)) / ERROR_SCALE / n
            it = 0
            while it < self.max_iterations and (mean > tol or it < least):
                mean = self._iterate(h, int(divergence)) / ERROR_SCALE / n
                it += 1
        if self.coupled:
            # The bodies take their impulses once per solve. Giving them back after every iteration
            # (the samples then moving within the solve) changed neither a floating plank's heave
            # nor its tilt over 3 s, so the cheaper exchange stays.
            self._push_bodies(self.model, state, h)
        return it, mean, float(self.err_max[None])

    @ti.func
    def _flux(self, k):
        """Drho_k/Dt [kg/m^3/s] from the slot velocities (static boundary)."""
        vi = self.sv[k]
        d = vi.dot(self.wall_grad[k])  # every boundary sample, the bodies' at rest
        for m in range(self.nn[k]):
            d += (vi - self.sv[self.nbr[k, m]]).dot(self.grad[k, m])
        if ti.static(self.coupled):  # the bodies' samples move
            for m in range(self.body_n[k]):
                d -= self.bodies.v[self.body_nbr[k, m]].dot(self.body_grad[k, m])
        return d

    @ti.func
    def _predict(self, h, divergence):
        """Each slot's stiffness kappa from its predicted error, and the errors' fixed-point sum and max."""
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            e = self._predict_one(k, h, divergence)
            ti.atomic_add(self.err_sum[None], ti.cast(e * ERROR_SCALE + 0.5, ti.i64))
            ti.atomic_max(self.err_max[None], e)

    @ti.func
    def _predict_one(self, k, h, divergence):
        """Slot k's stiffness kappa from its predicted error; returns the error."""
        d = self._flux(k)
        s, e = ti.cast(0.0, float), ti.cast(0.0, float)
        if divergence:
            if self.nn[k] + self.bn[k] >= DIVERGENCE_MIN_NEIGHBORS:
                s = ti.max(d, 0.0)
            self.kappa[k] = s * self.alpha[k] / h
            e = s * h / self.rest_density
        else:
            s = ti.max(self.rho[k] + h * d - self.rest_density, 0.0)
            self.kappa[k] = s * self.alpha[k] / (h * h)
            e = s / self.rest_density
        return e

    @ti.func
    def _correct(self, h, apply):
        """v_k -= h [sum_j m (kappa_k + kappa_j) grad W + sum_b psi_b kappa_k grad W]; kappa summed.
        `apply` (a flag read in the loop, so that the loop stays a parallel one): False skips it."""
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            if apply:
                self._correct_one(k, h)

    @ti.func
    def _correct_one(self, k, h):
        """Slot k's velocity corrected by the current stiffness, which its sum takes."""
        ki = self.kappa[k]
        dv = ki * self._push_sum(k)  # the walls' samples mirrored (wall_pressure.py)
        for m in range(self.nn[k]):
            dv += (ki + self.kappa[self.nbr[k, m]]) * self.grad[k, m]
        self.sv[k] -= h * dv
        self.kacc[k] += ki

    @ti.kernel
    def _start(self, state: ti.template(), model: ti.template(), h: float, divergence: ti.i32) -> ti.i64:
        """_first_prediction; returns the errors' fixed-point sum."""
        self._first_prediction(state, h, divergence)
        return self.err_sum[None]

    @ti.kernel
    def _iterate(self, h: float, divergence: ti.i32) -> ti.i64:
        """_next_prediction; returns the errors' fixed-point sum."""
        self._next_prediction(h, divergence)
        return self.err_sum[None]

    @ti.func
    def _solve_pass(self, state: ti.template(), h, divergence, above, least, most):
        """The whole solve inside a serial loop of the calling kernel (serial_substep.py): the first
        prediction, then iterations while the errors' sum is at least `above` (first_sum_above: where the
        launch-per-iteration loop in _solve stops) or fewer than `least` were made, at most `most`;
        returns the iterations. The first prediction is the loop's pass -1 (its warm start's correction
        skipped where _first_prediction skips it): one copy of the correction and prediction to compile,
        the same operations in the same order."""
        self._warm_start(state, h, divergence)
        apply = ti.static(WARM_DIVERGENCE > 0.0) or not divergence
        it = -1  # -1: the first prediction
        while it < 0 or (it < most and (self.err_sum[None] >= above or it < least)):
            self._prediction(h, divergence, apply)
            apply = True
            it += 1
        return it

    @ti.func
    def _density_pass(self, state: ti.template(), h, above, least, most):
        """The density solve inside a serial loop (serial_substep.py); returns the iterations."""
        return self._solve_pass(state, h, 0, above, least, most)

    @ti.func
    def _first_prediction(self, state: ti.template(), h, divergence):
        """Warm start from a share of the last step's stiffness, then the first prediction."""
        self._warm_start(state, h, divergence)
        self._prediction(h, divergence, ti.static(WARM_DIVERGENCE > 0.0) or not divergence)

    @ti.func
    def _warm_start(self, state: ti.template(), h, divergence):
        """Each slot's kappa from a share of the last step's stiffness (kacc, the sum, cleared)."""
        ti.loop_config(serialize=self.serial)
        for k in range(self._live()):
            self._warm_one(state, k, h, divergence)

    @ti.func
    def _warm_one(self, state: ti.template(), k, h, divergence):
        """Slot k's kappa from a share of the last step's stiffness; its sum cleared."""
        j = self.grid.sorted_id[k]
        self.kacc[k] = 0.0
        if divergence:
            self.kappa[k] = WARM_DIVERGENCE * state.fluid_kappa_v[j] / h
        else:
            # Only where the particle is headed into compression (as SPlisHSPlasH). Applied to every
            # particle, one start of a settled column read its pressure slope 4.5 % steep against
            # 1.5 %, but starts moved by 1e-10 m spread this way's from +1.5 to +7.3 %
            # (tests/test_fluid.py, SLOPE_TOLERANCE): the choice follows SPlisHSPlasH, not that pair.
            self.kappa[k] = 0.0
            if self.rho[k] + h * self._flux(k) > self.rest_density:
                self.kappa[k] = WARM_DENSITY * state.fluid_kappa[j] / (h * h)

    @ti.func
    def _next_prediction(self, h, divergence):
        """One correction and the next prediction."""
        self._prediction(h, divergence, True)

    @ti.func
    def _prediction(self, h, divergence, apply):
        """The correction by the current stiffness (where `apply`), then the errors' sums cleared and the
        next prediction."""
        self._correct(h, apply)
        self.err_sum[None] = 0
        self.err_max[None] = 0.0
        self._predict(h, divergence)
