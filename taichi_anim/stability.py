"""Stability guard: the model's highest frequency against the explicit method's stability region.

Highest frequency. Linearised about a state, the model is M x'' + C x' + K x = f, K = -df/dx and
C = -df/dv summed over the force terms (springs, membrane, bending, aerodynamic panels, anchors, drag;
each term's own positive semi-definite linearisation, the one the implicit solvers use); sphere contacts
are projections, not penalty springs, and add no stiffness. The modes' squared frequencies are the
eigenvalues of M^-1 K over the free particles (pinned particles, of mass 0, are left out), the same as
those of the symmetric Ks = M^-1/2 K M^-1/2. Two estimates of its largest eigenvalue omega_max^2:
  - block Gershgorin (Feingold & Varga, "Block diagonally dominant matrices and generalizations of the
    Gerschgorin circle theorem", Pacific J. Math. 12, 1962): every eigenvalue of the symmetric Ks lies
    below max_i [lambda_max(D_i) + sum_j ||B_ij||_2], D_i the 3x3 diagonal and B_ij the off-diagonal
    blocks of particle i's row. A guaranteed upper bound, one pass over the elements;
  - Lanczos with full reorthogonalisation (Golub & Van Loan, "Matrix Computations", 4th ed., sec. 10.1)
    on Ks, from a seeded random start, until the top Ritz pair's residual r = beta_m |y_m| is below
    1e-3 of its value; omega^2 = theta + r (an eigenvalue lies within r of theta; Lanczos reaches the
    top of the spectrum first, so this is omega_max^2 to about r in practice, not a proven bound).
The damping ratio of that mode is zeta = u^T Cs u / (2 omega), u the unit Ritz vector. Springs and
pointwise terms give their blocks in NumPy; for the other element terms (fast_blocks False), whose exact
element Hessians take long to compile, Lanczos multiplies by central differences of the total force
instead (no bound).

Stability region. Each mode is the test system y' = A y, A = [[0, 1], [-w^2, -c]], its eigenvalues
lambda = -c/2 +- sqrt(c^2/4 - w^2). A Runge-Kutta method multiplies them by its stability function
R(h lambda) = 1 + z b^T (I - z A_rk)^-1 1 (Hairer & Wanner, "Solving ODEs II", sec. IV.2, eq. 2.3);
symplectic Euler's one-step map is [[1 - h^2 w^2, h (1 - h c)], [-h w^2, 1 - h c]], whose spectral radius
is 1 for h w < 2 undamped (Hairer, Lubich & Wanner, "Geometric Numerical Integration", sec. I.1.2).
A step h is within the limit when no mode's energy grows faster than GROWTH per second of simulated
time: rho(h)^(2/h) <= 1 + GROWTH. For symplectic Euler (h w < 2) and RK4 (|z| <= 2 sqrt 2 on the
imaginary axis) this is their sharp boundary; explicit Euler and midpoint grow every undamped oscillation
at any h (|R(i y)|^2 = 1 + y^2 and 1 + y^4/4), so their limit is where that growth reaches GROWTH: with
no damping h <= ln(1 + GROWTH) / w^2 for Euler, tiny on stiff cloth; with damping, where the damping
outweighs the growth. The modes below omega_max are checked with the damping of stiffness-proportional
(Rayleigh) damping through the top mode, c(w) = 2 zeta omega (w / omega)^2. Implicit Euler has no limit;
the adaptive methods (rk45, adaptive) choose their own steps and are exempt.

Each integrator declares its region (`stability_region`, a StabilityRegion: unconditional, adaptive, a
Runge-Kutta tableau, symplectic Euler, or any method's one-step matrix on the test system); the guard
asks for it, never for the method's name, and an integrator without one is refused when it is bound.
Each force term gives its own linearisation (terms/base.py: `stiffness_part` of an element term,
`point_blocks` of a pointwise one, else a kernel evaluates its `jacobian`).
"""

import math
import time
from dataclasses import asdict, dataclass

import numpy as np
import taichi as ti

from . import validate
from .errors import ParameterError
from .runtime import data_oriented, np_float
from .terms.stiffness import BlockPart

GROWTH = 0.01  # energy growth per second of simulated time that a step may allow (1%)
GUARD_SAFETY = 0.95  # the guard reports steps above this fraction of the limit
AUTO_SAFETY = 0.8  # automatic substeps keep each step below this fraction of the limit
MAX_AUTO_SUBSTEPS = 100_000
LANCZOS_STEPS = 80
LANCZOS_RTOL = 1e-3
_MODES = np.linspace(0.02, 1.0, 50)  # modes w / omega_max checked by stability_limit


@dataclass(frozen=True)
class Frequency:
    """Highest frequency of a model about a state: omega [rad/s] (Lanczos, see the module docstring),
    bound [rad/s] (block Gershgorin, an upper bound; nan where K was not built from element blocks),
    zeta: damping ratio of the top mode, iterations (Lanczos steps), seconds (wall time)."""

    omega: float
    bound: float
    zeta: float
    iterations: int
    seconds: float


# ---------------------------------------------------------------- the linearisation, per element


def _element_blocks(model, x, v, t):
    """The model's K and C as a list of parts (SpringPart, BlockPart, or a term's own part with `apply`
    and `gershgorin`): each element term's `stiffness_part`, and the pointwise terms' blocks."""
    parts = []
    n = model.particle_count
    for term in model.element_terms:
        make = getattr(term, "stiffness_part", None)
        if make is None:
            raise ParameterError(
                f"the stability estimate needs stiffness_part(x, v, t) of element term {type(term).__name__}"
            )
        parts.append(make(x, v, t))
    point = _point_blocks(model, x, v, t)
    if point is not None:
        parts.append(BlockPart(np.arange(n)[:, None], *point))
    return parts


def _point_blocks(model, x, v, t):
    """Per-particle 3x3 blocks (N, 3, 3) of the pointwise terms, K and C, or None without any: each
    term's `point_blocks` in NumPy (drag, anchor springs), or, when one term cannot give them, all of
    them by a kernel (model.force_jacobian)."""
    n = model.particle_count
    terms = [term for term in model.point_terms if term.has_jacobian]
    if not terms:
        return None
    blocks = [term.point_blocks(x, v, t) for term in terms]
    if any(b is None for b in blocks):
        return _PointJacobians(model).blocks(x, v, t)
    k = np.zeros((n, 3, 3))
    c = np.zeros((n, 3, 3))
    for kt, ct in blocks:
        k += kt
        c += ct
    return k, c


@data_oriented
class _PointJacobians:
    """-df/dx and -df/dv of the pointwise terms per particle, by a kernel (for terms NumPy cannot read)."""

    def __init__(self, model):
        n = model.particle_count
        self.model = model
        self.x = ti.Vector.field(3, float, n)
        self.v = ti.Vector.field(3, float, n)
        self.k = ti.Matrix.field(3, 3, float, n)
        self.c = ti.Matrix.field(3, 3, float, n)

    def blocks(self, x, v, t):
        self.x.from_numpy(x.astype(np_float()))
        self.v.from_numpy(v.astype(np_float()))
        self._run(self.model, t)
        return self.k.to_numpy().astype(np.float64), self.c.to_numpy().astype(np.float64)

    @ti.kernel
    def _run(self, model: ti.template(), t: float):
        for i in range(model.particle_count):
            jx, jv = model.force_jacobian(i, self.x[i], self.v[i], t)
            self.k[i] = -jx
            self.c[i] = -jv


# ---------------------------------------------------------------- the estimates


class _Scaled:
    """Ks = M^-1/2 K M^-1/2 and Cs over the free particles' degrees of freedom (s = m^-1/2, 0 if pinned)."""

    def __init__(self, parts, masses):
        free = masses > 0.0
        self.s = np.where(free, 1.0 / np.sqrt(np.where(free, masses, 1.0)), 0.0)
        self.count = len(masses)
        self.size = 3 * len(masses)
        self.free_dofs = np.repeat(free, 3)
        self.parts = parts

    def apply(self, p, damping: bool = False) -> np.ndarray:
        """Ks p (or Cs p) for p (3N,)."""
        q = p.reshape(-1, 3) * self.s[:, None]
        out = sum(part.apply(q, damping) for part in self.parts)
        return (out * self.s[:, None]).reshape(-1)

    def gershgorin(self) -> float:
        """max_i [lambda_max(D_i) + sum_j ||B_ij||_2] over the rows of Ks (block Gershgorin)."""
        diag = np.zeros((self.count, 3, 3))
        off = np.zeros(self.count)
        for part in self.parts:
            part.gershgorin(diag, off, self.s)
        top = np.linalg.eigvalsh(diag)[:, -1] * self.s**2
        return float(max(np.max(top + off), 0.0))

    def lanczos(self, seed: int = 0):
        """(theta + r, unit Ritz vector, steps) for the top eigenpair of Ks (see the module docstring).
        Products by einsum, not BLAS: a threaded BLAS on a busy machine was 18x slower here."""
        n_free = int(self.free_dofs.sum())
        steps = min(LANCZOS_STEPS, n_free)
        q = np.random.default_rng(seed).standard_normal(self.size) * self.free_dofs
        q /= np.sqrt(np.einsum("i,i", q, q))
        basis = np.empty((steps + 1, self.size))
        basis[0] = q
        alpha, beta = [], []
        top, vec, j, residual = 0.0, np.zeros(1), 0, 0.0
        for j in range(steps):
            w = self.apply(basis[j])
            alpha.append(float(np.einsum("i,i", basis[j], w)))
            for _ in range(2):  # full reorthogonalisation, twice is enough
                w -= np.einsum("ji,j->i", basis[: j + 1], np.einsum("ji,i->j", basis[: j + 1], w))
            b = float(np.sqrt(np.einsum("i,i", w, w)))
            t = np.diag(alpha) + np.diag(beta, 1) + np.diag(beta, -1)
            vals, vecs = np.linalg.eigh(t)
            top, vec = float(vals[-1]), vecs[:, -1]
            residual = b * abs(vec[-1])
            if residual <= LANCZOS_RTOL * max(top, 1e-300) or b <= 1e-12 * max(top, 1e-300):
                break
            beta.append(b)
            basis[j + 1] = w / b
        return top + residual, np.einsum("ji,j->i", basis[: len(vec)], vec), j + 1


class _ProbePart:
    """K p and C p of every force term by central differences of the model's total force (model.forces):
    K p = -(f(x + e p) - f(x - e p)) / 2e, C p = -(f(x, v + e p) - f(x, v - e p)) / 2e. Used for the
    element terms other than springs (membrane, bending, aerodynamics), whose exact element Hessians
    (element_arrays) take tens of seconds to compile, against a few for the force kernel. The step e
    moves the largest component of p by `reach` [m or m/s]: 1% of the mean element edge in float32 (its
    rounding of positions is then 1e-3 of the difference, and the central difference's error of order
    (e / edge)^2 is 1e-4), 1e-5 of it in float64."""

    def __init__(self, model, x, v, t):
        self.model, self.x, self.v, self.t = model, x, v, t
        edges = [
            np.linalg.norm(x[term.vertices[:, 0]] - x[term.vertices[:, 1]], axis=1).mean()
            for term in model.element_terms
            if hasattr(term, "vertices")
        ]
        self.reach = (1e-2 if np_float() == np.float32 else 1e-5) * float(np.mean(edges))

    def apply(self, p, damping: bool):
        top = float(np.abs(p).max())
        if top == 0.0:
            return np.zeros_like(p)
        e = self.reach / top
        forces = self.model.forces
        if damping:
            df = forces(self.x, self.v + e * p, self.t) - forces(self.x, self.v - e * p, self.t)
        else:
            df = forces(self.x + e * p, self.v, self.t) - forces(self.x - e * p, self.v, self.t)
        return -df / (2.0 * e)

    def gershgorin(self, diag, off, s):
        raise NotImplementedError  # needs the element blocks


def frequency(model, x, v=None, t: float = 0.0, *, blocks: bool | None = None) -> Frequency:
    """Highest frequency [rad/s] of `model` linearised at positions x (N,3) [m] and velocities v (N,3)
    [m/s] (default 0): see the module docstring. blocks: build K and C from the terms' element blocks
    (exact, and gives the Gershgorin bound) rather than by differences of the total force (_ProbePart);
    default: blocks when every element term's are fast (`fast_blocks`: springs, no kernel to compile).
    Without blocks the bound
    is nan."""
    start = time.perf_counter()
    x = np.asarray(x, dtype=np.float64)
    v = np.zeros_like(x) if v is None else np.asarray(v, dtype=np.float64)
    masses = model.particle_masses()
    if blocks is None:
        blocks = all(getattr(term, "fast_blocks", False) for term in model.element_terms)
    stiff = model.element_terms or any(term.has_jacobian for term in model.point_terms)
    if not stiff or not np.any(masses > 0.0):
        return Frequency(0.0, 0.0, 0.0, 0, time.perf_counter() - start)
    parts = _element_blocks(model, x, v, t) if blocks else [_ProbePart(model, x, v, t)]
    scaled = _Scaled(parts, masses)
    bound = math.sqrt(scaled.gershgorin()) if blocks else math.nan
    lam, u, steps = scaled.lanczos()
    omega = math.sqrt(max(lam, 0.0))
    zeta = float(np.einsum("i,i", u, scaled.apply(u, damping=True))) / (2.0 * omega) if omega > 0.0 else 0.0
    return Frequency(omega, bound, zeta, steps, time.perf_counter() - start)


def state_frequency(model, state) -> Frequency:
    """frequency() at the state's positions and velocities and time."""
    x, v, _ = state.motion()
    return frequency(model, x, v, state.time)


# ---------------------------------------------------------------- stability regions


REGION_KINDS = ("unconditional", "adaptive", "runge_kutta", "symplectic_euler", "step_matrix")


@dataclass(frozen=True)
class StabilityRegion:
    """What an integrator declares about its stability (its `stability_region`), read by the guard,
    stability_limit and auto_substeps, never its name. kind:
      "unconditional"     stable at any step (implicit Euler): no limit
      "adaptive"          the method chooses its own steps (rk45, adaptive): exempt from the guard
      "runge_kutta"       an explicit Runge-Kutta method: `tableau` (a, b) gives R(z)
      "symplectic_euler"  symplectic Euler's one-step map (module docstring)
      "step_matrix"       any one-step method: step_matrix(h, w, c) -> (M, 2, 2) array, its map of (y, y')
                          over a step h [s] on the modes y'' + c y' + w^2 y = 0 (w [rad/s], c [1/s], (M,))
    Use the constructors: unconditional(), adaptive(), runge_kutta(tableau), symplectic_euler(),
    from_step_matrix(fn)."""

    kind: str
    tableau: object = None
    step_matrix: object = None

    def __post_init__(self):
        validate.choice("kind", self.kind, REGION_KINDS)
        if self.kind == "runge_kutta" and self.tableau is None:
            raise ParameterError("a runge_kutta stability region needs its tableau")
        if self.kind == "step_matrix" and not callable(self.step_matrix):
            raise ParameterError("a step_matrix stability region needs step_matrix(h, w, c) -> (M, 2, 2)")

    @classmethod
    def unconditional(cls) -> "StabilityRegion":
        """Stable at any step (an A-stable implicit method)."""
        return cls("unconditional")

    @classmethod
    def adaptive(cls) -> "StabilityRegion":
        """A method that chooses its own steps (exempt from the guard)."""
        return cls("adaptive")

    @classmethod
    def runge_kutta(cls, tableau) -> "StabilityRegion":
        """An explicit Runge-Kutta method's, from its tableau (a, b)."""
        return cls("runge_kutta", tableau=tableau)

    @classmethod
    def symplectic_euler(cls) -> "StabilityRegion":
        """Symplectic Euler's (h w < 2 undamped)."""
        return cls("symplectic_euler")

    @classmethod
    def from_step_matrix(cls, step_matrix) -> "StabilityRegion":
        """Any one-step method's, from its map step_matrix(h, w, c) -> (M, 2, 2) of (y, y') on the modes."""
        return cls("step_matrix", step_matrix=step_matrix)

    @property
    def limited(self) -> bool:
        """Whether the step has a stability limit the guard checks."""
        return self.kind not in ("unconditional", "adaptive")


def check_integrator(integrator) -> None:
    """Raise ParameterError naming an integrator's class if it declares no StabilityRegion (its
    `stability_region`); called when it is bound to a model."""
    region = getattr(integrator, "stability_region", None)
    if not isinstance(region, StabilityRegion):
        raise ParameterError(
            f"integrator {type(integrator).__name__} declares no stability_region (got {region!r}): give "
            "it a StabilityRegion (unconditional(), adaptive(), runge_kutta(tableau), symplectic_euler() or "
            "from_step_matrix(fn)), so the stability guard can bound its step"
        )


def region_of(method) -> StabilityRegion:
    """The StabilityRegion of an integrator, or of a method named in INTEGRATORS ("adaptive_<base>" too)."""
    if isinstance(method, str):
        # cycle: the integrators import this module (their stability regions), so it cannot import them
        from .integrators import INTEGRATORS

        cls = INTEGRATORS.get("adaptive" if method.startswith("adaptive") else method)
        if cls is None:
            raise ParameterError(f"unknown integrator {method!r}; known: {', '.join(INTEGRATORS)}")
        method = cls
    check_integrator(method)
    return method.stability_region


def _rk_increment(tableau, z: np.ndarray) -> np.ndarray:
    """P(z) = (R(z) - 1) / z of an explicit Runge-Kutta tableau: stage values K_s = 1 + z sum_j a_sj K_j,
    P = sum_s b_s K_s (kept apart from the 1, so small steps lose no digits)."""
    stages = []
    for s in range(len(tableau.b)):
        ks = np.ones_like(z)
        for j, a in enumerate(tableau.a[s] if s < len(tableau.a) else ()):
            ks = ks + z * a * stages[j]
        stages.append(ks)
    return sum(b * ks for b, ks in zip(tableau.b, stages, strict=True))


def _log_radius2(region, h: float, w: np.ndarray, c: np.ndarray) -> np.ndarray:
    """ln rho^2 of one step h on each mode (w [rad/s], c [1/s] damping per unit mass): the energy growth
    per step, computed without cancelling against 1 (but for a step_matrix region: from its eigenvalues)."""
    if region.kind == "step_matrix":
        m = np.asarray(region.step_matrix(h, w, c), dtype=np.float64).reshape(len(w), 2, 2)
        rho = np.abs(np.linalg.eigvals(m)).max(axis=1)
        return 2.0 * np.log(np.maximum(rho, 1e-300))
    if region.kind == "symplectic_euler":
        # One-step map [[1 - h^2 w^2, h (1 - h c)], [-h w^2, 1 - h c]]: det = 1 - h c, tr = 2 - a with
        # a = h^2 w^2 + h c, and tr^2/4 - det = a^2/4 - h^2 w^2.
        a = h * h * w * w + h * c
        disc = a * a / 4.0 - h * h * w * w
        real = np.abs(1.0 - a / 2.0) + np.sqrt(np.maximum(disc, 0.0))
        complex_pair = np.log1p(np.maximum(-h * c, -1.0 + 1e-15))  # rho^2 = det = 1 - h c
        return np.where(disc < 0.0, complex_pair, 2.0 * np.log(np.maximum(real, 1e-300)))
    disc = np.sqrt((c * c / 4.0 - w * w).astype(complex))
    z = h * np.concatenate([-c / 2.0 + disc, -c / 2.0 - disc])
    zp = z * _rk_increment(region.tableau, z)  # R - 1
    return np.log1p(np.maximum(2.0 * zp.real + np.abs(zp) ** 2, -1.0 + 1e-15))


def stability_limit(method, omega: float, zeta: float = 0.0, *, growth: float = GROWTH) -> float | None:
    """Largest step [s] of `method` (an integrator or its name) on modes up to omega [rad/s] with damping
    ratio zeta at the top (see the module docstring), from its stability_region: inf for an unconditional
    one (implicit Euler), None for adaptive methods (rk45, adaptive), which choose their own steps."""
    region = region_of(method)
    if region.kind == "adaptive":
        return None
    if region.kind == "unconditional" or omega <= 0.0:
        return math.inf
    w = omega * _MODES
    c = 2.0 * zeta * omega * _MODES**2
    rate = math.log1p(growth)

    def ok(h: float) -> bool:
        return bool(np.all(_log_radius2(region, h, w, c) <= rate * h))

    # Scan up from far below any limit, then bisect: the first failure counts (regions need not be
    # intervals in h for every method, and the first crossing is the one a user meets).
    hs = np.geomspace(1e-12 / omega, 10.0 / omega, 400)
    good = None
    for h in hs:
        if not ok(h):
            break
        good = h
    else:
        return math.inf
    if good is None:
        return 0.0
    lo, hi = good, h
    for _ in range(50):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


# ---------------------------------------------------------------- the guard and automatic substeps


def _estimate(stepper, state) -> Frequency:
    """The stepper's cached Frequency (estimated once per model, at the first state the guard sees)."""
    est = getattr(stepper, "stability_estimate", None)
    if est is None:
        est = state_frequency(stepper.model, state)
        stepper.stability_estimate = est
    return est


def _guard_estimate(stepper, state) -> Frequency | None:
    """_estimate, or None (recorded once as a "stability_unchecked" event) for a model with a term the
    estimate cannot linearise: the guard must never stop a run it cannot judge."""
    if getattr(stepper, "stability_unchecked", False):
        return None
    try:
        return _estimate(stepper, state)
    except ParameterError as e:
        stepper.stability_unchecked = True
        stepper.health.event("stability_unchecked", state.step_count, str(e))
        return None


def guard(stepper, state, dt: float) -> None:
    """Check a step of dt [s] against the stability limit of the stepper's method; called by the Stepper
    whenever dt changes (the estimate is made once per stepper). A step above GUARD_SAFETY x the limit is
    reported to `stepper.health` as "unstable_step" (policy "stability": warn, raise or ignore). Sphere
    contacts may split dt further; the guard checks dt itself, so it can only be on the safe side."""
    if stepper.policy.stability == "ignore":
        return
    method = stepper.integrator
    if not region_of(method).limited:
        return
    est = _guard_estimate(stepper, state)
    if est is None:
        return
    cached = getattr(stepper, "stability_limit", None)  # (estimate, limit): the region scan costs ms
    if cached is None or cached[0] is not est:
        cached = (est, stability_limit(method, est.omega, est.zeta))
        stepper.stability_limit = cached
    limit = cached[1]
    if limit is None or dt <= GUARD_SAFETY * limit:
        return
    n = math.ceil(dt / (AUTO_SAFETY * limit)) if limit > 0.0 else None
    advice = f"split it into {n} substeps (substeps='auto')" if n else "use a smaller step"
    where = "exceeds" if dt > limit else f"is within {1 - GUARD_SAFETY:.0%} of"
    message = (
        f"{method.name}: dt = {dt:.3g} s {where} the stability limit {limit:.3g} s of this model "
        f"(highest frequency {est.omega:.4g} rad/s, damping ratio {est.zeta:.2g}); {advice}, or use "
        "implicit_euler"
    )
    stepper.health.report(
        "unstable_step", state.step_count, message, "stability", dt=dt, limit=limit, omega=est.omega
    )


def auto_substeps(
    model, integrator, frame_dt: float, *, safety: float = AUTO_SAFETY, state=None
) -> tuple[int, dict]:
    """The smallest number of substeps n for which frame_dt / n [s] is within `safety` x the stability
    limit of `integrator` on `model` (1 for implicit Euler and the adaptive methods), and a record of the
    choice (omega [rad/s], zeta, limit [s], substeps) for the run's settings. The estimate is made at
    `state` (default: a new state, the model's start) and kept on the integrator's stepper, so its guard
    does not repeat it. Raises ParameterError when more than MAX_AUTO_SUBSTEPS would be needed."""
    frame_dt = validate.positive("frame_dt", frame_dt)
    safety = validate.positive("safety", safety)
    if safety > 1.0:
        raise ParameterError(f"safety must lie in (0, 1], got {safety!r}")
    record = {"mode": "auto", "safety": safety, "method": integrator.name}
    if not region_of(integrator).limited:
        return 1, {**record, "substeps": 1, "limit": None}
    stepper = integrator.stepper_for(model)
    est = _estimate(stepper, model.state() if state is None else state)
    limit = stability_limit(integrator, est.omega, est.zeta)
    record.update(asdict(est), limit=limit)
    if math.isnan(est.bound):
        record["bound"] = None  # not computed (see frequency); JSON has no NaN
    if limit is None or math.isinf(limit):
        n = 1
    elif limit <= 0.0:
        n = math.inf  # e.g. explicit Euler on an undamped oscillator: no step keeps its energy bounded
    else:
        n = math.ceil(frame_dt / (safety * limit) - 1e-9)
    if n > MAX_AUTO_SUBSTEPS:
        raise ParameterError(
            f"substeps='auto': {integrator.name} needs {n if limit else 'unbounded'} substeps per "
            f"{frame_dt:.3g} s on this model (stability limit {limit:.3g} s, highest frequency "
            f"{est.omega:.4g} rad/s); use symplectic_euler, rk4 or implicit_euler"
        )
    record["substeps"] = max(n, 1)
    if limit is not None and math.isinf(limit):
        record["limit"] = None  # no stiffness: any step is stable (and JSON has no infinity)
    return max(n, 1), record
