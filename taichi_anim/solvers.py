"""The solver protocol: what the Stepper's ordered list of solvers (rigid bodies, sphere contacts, cloth
self-contact, and whatever a user appends) is asked, and when. A time-integration method (integrators/)
proposes each (sub)step; the solvers then correct what it proposed, one after the other.

When the Stepper calls each hook (list order every time):
  substeps(model, state, dt) -> int      at the start of a step: how many substeps the step needs (the
                                         largest answer wins; continuous sphere contacts split by speed)
  before_substep(model, state, h)        before the method advances a substep (self-contact records the
                                         substep's start positions here)
  after_substep(model, state, h, step)   after the method advanced it by h [s]: correct the proposed
                                         positions and velocities in place (`step` numbers it, 1-based)
  check(state)                           when the Stepper reads the divergence watch: read the solver's
                                         own statistics; raise DivergenceError to have the step rolled back
  settings() -> dict                     the solver's options, for run.json
  name                                   a short label; also why a frame with this solver is stepped one
                                         substep at a time (frame_mode's reason)
and, optionally,
  separation_speed(model, state, dt)     [m/s] the speed the solver may legitimately give particles at
                                         the first step (spheres placed overlapping are pushed apart at
                                         overlap / dt); the watchdog's speed bound allows it
  frame_stats() -> dict                  after each frame of a scene run (scenes/runner.py): the
                                         solver's figures for that frame, kept per frame in run.json's
                                         `solver_frames` (the liquid: pressure iterations, density errors)

The rigid bodies' solver (bodies/rigid/dynamics.py) comes first: it steps the bodies by the method's
`rigid_scheme` (its constructor gets the method: `takes_method`), after the particles they push and that
push them have moved. The liquid's pressure solver (bodies/fluid/dfsph.py) follows: it makes the
velocities the method proposed for the fluid particles divergence- and density-error-free.

Coupling is Gauss-Seidel through the State: each solver reads the positions and velocities the method
and the solvers before it left, and writes its corrections (impulses as velocity changes, projections as
position changes) into the same fields, for the next one to read. So the order is the coupling: sphere
contacts come before self-contact, which comes last because its guard must see the final positions
(nothing may move a cloth vertex after it). A solver that needs to run after every substep forces the
Stepper to step frames substep by substep (Stepper.frame_mode): fused frames run the method alone.

Newton's coupled solvers exchange state the same way (`solver.step(state_in, state_out, control,
contacts, dt)` in a sequence, each reading the state the previous one wrote).

Adding a contact solver: a class with these methods in its own file, and one line in `SOLVERS` below
(the model option it is built from); a user adds one at run time with `Stepper.add_solver(solver)`."""

from .bodies.fluid import fluid_solver
from .bodies.rigid import RigidDynamics
from .collision.self_contact import SelfContact
from .collision.spheres import ContactSpheres
from .errors import ParameterError

# Every hook the Stepper calls: a solver that lacks one is refused when it is added, not mid-run.
REQUIRED = ("name", "substeps", "before_substep", "after_substep", "check", "settings")

# The built-in solvers, in list order: (the Model attribute holding the options a Builder method
# recorded, or None when the scene did not ask for it; the class built from them with (model, **options)).
SOLVERS = (
    ("rigid_dynamics", RigidDynamics),
    ("fluid", fluid_solver),
    ("sphere_contacts", ContactSpheres),
    ("self_contact", SelfContact),
)


class Solver:
    """A convenient base for a user's solver: every hook of the protocol as a no-op (override
    `after_substep`, and whatever else the solver needs). Any object with the hooks will do."""

    name = "solver"

    def substeps(self, model, state, dt: float) -> int:
        """Substeps the step of dt [s] needs (1: none of its own)."""
        return 1

    def before_substep(self, model, state, h: float) -> None:
        """Before the method advances the state by h [s]."""

    def after_substep(self, model, state, h: float, step: int) -> None:
        """Correct, in place, what the method (and the solvers before this one) proposed for the
        substep of h [s]."""

    def check(self, state) -> None:
        """Read the solver's statistics; raise DivergenceError if the step must be rolled back."""

    def settings(self) -> dict:
        """Options, for run.json."""
        return {}


def check_solver(solver) -> None:
    """Raise ParameterError naming the first hook of the protocol that `solver` lacks."""
    for hook in REQUIRED:
        if not hasattr(solver, hook):
            raise ParameterError(
                f"solver {solver!r} lacks {hook!r}: a solver needs {', '.join(REQUIRED)} "
                f"(taichi_anim/solvers.py describes the protocol; subclass solvers.Solver for no-op defaults)"
            )
        if hook != "name" and not callable(getattr(solver, hook)):
            raise ParameterError(
                f"solver {solver!r}: {hook!r} must be a method, got {getattr(solver, hook)!r}"
            )


def make_solvers(model, method=None) -> list:
    """The model's built-in solvers, in list order: one per option the scene asked for. A solver class
    with `takes_method` also gets the Stepper's integrator (`method=`): rigid bodies step by its scheme."""
    solvers = []
    for key, make in SOLVERS:
        options = getattr(model, key, None)
        if options is not None:
            extra = {"method": method} if getattr(make, "takes_method", False) else {}
            solvers.append(make(model, **options, **extra))
    return solvers
