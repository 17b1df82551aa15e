"""A pytest plugin for benchmarks/suite_compile.py: the time each test spends in Taichi's compiler.

Taichi compiles a kernel instance in two steps, which the engine's CompileClock times per kernel name
(taichi_anim/compile_clock.py): `Kernel.materialize` runs its Python front end (every process, every
instance), and the instance's first launch compiles the IR to machine code or loads it from the offline
cache and generates the machine code from the cached IR;
a field's element read or written from Python scope compiles its SNode's reader or writer kernel at the
first access (timed apart, under one name).
The plugin times both per kernel name and per test, and each xdist worker writes its totals to
SUITE_COMPILE_OUT/<worker>.json at the end. The first launch includes that launch's run time, small next
to a compile (a frame in one launch is the exception: its first frame is counted as compile).
"""

import collections
import importlib
import json
import os
import time
from pathlib import Path

import pytest

from taichi_anim.compile_clock import CompileClock

_front = collections.defaultdict(float)  # kernel name -> s in the front end
_load = collections.defaultdict(float)  # kernel name -> s in first launches
_instances = collections.Counter()  # kernel name -> instances compiled
_per_test = collections.defaultdict(float)  # test id -> s compiling
_test = {"id": ""}

taichi_field = importlib.import_module("taichi.lang.field")  # `taichi.lang.field` the attribute is a function

# A field's element read or written from Python (`f[i]`, `f[None] = v`) runs a reader or writer kernel
# of its SNode, which Taichi compiles (or loads) at the accessor's first use, outside Kernel.
_accessor_init = taichi_field.SNodeHostAccessor.__init__
ACCESSORS = "snode_reader/snode_writer (Python-scope f[i])"


def _first_call_timed(fn):
    first = [True]

    def call(*args):
        if not first[0]:
            return fn(*args)
        first[0] = False
        t0 = time.perf_counter()
        try:
            return fn(*args)
        finally:
            spent = time.perf_counter() - t0
            _load[ACCESSORS] += spent
            _instances[ACCESSORS] += 1
            _per_test[_test["id"]] += spent

    return call


def _timed_accessor_init(self, snode):
    _accessor_init(self, snode)
    self.getter = _first_call_timed(self.getter)
    self.setter = _first_call_timed(self.setter)


taichi_field.SNodeHostAccessor.__init__ = _timed_accessor_init


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _test["id"] = item.nodeid
    with CompileClock() as clock:  # the engine's own clock, around the test's setup, call and teardown
        yield
    for name, (front, load, instances) in clock.by_kernel.items():
        _front[name] += front
        _load[name] += load
        _instances[name] += instances
    _per_test[item.nodeid] += clock.seconds or 0.0


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    duration = report.get_result().duration
    _per_test[item.nodeid + "::wall"] += duration


def pytest_sessionfinish(session):
    out = os.environ.get("SUITE_COMPILE_OUT")
    if not out:
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    data = {"front": _front, "load": _load, "instances": _instances, "per_test": _per_test}
    (Path(out) / f"{worker}.json").write_text(json.dumps(data))
