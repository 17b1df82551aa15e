"""Stopping a run cleanly on SIGINT (Ctrl-C), SIGTERM (`timeout`, `docker stop`, Slurm, CI runners,
`kill`) and SIGHUP (a closed terminal or SSH session).

Python's default for SIGTERM and SIGHUP is to die at once, without `finally` blocks: run.json stays
"running", temporaries stay and an in-memory USD stage is lost. While `stop_on_signals()` is active
(the runner wraps a run in it) the first such signal only sets a flag; the runner looks at it between
frames (a frame in progress finishes), saves what it has and raises RunInterrupted. A second signal
while frames are running forces the stop at once: RunInterrupted is raised wherever Python is (the
frame in progress is then lost; a Taichi kernel that is running still finishes first, since Python runs
signal handlers only between bytecodes). Handlers are installed only in the main thread (Python allows
no other) and the previous ones are restored on exit; a signal that arrives after the run's last look at
the flag is delivered again to the previous handler then, so nobody loses it.
"""

from __future__ import annotations

import signal
import threading

from .errors import RunInterrupted

# SIGHUP does not exist on Windows.
STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


class SignalStop:
    """The flag that stop_on_signals() sets: `signum` is the first stop signal received (None before)."""

    def __init__(self):
        self.signum: int | None = None
        self.forcible = True  # a second signal raises at once (the runner clears it when frames are done)
        self.taken = False  # the runner acted on the signal; otherwise it is delivered again on exit
        self._previous: dict[int, object] = {}

    @property
    def requested(self) -> bool:
        """Whether a stop signal has arrived."""
        return self.signum is not None

    def interrupted(self, **details) -> RunInterrupted:
        """The RunInterrupted for the signal received; the runner acts on it, so it is not redelivered."""
        self.taken = True
        return RunInterrupted(self.signum, **details)

    def _handle(self, signum, frame) -> None:
        if self.signum is None:
            self.signum = signum
        elif self.forcible:
            self.forcible = False  # raise once; a third signal must not interrupt the clean-up
            self.taken = True
            raise RunInterrupted(signum, forced=True)

    def __enter__(self) -> SignalStop:
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                if signal.getsignal(sig) is None:  # a handler set outside Python: it cannot be restored
                    continue
                try:
                    self._previous[sig] = signal.signal(sig, self._handle)
                except (OSError, ValueError):  # not settable here (e.g. an embedded interpreter)
                    pass
        return self

    def __exit__(self, kind, error, trace) -> bool:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        if self.signum is not None and not self.taken:
            # Came after the run's last look at the flag: hand it to whoever would have had it.
            signal.raise_signal(self.signum)
        return False


def stop_on_signals() -> SignalStop:
    """A context manager catching SIGINT, SIGTERM and SIGHUP for a run (see the module docstring)."""
    return SignalStop()
