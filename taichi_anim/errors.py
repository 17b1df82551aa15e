"""Errors and warnings raised by taichi_anim: bad parameters, diverging or unconverged simulations,
steps beyond a method's stability limit, and output that could not be written."""


class ParameterError(ValueError):
    """A parameter has an invalid value; the message names the parameter and the value."""


class DivergenceError(RuntimeError):
    """A step produced non-finite or runaway positions, velocities or energy. The message says which step,
    particle, quantity and value; the same facts are attributes (None where not known)."""

    def __init__(self, message: str, *, step=None, particle=None, quantity=None, value=None):
        super().__init__(message)
        self.step = step
        self.particle = particle
        self.quantity = quantity
        self.value = value


class ConvergenceError(RuntimeError):
    """A solver stopped before its tolerance (linear solve, Newton, adaptive step control) and the
    run's policy says to raise."""


class StabilityError(RuntimeError):
    """A step exceeds the explicit method's stability limit and the run's policy says to raise."""


class OutputError(RuntimeError):
    """Output could not be written completely (disk full, permissions, a file where a folder must be);
    nothing incomplete was published under a final name."""


class SolverWarning(RuntimeWarning):
    """A solver stopped before its tolerance; the run goes on (policy "warn")."""


class StabilityWarning(RuntimeWarning):
    """A step exceeds the explicit method's stability limit; the run goes on (policy "warn")."""
