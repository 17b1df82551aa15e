"""Measuring the time Taichi spends compiling kernels, apart from the time they run.

Taichi compiles a kernel on its first call in two steps: `Kernel.materialize` turns the Python function
into Taichi IR (once per template instance), and the first launch of that instance compiles the IR to
machine code, or loads it from the offline cache (`Program.compile_kernel`, inside
`Kernel.launch_kernel`). CompileClock times both for the kernels that are new inside its block: the
materialize calls that add an instance, and the first launch of each such instance (which includes that
one launch's run time, small next to a compile). Kernels compiled before the block (while a scene was
built) are not counted. The clock wraps the two methods of taichi.lang.kernel_impl.Kernel for the
block only, so later frames pay nothing; it is the one place that touches Taichi's internals (checked
against Taichi 1.7.4): where they differ, `seconds` stays None ("not measured") instead of guessing.
"""

from __future__ import annotations

import time


class CompileClock:
    """`with CompileClock() as clock: ...` then clock.seconds [s] spent compiling in the block (None if
    this Taichi cannot be measured), clock.kernels, the kernel instances compiled, and clock.by_kernel,
    per kernel name [front end s, first launches s, instances]."""

    def __init__(self):
        self.seconds: float | None = None
        self.kernels = 0
        self.by_kernel: dict[str, list] = {}
        self._fresh: dict[int, tuple] = {}  # id -> (compiled instance not launched yet, kept alive; name)
        self._saved = None

    def __enter__(self) -> CompileClock:
        try:
            from taichi.lang.kernel_impl import Kernel

            materialize, launch = Kernel.materialize, Kernel.launch_kernel
        except (ImportError, AttributeError):
            return self
        self.seconds = 0.0
        self._saved = (Kernel, materialize, launch)
        clock = self

        def timed_materialize(kernel, *args, **kwargs):
            before = len(kernel.compiled_kernels)
            t0 = time.perf_counter()
            try:
                return materialize(kernel, *args, **kwargs)
            finally:
                new = list(kernel.compiled_kernels.values())[before:]
                if new:
                    name, spent = kernel.func.__qualname__, time.perf_counter() - t0
                    clock.seconds += spent
                    clock.kernels += len(new)
                    clock._add(name, 0, spent, len(new))
                    clock._fresh.update((id(k), (k, name)) for k in new)

        def timed_launch(kernel, compiled, *args, **kwargs):
            fresh = clock._fresh.pop(id(compiled), None)
            if fresh is None:
                return launch(kernel, compiled, *args, **kwargs)
            t0 = time.perf_counter()
            try:
                return launch(kernel, compiled, *args, **kwargs)
            finally:
                spent = time.perf_counter() - t0
                clock.seconds += spent
                clock._add(fresh[1], 1, spent, 0)

        Kernel.materialize, Kernel.launch_kernel = timed_materialize, timed_launch
        return self

    def _add(self, name: str, step: int, seconds: float, instances: int) -> None:
        row = self.by_kernel.setdefault(name, [0.0, 0.0, 0])
        row[step] += seconds
        row[2] += instances

    def __exit__(self, *exc) -> bool:
        if self._saved is not None:
            kernel, materialize, launch = self._saved
            kernel.materialize, kernel.launch_kernel = materialize, launch
            self._saved = None
        self._fresh.clear()
        return False
