"""Run health: what a run does when a solver misbehaves (`Policy`) and what it reports (`Health`).

Every solver reports instead of failing silently: a linear solve or Newton loop that stops at its cap, an
adaptive method that rejects too many steps, a step beyond an explicit method's stability limit, a
divergence and what was done about it. The Stepper owns one `Policy` and one `Health`
(`stepper.policy`, `stepper.health`); `Health.to_dict()` goes into the run summary and `run.json`.
"""

import warnings
from collections import Counter
from dataclasses import asdict, dataclass

from . import validate
from .errors import ConvergenceError, SolverWarning, StabilityError, StabilityWarning

REPORT_CHOICES = ("ignore", "warn", "raise")
DIVERGENCE_CHOICES = ("raise", "retry", "implicit")
MAX_EVENTS = 100  # events kept in full; the counters keep counting after that


@dataclass(frozen=True)
class Policy:
    """What a run does when something goes wrong.

    nonconvergence: a solver stopped before its tolerance — "ignore", "warn" (default; counted and warned
        once per kind) or "raise" (ConvergenceError).
    stability: a step exceeds the explicit method's stability limit — "ignore", "warn" (default) or
        "raise" (StabilityError).
    divergence: the watchdog caught an explosion — "raise" (default: DivergenceError, nothing after the
        last good state is kept), "retry" (roll back to the state before the step and redo it with
        2, 4, ... substeps, up to max_retries halvings) or "implicit" (roll back and redo the step with
        implicit Euler).
    keep_last_good: keep a copy of the state at the last good checked step (one copy per step, or per
        frame of fused substeps), so that a DivergenceError under "raise" leaves the state there
        (positions, velocities, lifetimes, emission, trails, time and step count); without it (default)
        the state holds the step that diverged, which the error names. Off by default because the copy
        costs a kernel launch and a memcpy per step (a third of a 10^4-particle step); "retry" and
        "implicit" always keep it (it is their rollback point).
    """

    nonconvergence: str = "warn"
    stability: str = "warn"
    divergence: str = "raise"
    max_retries: int = 4
    keep_last_good: bool = False

    def __post_init__(self):
        validate.choice("nonconvergence", self.nonconvergence, REPORT_CHOICES)
        validate.choice("stability", self.stability, REPORT_CHOICES)
        validate.choice("divergence", self.divergence, DIVERGENCE_CHOICES)
        validate.count("max_retries", self.max_retries, 1)
        if not isinstance(self.keep_last_good, bool):
            raise validate.ParameterError(
                f"keep_last_good must be True or False, got {self.keep_last_good!r}"
            )


def make_policy(policy) -> Policy:
    """A Policy from None (defaults), a Policy, or a dict of its fields."""
    if policy is None:
        return Policy()
    if isinstance(policy, Policy):
        return policy
    if isinstance(policy, dict):
        return Policy(**policy)
    raise validate.ParameterError(f"policy must be a Policy or a dict of its fields, got {policy!r}")


class Health:
    """Counters and events of one run. `count(key)` tallies (e.g. "linear_solves", "linear_iterations");
    `event(kind, step, message, **data)` records a notable event (kept up to MAX_EVENTS) and counts it
    under `kind`;
    `report(kind, step, message, setting, **data)` records an event and applies the policy setting
    (the Policy field name: "nonconvergence" or "stability")."""

    def __init__(self, policy: Policy | None = None):
        self.policy = policy or Policy()
        self.counts: Counter = Counter()
        self.events: list[dict] = []
        self._warned: set[str] = set()

    def count(self, key: str, n: int = 1) -> None:
        """Add n to the tally `key` (e.g. "linear_unconverged", "substeps_rejected")."""
        self.counts[key] += n

    def event(self, kind: str, step: int | None, message: str, **data) -> None:
        """Record an event of `kind` at `step` (counted; its message and data kept up to MAX_EVENTS)."""
        self.counts[kind] += 1  # an event is also a count, under its own kind
        if len(self.events) < MAX_EVENTS:
            self.events.append({"kind": kind, "step": step, "message": message, **data})

    def report(self, kind: str, step: int | None, message: str, setting: str, **data) -> None:
        """Record an event and act on it as the policy field `setting` says: "ignore", "warn" (one
        warning per kind) or "raise" (the error of that kind)."""
        self.event(kind, step, message, **data)
        action = getattr(self.policy, setting)
        if action == "raise":
            raise (StabilityError if setting == "stability" else ConvergenceError)(message)
        if action == "warn" and kind not in self._warned:
            self._warned.add(kind)  # once per kind: the counts say how often
            category = StabilityWarning if setting == "stability" else SolverWarning
            warnings.warn(f"{message} (further '{kind}' events are counted in the run summary)", category, 3)

    def to_dict(self) -> dict:
        """{"policy", "counts", "events"} as plain data, for the summary line and run.json."""
        return {"policy": asdict(self.policy), "counts": dict(self.counts), "events": list(self.events)}
