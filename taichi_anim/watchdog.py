"""Divergence watchdog: catches explosions, not only NaN.

A NaN/inf test alone misses the commonest explosion: once a spring's squared length overflows, its
direction d * rsqrt(|d|^2) is 0, the force vanishes and the state stays finite near 1e25. So every
particle that ends a step is also held to bounds derived from the scene (fused into the step's last
kernel, `watch_against`, at the cost of a few flops per particle):

* extent: |x - c|_inf <= L(t) = L0 + v_ref t + |g| t^2 / 2, with c and s the centre and half-size of the
  scene's box (alive particles at the first step, colliders' finite geometry over their keyframes,
  emitters' sources, attachments' targets) and L0 = EXTENT_FACTOR (s + MARGIN). 100 times the scene
  is far beyond anything a camera frames (and float32 there has lost two digits of the scene's scale);
  the time terms are what a particle leaving the scene at v_ref and falling freely can reach, so a long
  free fall is not an explosion.
* speed: |v| <= V(t) = SPEED_FACTOR v_ref + |g| t, with v_ref the largest speed the scene can supply:
  initial and emitter speeds, wind, moving colliders and attachments, spheres placed overlapping
  pushed apart in the first step (overlap / dt), free fall across the scene
  (sqrt(2 |g| H), H its box diagonal), the initial elastic energy put into the lightest particle
  (sqrt(2 E_el / m_min)), and at least 1 m/s. Explosions grow geometrically (by (h w)^2 per step for a
  stiff spring past its limit), so a generous factor costs only a step or two of detection.
* energy, where the scene has one (every term of energy_kind "potential" or "dissipative": no source
  such as wind or aerodynamics, no emitters, attachments or moving colliders; `describe()` says what
  switched it off): E(t) <= E(0) + ENERGY_FACTOR E_s, with E the kinetic plus potential energy (every
  potential term's `energy`: gravity, springs, membrane, bending, anchors, a user's) and
  E_s = KE(0) + E_el(0) + M |g| H + M (1 m/s)^2 / 2 all the energy the scene holds or can release.
  Damping, drag, contacts and colliders only remove energy; an explicit method's bounded energy error
  stays well inside (symplectic Euler's energy swings by a factor (1 + a) / (1 - a), a = h w / 2, on an
  oscillator: 3 at a = 1/2). Evaluated every `energy_every` steps (it copies the state to NumPy), when a
  check is due.

Each part supplies what its bounds need (terms/base.py, collision/colliders.py): a term its
speed_bound (wind), acceleration_bound (|g|), stored_energy (E_el) and energy; a collider its
sample_points at its key_times and its velocity_bound. A part without them is refused when it is added.

The kernel compares with constants (a box lo..hi and a squared speed): the bounds at the end of a window
over which they loosen by at most a tenth, rewritten by the Stepper once per window, not per step.
Each bound can be overridden or switched off (`Watchdog.configure`). The first step that broke a bound,
its lowest particle index, the quantity and its value are recorded with atomics (`watch_against`) and
read by `Stepper.check`, which raises DivergenceError naming them.
"""

import math
import os

import numpy as np
import taichi as ti

from . import validate
from .errors import DivergenceError, ParameterError

EXTENT_FACTOR = 100.0
MARGIN = 1.0  # [m]: a point-like scene still gets a box of 100 m
SPEED_FACTOR = 10.0
SPEED_FLOOR = 1.0  # [m/s]
ENERGY_FACTOR = 10.0
ENERGY_EVERY = 100
# What broke a bound (codes written by the kernel, names in DivergenceError.quantity).
NONFINITE_POSITION, NONFINITE_VELOCITY, POSITION, SPEED = 1, 2, 3, 4
QUANTITY = {
    NONFINITE_POSITION: "position",
    NONFINITE_VELOCITY: "velocity",
    POSITION: "position",
    SPEED: "speed",
}
NO_INDEX = 2**31 - 1


def bounds_compiled() -> bool:
    """Whether new States compile the bound checks in (TAICHI_ANIM_WATCHDOG_BOUNDS=0 leaves only the
    non-finite test, to measure the checks' cost)."""
    return os.environ.get("TAICHI_ANIM_WATCHDOG_BOUNDS", "1") != "0"


@ti.func
def watch_limits(state: ti.template()):
    """The watchdog's bounds for the current step, loaded once: box lo (3), hi (3) [m], squared speed
    limit [m^2/s^2] (zeros when the bounds are not compiled in)."""
    lim = ti.Vector.zero(float, 7)
    if ti.static(state.watch_bounds):
        lim = state.watch_limit[None]
    return lim


@ti.func
def watch_against(state: ti.template(), lim, i, x, v, step):
    """Record particle i if its end-of-step (x, v) is non-finite or outside the bounds `lim`, loaded by
    the caller (watch_limits): a blocked frame (integrators/blocked.py) loads them once per particle
    instead of once per substep.

    The test that passes is the hot path of every particle-step: one sum with a bit test (non-finite:
    exponent all ones, immune to the fast-math flags that let LLVM assume no infinities) and seven
    compares joined with `|`, with no branch on the quantity until something fails. In a blocked frame of
    10^4 particles under gravity (serial, 2-core Xeon) a particle-step took 9.0 ns with the earlier form
    and 5.1 ns with this one (3.7 ns with no bounds compiled in): the earlier `max` chain lowered to
    NaN-safe maxnum sequences, each waiting on the last."""
    if breaks_bounds(state, lim, x, v):
        _record(state, i, x, v, step)


@ti.func
def breaks_bounds(state: ti.template(), lim, x, v):
    """Whether (x, v) is non-finite or outside the bounds `lim` (watch_against's test, without the
    record: a blocked frame's pack tests its particles with it as one vector)."""
    total = x.sum() + v.sum()  # NaN or inf in any component makes the sum NaN or inf
    bad = (ti.bit_cast(ti.cast(total, ti.f32), ti.u32) & ti.u32(0x7F800000)) == ti.u32(0x7F800000)
    if ti.static(state.watch_bounds):
        out = (x[0] < lim[0]) | (x[1] < lim[1]) | (x[2] < lim[2])
        out |= (x[0] > lim[3]) | (x[1] > lim[4]) | (x[2] > lim[5]) | (v.norm_sqr() > lim[6])
        bad |= out
    return bad


@ti.func
def _record(state: ti.template(), i, x, v, step):
    """What watch_against found wrong with particle i, recorded with atomics."""
    code = 0
    value = 0.0
    total = x.sum() + v.sum()
    if ti.math.isnan(total) or ti.math.isinf(total):
        code = NONFINITE_VELOCITY
        value = v.sum()
        sx = x.sum()
        if ti.math.isnan(sx) or ti.math.isinf(sx):
            code = NONFINITE_POSITION
            value = sx
    elif ti.static(state.watch_bounds):
        lim = state.watch_limit[None]
        lo = ti.Vector([lim[0], lim[1], lim[2]])
        hi = ti.Vector([lim[3], lim[4], lim[5]])
        s2 = v.norm_sqr()
        if ti.max((x - hi).max(), (lo - x).max()) > 0.0:
            code = POSITION
            value = ti.abs(x - 0.5 * (lo + hi)).max()
        elif s2 > lim[6]:
            code = SPEED
            value = ti.sqrt(s2)
    if code != 0:
        ti.atomic_add(state.nonfinite_count[None], 1)
        if ti.atomic_min(state.nonfinite_step[None], step) >= step:
            ti.atomic_min(state.watch_particle[None], i)  # the lowest index at the first bad step
        if ti.atomic_add(state.watch_claim[None], 1) == 0:  # one consistent record, whoever came first
            state.watch_record[None] = ti.Vector([step, i, code])
            state.watch_value[None] = value


@ti.kernel
def write_watch_limits(state: ti.template(), lx: float, ly: float, lz: float, hx: float, hy: float, hz: float,
                       v2: float):  # fmt: skip
    """The watchdog's limits into the state's field in one launch (a Python-scope write of the 7-vector
    is seven writer kernels, compiled with an empty cache at about 17 ms each): the box lo, hi [m] and
    the squared speed [m^2/s^2]."""
    state.watch_limit[None] = ti.Vector([lx, ly, lz, hx, hy, hz, v2], dt=float)


class Watchdog:
    """The divergence bounds of one model (a Stepper's `watchdog`). Derived from the scene when the
    first state is stepped; `configure` overrides them. `describe()` gives the bounds in force."""

    def __init__(self, model):
        self.model = model
        self.extent = None  # (lo, hi) [m] fixed box, inf (off) or None (derived)
        self.speed = None  # [m/s] fixed limit, inf (off) or None (derived)
        self.energy_tolerance = None  # [J] allowed energy gain, inf (off) or None (derived)
        self.energy_every = ENERGY_EVERY
        # [m/s] the speed at which sphere contacts push initially overlapping spheres apart (overlap / dt:
        # a projection turns an overlap into velocity); set by the Stepper before the first step.
        self.separation_speed = 0.0
        self.version = 0  # bumped on every change: states rewrite their limit field
        self.derived = None  # dict of the derived quantities, made on the first `arm`
        self._energy = None  # E(x, v) -> J, or None when the scene has no energy
        self.energy_reason = None  # why the energy is not checked (energy_unchecked), once derived

    def configure(self, *, extent="keep", speed="keep", energy_tolerance="keep", energy_every=None):
        """Override bounds. extent: (lo, hi) [m] a fixed box particles must stay in, math.inf (off) or
        None (derived); speed [m/s]: a fixed limit, math.inf (off) or None (derived); energy_tolerance
        [J]: the energy gain allowed over the start, math.inf (off) or None (derived); energy_every: steps
        between energy evaluations. Arguments left out keep their setting."""
        if not isinstance(extent, str) or extent != "keep":
            self.extent = _extent(extent)
        if not isinstance(speed, str) or speed != "keep":
            self.speed = _limit("speed", speed)
        if not isinstance(energy_tolerance, str) or energy_tolerance != "keep":
            self.energy_tolerance = _limit("energy_tolerance", energy_tolerance, zero=True)
        if energy_every is not None:
            self.energy_every = validate.count("energy_every", energy_every, 1)
        self.version += 1

    def disable(self) -> None:
        """Switch every bound off (the non-finite test stays): for studies of unstable methods."""
        self.configure(extent=math.inf, speed=math.inf, energy_tolerance=math.inf)

    # -- deriving the bounds -------------------------------------------------------------------------

    def arm(self, state, dt: float) -> None:
        """Before a step of dt [s] of `state`: derive the bounds (first state only), record the state's
        start energy, and write the limits into its field when they changed or the step ends past the
        window they were written for."""
        if self.derived is None:
            self.derived = scene_bounds(self.model, state, self.separation_speed)
            self._energy = energy_function(self.model)
            self.energy_reason = energy_unchecked(self.model)
        if state.watch_version != self.version or state.time + dt > state.watch_until:
            # The bounds grow with time; the kernel tests constants: those at the end of a window in
            # which they loosen by at most a tenth (one field write per window, not per step).
            end = state.time + dt
            w = self.window(end)
            until = end + w
            lo, hi, vmax = self.limits_at(until if w < math.inf else end)  # inf: they do not grow
            write_watch_limits(state, *(float(c) for c in (*lo, *hi, vmax * vmax)))
            state.watch_bounds_now = (lo, hi, vmax)
            state.watch_version, state.watch_until = self.version, until
        if state.energy_start is None and self._energy is not None:
            state.energy_start = self._energy(state)
            state.energy_step = state.step_count

    def limits(self) -> list:
        """The kernel's limits: centre c (3) [m], half-sizes s (3) [m], v_ref [m/s], |g| [m/s^2] of the
        box |x - c| <= s + v_ref t + |g| t^2 / 2 (per axis); V0 [m/s], |g| [m/s^2] of the speed limit
        V(t) = V0 + |g| t."""
        d = self.derived
        c, half, v_ref, g = d["centre"], np.full(3, d["extent"]), d["v_ref"], d["g"]
        if self.extent is not None:  # a fixed box (or none): no growth in time
            v_ref, g = 0.0, 0.0
            if self.extent == math.inf:
                half = np.full(3, math.inf)
            else:
                lo, hi = self.extent
                c, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        v0, gv = d["speed"], d["g"]
        if self.speed is not None:
            v0, gv = self.speed, 0.0
        return [float(a) for a in (*c, *half, v_ref, g, v0, gv)]

    def window(self, t: float) -> float:
        """How long [s] after t the limits at t + window stay within ~10% of those at t."""
        lim = self.limits()
        half = min(lim[3:6]) + t * (lim[6] + 0.5 * lim[7] * t)
        grow_x = lim[6] + lim[7] * t  # d half / dt
        speed, grow_v = lim[8] + lim[9] * t, lim[9]
        w = math.inf
        if grow_x > 0.0:
            w = min(w, 0.1 * half / grow_x)
        if grow_v > 0.0:
            w = min(w, 0.1 * speed / grow_v)
        return w

    def limits_at(self, t: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(lo (3,), hi (3,) [m] of the box, speed limit [m/s]) in force at time t [s]."""
        lim = self.limits()
        c, half = np.array(lim[:3]), np.array(lim[3:6]) + t * (lim[6] + 0.5 * lim[7] * t)
        return c - half, c + half, lim[8] + lim[9] * t

    def energy_limit(self) -> float:
        """Energy gain [J] allowed over the start (inf: no energy check)."""
        if self._energy is None:
            return math.inf
        if self.energy_tolerance is not None:
            return self.energy_tolerance
        return ENERGY_FACTOR * self.derived["energy_scale"]

    def describe(self) -> dict:
        """The bounds in force (for run summaries): derived values and overrides."""
        out = {"energy_every": self.energy_every, "energy_checked": self._energy is not None}
        if self.energy_reason is not None:
            out["energy_unchecked"] = self.energy_reason
        if self.derived is not None:
            lo, hi, v = self.limits_at(0.0)
            out.update(
                box_at_start=[lo.tolist(), hi.tolist()], speed_at_start=v, energy_gain=self.energy_limit()
            )
            out.update({k: self.derived[k] for k in ("v_ref", "g", "energy_scale")})
        return out

    # -- reading a state's record --------------------------------------------------------------------

    def error(self, state, count: int) -> DivergenceError:
        """The DivergenceError for a state whose watch counted `count` bad particle-steps."""
        step = int(state.nonfinite_step[None])
        first = int(state.watch_particle[None])
        rec = state.watch_record[None]
        rstep, rpart, rcode = int(rec[0]), int(rec[1]), int(rec[2])
        value = float(state.watch_value[None])
        if rcode == 0:  # counted outside the particle finish (sphere contacts)
            return DivergenceError(
                f"simulation diverged at step {step}: {count} particle(s) got a non-finite position or "
                f"velocity in the sphere contacts (check dt and the contact settings); stopping before "
                f"anything is exported",
                step=step,
                quantity="position",
                value=math.nan,
            )
        particle, code = rpart, rcode
        if first != NO_INDEX and first != rpart and state.step_count == step:
            # The state still holds the first bad step: report its lowest particle, read back.
            particle = first
            code, value = self.classify(state, first)
        elif rstep != step:
            step = rstep
        quantity = QUANTITY[code]
        lo, hi, vmax = state.watch_bounds_now
        if code in (NONFINITE_POSITION, NONFINITE_VELOCITY):
            what = f"a non-finite {quantity} ({value})"
        elif code == POSITION:
            box = f"[{', '.join(f'{a:.3g}' for a in lo)}]..[{', '.join(f'{a:.3g}' for a in hi)}] m"
            what = f"a position {value:.4g} m from the centre of the watchdog's box, outside {box}"
        else:
            what = f"a speed of {value:.4g} m/s (limit {vmax:.4g} m/s)"
        return DivergenceError(
            f"simulation diverged at step {step}: particle {particle} reached {what}; {count} "
            f"particle-step(s) broke the watchdog's bounds; stopping before anything is exported (check "
            f"dt, stiffness and the integrator's stability limit; bounds: Stepper.watchdog)",
            step=step,
            particle=particle,
            quantity=quantity,
            value=value,
        )

    def classify(self, state, i: int) -> tuple[int, float]:
        """(code, value) of particle i as the state holds it now (the kernel's test, in NumPy)."""
        x = np.array(state.particle_x[i], dtype=np.float64)
        v = np.array(state.particle_v[i], dtype=np.float64)
        if not np.all(np.isfinite(x)):
            return NONFINITE_POSITION, float(x.sum())
        if not np.all(np.isfinite(v)):
            return NONFINITE_VELOCITY, float(v.sum())
        lo, hi, vmax = state.watch_bounds_now
        c, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        d = np.abs(x - c)
        speed = float(np.linalg.norm(v))
        # Rounding at the boundary: the larger excess names the quantity.
        if np.max(d / np.maximum(half, 1e-30)) >= speed / max(vmax, 1e-30):
            return POSITION, float(d.max())
        return SPEED, speed

    def energy_error(self, state, *, now: bool = False):
        """The DivergenceError for energy grown beyond the allowed gain, or None; the energy is
        evaluated only when due (every `energy_every` steps), or at once with now=True."""
        if self._energy is None or state.energy_start is None:
            return None
        if state.step_count == state.energy_step or (
            not now and state.step_count - state.energy_step < self.energy_every
        ):
            return None
        state.energy_step = state.step_count
        limit = self.energy_limit()
        if limit == math.inf:
            return None
        e = self._energy(state)
        if e - state.energy_start <= limit:
            return None
        return DivergenceError(
            f"simulation diverged by step {state.step_count}: the energy grew from "
            f"{state.energy_start:.4g} J to {e:.4g} J, more than the {limit:.4g} J the scene's forces "
            f"can supply; stopping before anything is exported (check dt, stiffness and the integrator's "
            f"stability limit; bounds: Stepper.watchdog)",
            step=state.step_count,
            quantity="energy",
            value=e,
        )


def scene_bounds(model, state, separation_speed: float = 0.0) -> dict:
    """The scene's box (centre, half-size), reference speed, |g| and energy scale (see the module doc);
    separation_speed [m/s]: how fast contacts push the start's overlapping spheres apart. Every part is
    asked, never its class: colliders for their points over their keyframes and their speed, terms for
    the speed and uniform acceleration they supply and the energy they hold (terms/base.py)."""
    x_all, v_all, alive = state.motion()
    x = x_all[alive]
    v = v_all[alive]
    points = [x.reshape(-1, 3)]
    speeds = [float(np.max(np.linalg.norm(v, axis=1), initial=0.0)), separation_speed]
    for c in model.colliders:
        p, s = collider_reach(c)
        points.append(p)
        speeds.append(s)
    for a in model.attachments:
        p, s = _keyframed(a.target, a.motion.times if a.motion is not None else a.times)
        points.append(p)
        speeds.append(s)
    for e in model.emitters:
        es = e.s
        points.append(np.asarray(es.center) + np.array([[-1.0], [1.0]]) * np.asarray(_emitter_size(es)))
        speeds.append(es.speed * (1.0 + es.speed_jitter))
    masses = model.particle_masses()
    g = 0.0
    elastic = 0.0
    for t in model.terms:
        g += float(t.acceleration_bound())
        speeds.append(float(t.speed_bound()))
        elastic += float(t.stored_energy(x_all, masses))
    allp = np.concatenate([p.reshape(-1, 3) for p in points if len(p)])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    height = float(np.linalg.norm(hi - lo))
    free = masses[masses > 0]
    m_min = float(free.min()) if len(free) else math.inf
    total_mass = float(masses[alive].sum())
    speeds += [math.sqrt(2.0 * g * height), math.sqrt(2.0 * max(elastic, 0.0) / m_min), SPEED_FLOOR]
    v_ref = max(speeds)
    kinetic = 0.5 * float(np.sum(masses[alive][:, None] * v**2))
    return {
        "centre": 0.5 * (lo + hi),
        "extent": EXTENT_FACTOR * (0.5 * float(np.max(hi - lo)) + MARGIN),
        "v_ref": v_ref,
        "g": g,
        "speed": SPEED_FACTOR * v_ref,
        "energy_scale": kinetic + max(elastic, 0.0) + total_mass * (g * height + 0.5 * SPEED_FLOOR**2),
    }


def energy_unchecked(model) -> str | None:
    """Why the scene's energy is not checked (it can gain energy from outside), or None if it is: an
    emitter, an attachment, a moving collider or a force term that is a source (energy_kind "source")."""
    if model.emitter_count or model.attachment_count:
        return "the scene has emitters or attachments (they add energy)"
    moving = [type(c).__name__ for c in model.colliders if c.moving]
    if moving:
        return f"moving collider(s) {', '.join(moving)} can add energy"
    sources = [type(t).__name__ for t in model.terms if t.energy_kind == "source"]
    if sources:
        return f"force term(s) {', '.join(sources)} can add energy (energy_kind 'source')"
    return None


def energy_function(model):
    """E(state) -> kinetic plus potential energy [J] (every term of energy_kind "potential": gravity,
    springs, membrane, bending, anchors, a user's), or None if the scene can gain energy from outside
    (energy_unchecked). The kinetic part is one reduction kernel (f64 sums); the potentials read the
    positions in NumPy."""
    if energy_unchecked(model) is not None:
        return None
    potentials = [t for t in model.terms if t.energy_kind == "potential"]
    masses = model.particle_masses()
    out = model.new_field(model, "kinetic_energy", ti.f64, ())

    def energy(state) -> float:
        e = float(_kinetic_energy(model, state, out))
        if potentials:
            x = state.motion()[0]  # the read scene_bounds compiled (positions() is a kernel of its own)
            e += sum(float(t.energy(x, masses)) for t in potentials)
        return e

    return energy


@ti.kernel
def _kinetic_energy(model: ti.template(), state: ti.template(), out: ti.template()) -> ti.f64:
    # cleared and returned here rather than from Python: a Python-scope access runs its own kernel
    out[None] = 0.0
    for i in range(model.live_particles()):
        v = state.particle_v[i]
        out[None] += ti.cast(0.5 * model.mass(i) * v.norm_sqr(), ti.f64)
    return out[None]


def _extent(extent):
    if extent is None or (isinstance(extent, float) and extent == math.inf):
        return extent
    try:
        lo, hi = (
            np.asarray(validate.vec3(n, b), dtype=np.float64)
            for n, b in zip(("lo", "hi"), extent, strict=True)
        )
    except (TypeError, ValueError):
        raise ParameterError(f"extent must be (lo, hi) [m], math.inf or None, got {extent!r}") from None
    if np.any(hi <= lo):
        raise ParameterError(f"extent: hi must exceed lo on every axis, got {extent!r}")
    return lo, hi


def _limit(name: str, value, zero: bool = False):
    if value is None:
        return None
    v = float(value)
    if v != v or v < 0.0 or (v == 0.0 and not zero):
        raise ParameterError(
            f"{name} must be a number {'>=' if zero else '>'} 0, math.inf or None, got {value!r}"
        )
    return v


def _emitter_size(es) -> tuple:
    r = es.size[0]
    return tuple(es.size) if es.shape.value == "box" else (r, r, r)


def collider_reach(c) -> tuple[np.ndarray, float]:
    """Points of a collider's finite geometry over its keyframes (world) and its largest speed [m/s]:
    its sample_points at each of its key_times (or at 0 if it is static) and its velocity_bound."""
    times = c.key_times()
    times = [0.0] if times is None or len(times) == 0 else times
    points = [np.asarray(c.sample_points(float(t)), dtype=np.float64).reshape(-1, 3) for t in times]
    return np.concatenate(points), float(c.velocity_bound())


def _keyframed(at, times) -> tuple[np.ndarray, float]:
    """Points at(t) (P,3) over keyframe times, and the largest chord speed between keyframes [m/s]."""
    times = np.asarray(times, dtype=np.float64)
    frames = [np.asarray(at(t), dtype=np.float64).reshape(-1, 3) for t in times]
    speed = 0.0
    for k in range(len(times) - 1):
        dt = times[k + 1] - times[k]
        speed = max(speed, float(np.max(np.linalg.norm(frames[k + 1] - frames[k], axis=1))) / dt)
    return np.concatenate(frames), speed
