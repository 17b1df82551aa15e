"""runtime.data_oriented: the descriptor fast path (on the Taichi versions it is verified for) and the
plain `ti.data_oriented` fallback give the same simulation, bit for bit."""

import os
import subprocess
import sys

import pytest

SCRIPT = """
import hashlib, numpy as np, taichi_anim as ta
from taichi_anim import runtime
ta.init("cpu", precision="f64", cpu_threads=1)
b = ta.Builder()
b.add_force_gravity()
c = b.add_cloth_grid(origin=(0, 1, 0), size=(0.3, 0.3), resolution=(6, 6), plane="xy", pinned=[30, 35],
                     material=ta.FabricMaterial())
b.add_force_aerodynamics(c, wind=(2.0, 0.0, 1.0))
model = b.finalize()
for name in ("symplectic_euler", "implicit_euler", "rk4"):
    s = model.state()
    integ = ta.make_integrator(name)
    for _ in range(10):
        integ.step(model, s, 1e-4)
    print(name, hashlib.sha256(s.positions().tobytes()).hexdigest())
print("fast", runtime.FAST_DATA_ORIENTED)
"""


def start(plain: bool) -> subprocess.Popen:
    env = dict(os.environ)
    env.pop("TAICHI_ANIM_PLAIN_DATA_ORIENTED", None)
    if plain:
        env["TAICHI_ANIM_PLAIN_DATA_ORIENTED"] = "1"
    return subprocess.Popen(
        [sys.executable, "-c", SCRIPT], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def lines(proc: subprocess.Popen) -> list[str]:
    out, err = proc.communicate()
    assert proc.returncode == 0, err
    return [line for line in out.splitlines() if not line.startswith("[Taichi]")]


@pytest.mark.slow  # two child processes compile every kernel (~1-2 min); the version gate is tested below
def test_fast_and_plain_data_oriented_give_the_same_bits():
    procs = start(False), start(True)  # both at once: each is mostly single-threaded JIT compilation
    fast, plain = (lines(p) for p in procs)
    assert fast[-1] == "fast True" and plain[-1] == "fast False"
    assert fast[:-1] == plain[:-1] and len(fast) == 4


def test_fast_path_only_on_verified_taichi_versions(monkeypatch):
    import taichi as ti

    from taichi_anim import runtime

    monkeypatch.delenv("TAICHI_ANIM_PLAIN_DATA_ORIENTED", raising=False)
    assert runtime.fast_data_oriented_available() == (
        tuple(ti.__version__) in runtime.FAST_DATA_ORIENTED_VERSIONS
    )
    monkeypatch.setattr(ti, "__version__", (9, 9, 9))
    assert not runtime.fast_data_oriented_available()


@pytest.mark.parametrize("fast", [True, False])
def test_compile_with_sets_the_switch_for_that_kernel_only(monkeypatch, fast):
    """A kernel marked compile_with(cfg_optimization=False) compiles with that switch off, on the
    descriptor path and on Taichi's own data_oriented; other kernels, its later launches and later code
    see the program's setting; the result is the same arithmetic."""
    import taichi as ti
    from taichi.lang import impl
    from taichi.lang.kernel_impl import Kernel

    from taichi_anim import runtime

    monkeypatch.setattr(runtime, "FAST_DATA_ORIENTED", fast and runtime.FAST_DATA_ORIENTED)
    seen: dict[str, list[bool]] = {}
    launch = Kernel.launch_kernel

    def record(kernel, *args, **kwargs):
        seen.setdefault(kernel.func.__name__, []).append(impl.current_cfg().cfg_optimization)
        return launch(kernel, *args, **kwargs)

    monkeypatch.setattr(Kernel, "launch_kernel", record)

    @runtime.data_oriented
    class Sums:
        def __init__(self):
            self.out = ti.field(ti.i32, 2)

        @runtime.compile_with(cfg_optimization=False)
        @ti.kernel
        def switched(self, n: ti.i32):
            for i in range(n):
                ti.atomic_add(self.out[0], i)

        @ti.kernel
        def plain(self, n: ti.i32):
            for i in range(n):
                ti.atomic_add(self.out[1], i)

    before = impl.current_cfg().cfg_optimization
    sums = Sums()
    for _ in range(2):
        sums.switched(100)
        sums.plain(100)
    # Only the launch that compiles runs with the switch; the program's setting is back after it.
    assert seen == {"switched": [False, before], "plain": [before, before]}
    assert impl.current_cfg().cfg_optimization == before
    assert sums.out.to_numpy().tolist() == [9900, 9900]  # twice the sum of 0..99
    with pytest.raises(ti.TaichiSyntaxError, match="missing"):
        sums.switched()  # a failing call restores the switch too
    assert impl.current_cfg().cfg_optimization == before


def test_compile_with_switches_each_new_programs_instance_even_on_a_reused_id(monkeypatch):
    """After ta.init the kernel's new instance compiles with the switch off again, even when it gets the
    id an instance of the last program had (forced here: every id the same). Under the full suite a reused
    id once compiled the integrator's step with Taichi's CFG passes, which changed a sphere pile's bits."""
    import taichi as ti
    from taichi.lang import impl
    from taichi.lang.kernel_impl import Kernel

    import taichi_anim as ta
    from taichi_anim import runtime

    seen: list[bool] = []
    launch = Kernel.launch_kernel

    def record(kernel, *args, **kwargs):
        if kernel.func.__name__ == "switched":
            seen.append(impl.current_cfg().cfg_optimization)
        return launch(kernel, *args, **kwargs)

    monkeypatch.setattr(Kernel, "launch_kernel", record)
    monkeypatch.setattr(runtime, "id", lambda obj: 7, raising=False)  # the module's lookup of id()

    @runtime.data_oriented
    class Sums:
        def __init__(self):
            self.out = ti.field(ti.i32, ())

        @runtime.compile_with(cfg_optimization=False)
        @ti.kernel
        def switched(self, n: ti.i32):
            for i in range(n):
                ti.atomic_add(self.out[None], i)

    settings = []
    for _ in range(2):
        ta.init("cpu")
        settings.append(impl.current_cfg().cfg_optimization)
        sums = Sums()
        sums.switched(10)
        sums.switched(10)
        assert sums.out[None] == 90
    assert settings == [True, True]  # the program's own setting, which only the compiling launch overrides
    assert seen == [False, True, False, True]


def test_compile_with_refuses_unknown_switches():
    from taichi_anim import runtime
    from taichi_anim.errors import ParameterError

    with pytest.raises(ParameterError, match="fast_math"):
        runtime.compile_with(fast_math=False)


def test_the_offline_cache_holds_a_test_suites_kernels(monkeypatch):
    """Taichi's default cap (100 MB, then a quarter of the files deleted at every program's end) is below
    what the engine's kernels take (the test suite's: 334 MB): init raises it unless the user chose."""
    from taichi.lang import impl

    import taichi_anim as ta
    from taichi_anim import runtime

    monkeypatch.delenv("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", raising=False)
    ta.init("cpu")
    assert impl.current_cfg().offline_cache_max_size_of_files == runtime.OFFLINE_CACHE_BYTES > 300 * 2**20
    ta.init("cpu", offline_cache_max_size_of_files=12345)  # an explicit option wins
    assert impl.current_cfg().offline_cache_max_size_of_files == 12345
    monkeypatch.setenv("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", "54321")  # and so does Taichi's variable
    ta.init("cpu")
    assert impl.current_cfg().offline_cache_max_size_of_files == 54321
