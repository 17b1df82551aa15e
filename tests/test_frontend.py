"""The cheaper Taichi front end (taichi_anim/frontend.py): the same source positions for every node it
visits, the same error messages, and the same offline cache entries as Taichi's own front end."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim import frontend

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not frontend.available(), reason="patch not checked on this Taichi")


@ti.func
def _spread(v, k: ti.template()):
    out = ti.Vector.zero(float, 3)
    for c in ti.static(range(3)):
        out[c] = v[c] * (k + c)
    return out


def _kernels():
    """A kernel with the constructs whose positions Taichi formats differently: one-line and multi-line
    statements, for/if/while headers, static unrolls and an inlined function called twice."""
    x = ti.Vector.field(3, float, 8)

    @ti.kernel
    def k(s: float) -> float:
        acc = 0.0
        for i in range(8):
            v = ti.Vector([i, s, 1.0])
            if i % 2 == 0:
                x[i] = _spread(v, 1) + _spread(
                    v,
                    2,
                )
            j = 0
            while j < 2:
                j += 1
            acc += x[i].sum()
        return acc

    return k


def test_every_visited_position_is_taichis_own_text():
    seen = []
    init = frontend._Position.__init__

    def record(self, ctx, node):
        init(self, ctx, node)
        seen.append((ctx, node))

    frontend._Position.__init__ = record
    try:
        _kernels()(0.5)
    finally:
        frontend._Position.__init__ = init
    assert len(seen) > 100
    texts = [frontend._position_text(ctx, node) for ctx, node in seen]
    # Taichi's own function with Taichi's own TextWrapper (the patch memoises its wraps)
    from taichi.lang.ast import ast_transformer_utils as utils

    original = frontend._originals["get_pos_info"]
    utils.TextWrapper = frontend._originals["text_wrapper"]
    try:
        assert texts == [original(ctx, node) for ctx, node in seen]
    finally:
        utils.TextWrapper = frontend._MemoTextWrapper


def _error_message() -> str:
    @ti.kernel
    def broken() -> float:
        y = 1.0
        return y + undefined_name  # noqa: F821

    with pytest.raises(Exception) as caught:
        broken()
    return f"{type(caught.value).__name__}: {caught.value}"


def test_errors_read_as_with_taichis_front_end():
    patched = _error_message()
    frontend.uninstall()
    try:
        ta.init("cpu", precision="f64")
        plain = _error_message()
    finally:
        frontend.install()
    assert "undefined_name" in patched and "^" in patched
    assert patched == plain


_CACHE_RUN = """
import taichi as ti, taichi_anim as ta
from taichi_anim.scenes import make_scene
ta.init("cpu")
scene = make_scene("cloth", resolution=6)
scene.advance_frame()
ti.sync()
"""


def test_offline_cache_entries_are_the_same(tmp_path):
    """A scene stepped with the patched front end fills a cache; Taichi's own front end on that cache
    then compiles no kernel of its own: the IR is the same (its hash, the cache key, leaves the
    positions out; the first test checks those)."""

    def run(plain: bool) -> set[str]:
        env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=str(tmp_path), PYTHONPATH=str(ROOT))
        env["TAICHI_ANIM_PLAIN_FRONTEND"] = "1" if plain else "0"
        done = subprocess.run([sys.executable, "-c", _CACHE_RUN], env=env, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]
        return {p.name for p in tmp_path.rglob("*.tic")}

    patched = run(plain=False)
    assert len(patched) > 5
    assert run(plain=True) == patched


def test_first_source_read_matches_inspect():
    """The fast first read of a function's source gives inspect's lines and first line number, for
    kernels' functions (decorated, methods, nested) across the engine's modules."""
    import inspect

    from taichi_anim.bodies.rigid import contacts, detection, gjk
    from taichi_anim.integrators import base as integrators

    def python_function(obj):
        """The plain function behind a ti.func, ti.kernel or method, or None."""
        for name in ("_primal", "func", "func"):
            obj = getattr(obj, name, obj)
        return obj if inspect.isfunction(obj) else None

    funcs = [python_function(_spread), _kernels, test_first_source_read_matches_inspect]
    for module in (contacts, detection, gjk, integrators):
        for obj in vars(module).values():
            for member in vars(obj).values() if inspect.isclass(obj) else [obj]:
                func = python_function(member)
                if func is not None and func.__module__ == module.__name__:
                    funcs.append(func)
    assert len(funcs) > 40
    expected = [inspect.getsourcelines(func) for func in funcs]

    def refuse(obj):
        raise AssertionError(f"{obj.__qualname__} went to inspect")

    saved = frontend._originals["getsourcelines"]
    frontend._originals["getsourcelines"] = refuse  # every one of these takes the fast read
    try:
        for func, lines in zip(funcs, expected, strict=True):
            assert frontend._first_sourcelines(func) == lines, func.__qualname__
    finally:
        frontend._originals["getsourcelines"] = saved


def test_integer_literal_checks_match_taichis():
    import numpy as np

    check, clamp = frontend._originals["check_in_range"], frontend._originals["clamp_unsigned"]
    for npty in (np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint32, np.uint64):
        info = np.iinfo(npty)
        for val in (info.min, info.min - 1, info.max, info.max + 1, 0, -1, 2**31, 2**63 - 1, 2**63):
            assert frontend._check_in_range(npty, val) == check(npty, val)
    for val in (0, 2**63 - 1, 2**63, 2**64 - 1, -(2**63)):
        assert frontend._clamp_unsigned_to_range(np.int64, val) == clamp(np.int64, val)


def test_wraps_are_textwrappers():
    """The memoised wrap's shortcut for lines that fit gives TextWrapper's own result: random lines of
    code-like text with leading and trailing spaces, carets, blanks, tabs and lines too long."""
    import random
    import textwrap

    rng = random.Random(7)
    alphabet = "ab c  ^-.,()[]=+*/_0\t"
    for _ in range(20_000):
        text = " " * rng.randint(0, 8) + "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 90)))
        text += " " * rng.randint(0, 3)
        assert frontend._wrapped(80, text) == tuple(textwrap.TextWrapper(width=80).wrap(text)), repr(text)
    assert frontend._wrapped(80, "    ") == () and frontend._wrapped(80, "  x = 1  ") == ("  x = 1",)
