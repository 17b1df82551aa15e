"""Hard cases for backend choice: "auto" and "gpu" never crash the process, fall back to the CPU with a
message when no GPU starts, and record what was asked, what runs and why.

Taichi's own `ti.init(arch=ti.gpu)` dies with SIGSEGV on a machine without a GPU (its OpenGL check calls
a null function pointer), so every case that could crash runs in a child process."""

import json
import os
import subprocess
import sys
import warnings

import pytest

import taichi_anim as ta
from taichi_anim import runtime

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def run_python(code: str, *args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run(
        [sys.executable, *(["-c", code] if code else []), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        cwd=REPO,
    )


@pytest.mark.parametrize("arch", ["auto", "gpu"])
def test_init_auto_and_gpu_never_crash(arch):
    """Pass: `ta.init(arch)` in a fresh process exits 0; the backend it returns is the one
    `arch_choice()` reports; on the CPU the reason names each GPU backend probed and a RuntimeWarning
    says so on stderr; with a GPU the chosen backend passed its probe."""
    code = (
        "import json, taichi_anim as ta\n"
        "from taichi_anim import runtime\n"
        f"running = ta.init({arch!r})\n"
        "print('CHOICE', json.dumps(dict(runtime.arch_choice(), running=running)))\n"
    )
    out = run_python(code)
    assert out.returncode == 0, (out.returncode, out.stderr[-2000:])
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("CHOICE "))
    choice = json.loads(line[len("CHOICE ") :])
    assert choice["requested"] == arch and choice["chosen"] == choice["running"]
    probed = {p["arch"]: p for p in choice["probes"]}
    if choice["chosen"] == "cpu":
        assert set(probed) == set(runtime.GPU_CANDIDATES)
        assert not any(p["ok"] for p in probed.values())
        assert "no GPU found" in choice["reason"] and all(a in choice["reason"] for a in probed)
        assert "RuntimeWarning" in out.stderr and "running on the CPU" in out.stderr
    else:
        assert probed[choice["chosen"]]["ok"]


def test_cli_arch_auto_runs_one_frame(tmp_path):
    """Pass: `taichi-anim demo --arch auto --frames 1` exits 0 (not 139) and its run record names the
    backend that ran and the arch that was asked for."""
    out_dir = tmp_path / "out"
    out = run_python(
        "", "-m", "taichi_anim", "demo", "fountain", "--arch", "auto", "--frames", "1",
        "--quiet", "--no-export", "--out", str(out_dir),
    )  # fmt: skip
    assert out.returncode == 0, (out.returncode, out.stderr[-2000:])
    record = json.loads((out_dir / "run.json").read_text())
    choice = record["settings"]["arch_choice"]
    assert record["settings"]["arch_requested"] == "auto" and choice["requested"] == "auto"
    assert choice["chosen"] == record["timings"]["arch"] and choice["chosen"] in ("cpu", "cuda", "vulkan")
    assert [p["arch"] for p in choice["probes"]][:1] == ["cuda"]  # the GPU search ran in a child process
    if choice["chosen"] == "cpu":
        assert choice["reason"] and "running on the CPU" in out.stderr


def test_a_crashing_probe_does_not_take_the_process_down():
    """Pass: probing OpenGL (the backend whose check segfaults without a GPU) returns an answer in this
    process; where it crashed the detail names the signal."""
    runtime._probes.pop("opengl", None)
    result = runtime.probe_arch("opengl")
    assert set(result) == {"arch", "ok", "detail", "seconds"} and result["arch"] == "opengl"
    assert isinstance(result["ok"], bool) and result["detail"]
    if not result["ok"] and "crashed" in result["detail"]:
        assert "signal 11" in result["detail"]
    runtime._probes.pop("opengl", None)  # not one of the candidates: keep arch_choice() as the app sees it


def test_probe_verdicts():
    """Pass: the probe's output is read right: a crash, a failed start, a CPU fallback (with Taichi's
    reason), a wrong kernel result and a software Vulkan driver are all 'no'; a started device that ran
    the kernel is 'yes'."""
    verdict = runtime._probe_verdict
    assert verdict("cuda", -11, "") == (False, "Taichi crashed while starting cuda (signal 11)")
    ok, detail = verdict("cuda", 1, "Traceback ...\nRuntimeError: boom\n")
    assert not ok and "RuntimeError: boom" in detail
    fell_back = (
        "[W 11/24/26 08:05:27.210 1] [cuda_driver.cpp:load_lib@36] libcuda.so lib not found.\n"
        "[W 11/24/26 08:05:27.211 1] [misc.py:adaptive_arch_select@758] Arch=[cuda] is not supported\n"
        "TAICHI_ANIM_PROBE started x64\n"
    )
    assert verdict("cuda", 0, fell_back) == (False, "Taichi found no cuda device: libcuda.so lib not found.")
    assert not verdict("cuda", 0, "TAICHI_ANIM_PROBE started cuda\nTAICHI_ANIM_PROBE kernel wrong\n")[0]
    good = "TAICHI_ANIM_PROBE started {0}\nTAICHI_ANIM_PROBE kernel ok\n"
    assert verdict("cuda", 0, good.format("cuda"))[0]
    lavapipe = '[D] Vulkan Device "llvmpipe (LLVM 15.0.6, 256 bits)" supports Vulkan 0 version 1.3.230\n'
    ok, detail = verdict("vulkan", 0, lavapipe + good.format("vulkan"))
    assert not ok and "llvmpipe" in detail
    assert verdict("vulkan", 0, '[D] Vulkan Device "NVIDIA H100"\n' + good.format("vulkan"))[0]


def test_probe_is_cached_per_process(monkeypatch):
    """Pass: a second probe of the same backend starts no child process."""
    calls = []

    def fake_run(*args, **kwargs):
        calls.append(args)
        return subprocess.CompletedProcess(args, 0, "TAICHI_ANIM_PROBE started x64\n", "")

    monkeypatch.setattr(runtime, "_probes", {})
    monkeypatch.setattr(runtime.subprocess, "run", fake_run)
    first = runtime.probe_arch("cuda")
    assert runtime.probe_arch("cuda") is first and len(calls) == 1 and not first["ok"]


def test_probe_passes_but_taichi_falls_back(monkeypatch):
    """Pass: when a probe said yes but Taichi still starts the CPU in this process, init warns, returns
    "cpu" and the record says why (nothing crashes; the explicit "cuda" request stays an error)."""
    fake = {a: {"arch": a, "ok": a == "cuda", "detail": "faked", "seconds": 0.0} for a in ("cuda", "vulkan")}
    monkeypatch.setattr(runtime, "_probes", fake)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        running = ta.init("auto")
    if running == "cuda":  # a machine with CUDA: the faked probe was right after all
        return
    assert running == "cpu" and runtime.arch_choice()["chosen"] == "cpu"
    assert "could not start cuda" in runtime.arch_choice()["reason"]
    assert any("could not start cuda" in str(w.message) for w in caught)
