"""Errors and warnings raised by taichi_anim: bad parameters, diverging or unconverged simulations,
steps beyond a method's stability limit, output that could not be written, and runs stopped by a signal."""

import signal


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


class FolderBusyError(OutputError):
    """Another run holds the output folder (or the video file); `path` is what is busy, `pid` the other
    run's process id (None if it could not be read)."""

    def __init__(self, message: str, *, path, pid: int | None):
        super().__init__(message)
        self.path = path
        self.pid = pid


class RunInterrupted(KeyboardInterrupt):
    """A run stopped on a signal. A KeyboardInterrupt, so code written for Ctrl-C still catches it.

    signal_number, signal (its name, e.g. "SIGTERM"), forced (a second signal cut a frame short),
    frames_done and frames (None where not known), exit_code (128 + the signal's number, the shell's
    convention: 130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP) and summary (the run's summary, set by
    the runner once run.json is written)."""

    def __init__(self, signum: int, *, frames_done=None, frames=None, forced: bool = False):
        self.signal_number = int(signum)
        self.signal = _signal_name(signum)
        self.forced = forced
        self.frames_done = frames_done
        self.frames = frames
        self.summary: dict | None = None
        text = f"interrupted by {self.signal}"
        if frames_done is not None:
            text += f" after {frames_done}" + ("" if frames is None else f" of {frames}") + " frames"
        if forced:
            text += " (a second signal: the frame in progress was not finished)"
        super().__init__(text)

    @property
    def exit_code(self) -> int:
        """The command line's exit code: 128 + the signal's number."""
        return 128 + self.signal_number


def _signal_name(signum: int) -> str:
    """ "SIGTERM" for 15, and so on ("signal N" for a number without a name)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"
