"""Device probe, run as a script in a child process by `runtime.probe_arch`: start Taichi on the backend
named by argv[1], print the backend that actually runs (Taichi falls back to the CPU, with a warning,
when the backend is missing), and if it is the one asked for, run one kernel and read its result back.
Taichi logs at debug level, so the Vulkan device's name is in the output. A crash here (Taichi's OpenGL
check dies with SIGSEGV on machines without a GPU) ends only this child."""

import sys

MARK = "TAICHI_ANIM_PROBE"


def main(arch: str) -> int:
    import taichi as ti
    from taichi.lang import impl

    ti.init(arch=getattr(ti, arch), log_level=ti.DEBUG, offline_cache=False)
    running = impl.current_cfg().arch.name
    print(MARK, "started", running, flush=True)
    if running != arch:
        return 0
    x = ti.field(ti.f32, 4)

    @ti.kernel
    def fill():
        for i in x:
            x[i] = i

    fill()
    ok = float(x.to_numpy().sum()) == 6.0
    print(MARK, "kernel", "ok" if ok else "wrong", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
