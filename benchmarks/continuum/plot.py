"""The page's figure: error against wall time (own reference, continuum answer), implicit steps/s."""

from __future__ import annotations

from common import fmt_dt

from .config import IMPLICIT, MATERIALS, SYMPLECTIC, Settings

COLOURS = {"springs": "C0", "membrane": "C3"}


def _markers(s: Settings) -> dict:
    markers = {(SYMPLECTIC, None): "o"}
    for k, tol in enumerate(s.implicit_tols):
        markers[(IMPLICIT, tol)] = "s^v"[k % 3]
    return markers


def _series(ax, rows: list, key: str, model: str, method: str, tol, mk: str) -> None:
    """One model, method and tol: its stable runs as a line, unstable runs as crosses at 1 m."""
    sel = [r for r in rows if r["model"] == model and r["method"] == method and r["tol"] == tol]
    ok = [r for r in sel if r["status"] == "ok"]
    colour = COLOURS[model]
    if ok:
        ax.plot(
            [r["wall_per_sim_s"] for r in ok],
            [r[key] for r in ok],
            mk + "-",
            color=colour,
            mfc="none" if method.startswith("implicit") else colour,
            label=f"{model}: {method}" + (f" tol {tol:g}" if tol else ""),
            lw=0.8,
        )
        for r in ok:
            ax.annotate(fmt_dt(r["dt"]), (r["wall_per_sim_s"], r[key]), fontsize=6, alpha=0.7)
    for r in sel:
        if r["status"] != "ok":
            ax.plot([r["wall_per_sim_s"]], [1.0], "x", color=colour, ms=9)


def _error_panel(ax, rows: list, cont: dict, key: str, title: str, s: Settings) -> None:
    from matplotlib.ticker import NullFormatter

    for model in MATERIALS:
        for (method, tol), mk in _markers(s).items():
            _series(ax, rows, key, model, method, tol, mk)
    if key == "cont_max":
        for model in MATERIALS:
            ax.axhline(
                cont["model_error"][model][0],
                color=COLOURS[model],
                ls="--",
                lw=1,
                label=f"{model}: converged {s.n}² answer vs continuum",
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("wall time per simulated second [s] (f64, 2 threads)")
    ax.set_ylabel(f"max vertex error at T = {s.t_end:g} s [m]")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", lw=0.3)


def _rate_panel(ax, rows2: list, s: Settings) -> None:
    from matplotlib.ticker import NullFormatter

    for model in MATERIALS:
        for k, tol in enumerate(s.tols2):
            sel = [r for r in rows2 if r["model"] == model and r["tol"] == tol]
            if sel:
                ax.plot(
                    [r["n"] for r in sel],
                    [r["rate"] for r in sel],
                    "os"[k % 2] + ("-" if k == 0 else "--"),
                    color=COLOURS[model],
                    label=f"{model}, PCG tol {tol:g}",
                )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xticks(list(s.sizes2))
    ax.set_xticklabels([f"{n}²" for n in s.sizes2])
    ax.set_xlabel("grid")
    ax.set_ylabel("implicit steps per second at dt = 1/60 s (f32)")
    ax.set_title("implicit Euler, one step per frame, two corners pinned", fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)


def plot(rows: list, cont: dict, rows2: list, path, s: Settings) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(18, 6.4))
    _error_panel(axes[0], rows, cont, "err_max", "error against the model's own converged answer", s)
    title = f"error against the continuum answer ({cont['finest']}² membrane)"
    _error_panel(axes[1], rows, cont, "cont_max", title, s)
    handles, labels = axes[1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    _rate_panel(axes[2], rows2, s)
    fig.suptitle(
        f"Springs vs membrane + bending, {s.n}² cloth swinging from one edge (crosses: unstable runs)",
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
