"""A cheaper Python front end for Taichi's kernels: the same IR, built in well under half the time.

Every kernel instance is built by Taichi's Python front end, on each run, warm offline cache or not: the
cache key is a hash of the IR that front end builds, so it cannot be skipped. On this engine's largest
kernels that front end was most of a warm start (the flag: 3.5 s of 4.5 s), and a profile of it shows
two costs that do not shape the IR:

- the source position of every AST node visited, formatted eagerly (a `TextWrapper` per line) so that an
  error message can name it: more than half of the front end's time, though only one visit in four ever
  reads it (the IR's debug info) and an error reads one;
- the function's source read again through `inspect` (its file looked up, a tokenizer pass) and each of
  its lines re-wrapped by `textwrap.fill` at every inlined `ti.func` call: 0.7 s of the flag's 8 s
  profile.

`install()` makes the first lazy (each visit pushes its node; the text is formatted when read, memoised
by the source it points at) and memoises the second per code object (the file and lines) and per line
(the wrap): the flag's front end took 1.3 s instead of 3.5 s. A position, once read, is wrapped to 80
columns line by line (its source and its carets) by a TextWrapper; those wraps are memoised per string
too (the pile demo's warm contact step: front end 0.61 -> 0.58 s). A one-line node's position (most
nodes) is memoised on its line and caret columns alone, a function's source is read the first time
without inspect's module lookup, and the integer limits every literal is checked against are memoised
(0.66-0.68 -> 0.58-0.60 s). The strings are Taichi's own,
character for character, so the IR, its debug info and the offline cache keys are unchanged (tested:
tests/test_frontend.py). Like the fast `data_oriented` in runtime.py it touches Taichi's private names,
so it is on only for the Taichi versions it was checked against, and TAICHI_ANIM_PLAIN_FRONTEND=1 turns
it off.
"""

from __future__ import annotations

import ast
import functools
import inspect
import linecache
import os
import re
import textwrap
import traceback
from types import SimpleNamespace

import numpy as np
import taichi as ti
from taichi.lang import expr, impl
from taichi.lang.exception import TaichiCompilationError, handle_exception_from_cpp

CHECKED_VERSIONS = {(1, 7, 4)}
MULTILINE_HEADERS = ("For", "While", "FunctionDef", "If")  # Taichi prints only their header lines

_installed = False
_originals: dict = {}
_positions: dict = {}  # memo of formatted positions, keyed by the text and place they describe
_lines: dict = {}  # (source line, first caret, end) -> that line and its carets, as get_pos_info wraps them
_sources: dict = {}  # code object -> (source lines, first line)
_files: dict = {}  # code object -> source file


class _Position:
    """A node's source position, formatted only when something reads it."""

    __slots__ = ("ctx", "node")

    def __init__(self, ctx, node):
        self.ctx = ctx
        self.node = node

    def text(self) -> str:
        return _position_text(self.ctx, self.node)


def _position_text(ctx, node) -> str:
    """Taichi's `get_pos_info(node)`, memoised on everything its text depends on."""
    first, last = node.lineno, node.end_lineno
    if first == last:  # most nodes: the header, then the line and its carets (memoised on those alone)
        col, end = ctx.indent + node.col_offset, ctx.indent + node.end_col_offset
        code = ctx.src[first - 1]
        shown = _lines.get((code, col, end))
        if shown is None:
            shown = _lines[code, col, end] = _code_and_hint(code, " " * col + "^" * (end - col))
        return f'File "{ctx.file}", line {first + ctx.lineno_offset}, in {ctx.func.func.__name__}:\n' + shown
    body = getattr(node, "body", None)
    header_end = body[0].lineno if type(node).__name__ in MULTILINE_HEADERS and body else None
    key = (
        ctx.file,
        ctx.lineno_offset,
        ctx.func.func.__name__,
        ctx.indent,
        type(node).__name__,
        first,
        last,
        node.col_offset,
        node.end_col_offset,
        header_end,
        "\n".join(ctx.src[first - 1 : max(last, first)]),
    )
    text = _positions.get(key)
    if text is None:
        text = _positions[key] = _originals["get_pos_info"](ctx, node)
    return text


def _code_and_hint(code: str, hint: str) -> str:
    """What get_pos_info writes under its header for a one-line node: the line and its line of carets,
    each wrapped to 80 columns, the pieces interleaved (Taichi's `gen_line`)."""
    hint += " " * (len(code) - len(hint))
    code_rows, hint_rows = _wrapped(80, code), _wrapped(80, hint)
    if not code_rows:
        return "\n\n"
    # the carets can wrap to fewer rows than the code (trailing spaces dropped): zip stops at the shorter
    return "".join(c + "\n" + h + "\n" for c, h in zip(code_rows, hint_rows, strict=False))


def _builder_call(self, ctx, node):
    """Taichi's `Builder.__call__` with the position pushed unformatted (see the module's docstring)."""
    method = getattr(self, "build_" + type(node).__name__, None)
    if method is None or not isinstance(node, (ast.stmt, ast.expr)):
        return _originals["builder_call"](self, ctx, node)  # no position to push; unknown nodes raise there
    stack = impl.get_runtime().src_info_stack
    stack.append(_Position(ctx, node))
    try:
        return method(ctx, node)
    except Exception as e:
        _raise_with_position(ctx, node, e)
    finally:
        stack.pop()


def _raise_with_position(ctx, node, e):
    """What Taichi's builder does with an error: name the innermost node's position once, then pass it up."""
    if impl.get_runtime().print_full_traceback:
        raise e
    if ctx.raised:
        raise e.with_traceback(None)
    ctx.raised = True
    e = handle_exception_from_cpp(e)
    if not isinstance(e, TaichiCompilationError):
        raise TaichiCompilationError(_position_text(ctx, node) + traceback.format_exc()) from None
    raise type(e)(_position_text(ctx, node) + str(e)) from None


def _current_src_info(self):
    info = self.src_info_stack[-1]
    return info.text() if type(info) is _Position else info


def _by_code(table: dict, original, obj):
    """original(obj), memoised per code object (a function's source cannot change while it exists)."""
    code = getattr(obj, "__code__", None)
    if code is None:
        return original(obj)
    found = table.get(code)
    if found is None:
        found = table[code] = original(obj)
    return found


def _getsourcelines(obj):
    lines, first = _by_code(_sources, _first_sourcelines, obj)
    return list(lines), first


_DEF_OR_DECORATOR = re.compile(r"^(\s*def\s)|(\s*async\s+def\s)|(.*(?<!\w)lambda(:|\s))|^(\s*@)")


def _first_sourcelines(obj):
    """`inspect.getsourcelines(obj)` for a plain function whose first line is its `def` or decorator:
    the block from there, read from the file's lines (inspect also looks the module up first: half the
    time of this first read of each function, which every process pays). Anything else goes to inspect."""
    code = getattr(obj, "__code__", None)
    if code is None or hasattr(obj, "__wrapped__") or not os.path.isfile(code.co_filename):
        return _originals["getsourcelines"](obj)
    lines = linecache.getlines(code.co_filename)
    start = code.co_firstlineno - 1
    if not 0 <= start < len(lines) or not _DEF_OR_DECORATOR.match(lines[start]):
        return _originals["getsourcelines"](obj)
    return inspect.getblock(lines[start:]), start + 1


def _getsourcefile(obj):
    return _by_code(_files, _originals["getsourcefile"], obj)


_fills: dict = {}


def _fill(text, tabsize=4, width=9999):
    """textwrap.fill(text, tabsize=tabsize, width=width), memoised (kernel_impl fills every source line
    of a function at each inlined call; a plain dict is cheaper than lru_cache with keywords)."""
    found = _fills.get((text, tabsize, width))
    if found is None:
        found = _fills[text, tabsize, width] = textwrap.fill(text, tabsize=tabsize, width=width)
    return found


# What kernel_impl reads from `textwrap`: fill (once per source line; memoised) and dedent.
_textwrap = SimpleNamespace(fill=_fill, dedent=textwrap.dedent)


_limits: dict = {}


def _int_limits(npty) -> tuple:
    """(min, max, bits) of a NumPy integer type: np.iinfo builds a new object at each call, and Taichi's
    front end asks twice for every integer literal (8,554 times in the pile demo's contact step)."""
    found = _limits.get(npty)
    if found is None:
        info = np.iinfo(npty)
        found = _limits[npty] = (int(info.min), int(info.max), info.bits)
    return found


def _check_in_range(npty, val):
    """taichi.lang.expr's check that an integer literal fits `npty`, with the limits memoised."""
    low, high, _ = _int_limits(npty)
    return low <= val <= high


def _clamp_unsigned_to_range(npty, val):
    """taichi.lang.expr's wrap of an unsigned literal above `npty`'s max into its signed range."""
    low, high, bits = _int_limits(npty)
    if low <= val <= high:
        return val
    cap = 1 << bits
    assert 0 <= val < cap
    return val - cap


_WRAPPED_WHITESPACE = re.compile(r"[\t\n\x0b\x0c\r]")  # what TextWrapper turns into spaces, but ' '


@functools.lru_cache(maxsize=1 << 16)
def _wrapped(width: int, text: str) -> tuple:
    """TextWrapper(width=width).wrap(text). A line that fits, of ASCII with no whitespace but spaces (most
    source lines and caret lines), wraps to itself without its trailing spaces, or to nothing if blank:
    written directly, as TextWrapper's chunking took 7 % of the pile demo's warm front end."""
    if len(text) <= width and text.isascii() and not _WRAPPED_WHITESPACE.search(text):
        kept = text.rstrip(" ")
        return (kept,) if kept else ()
    return tuple(textwrap.TextWrapper(width=width).wrap(text))


class _MemoTextWrapper(textwrap.TextWrapper):
    """What Taichi's get_pos_info makes, TextWrapper(width=80), with `wrap` memoised per string: it wraps
    each node's source line and its line of carets, the same strings for every node on a line and for
    every node at the same columns (12,659 wraps, 5,550 positions, in the pile demo's warm start)."""

    def wrap(self, text):
        if self.__dict__ != _DEFAULT_WRAPPER:
            return super().wrap(text)  # other settings: not memoised
        return list(_wrapped(self.width, text))


_DEFAULT_WRAPPER = textwrap.TextWrapper(width=80).__dict__


def patch_allowed(switch: str, versions) -> bool:
    """Whether a patch of Taichi's internals may be on: this Taichi is one of the `versions` it was checked
    against, and the environment variable `switch` (set to anything but 0) does not turn it off."""
    if os.environ.get(switch, "") not in ("", "0"):
        return False
    return tuple(ti.__version__) in versions


def available() -> bool:
    """Whether this Taichi is one the patch was checked against, and it is not turned off."""
    return patch_allowed("TAICHI_ANIM_PLAIN_FRONTEND", CHECKED_VERSIONS)


def install() -> bool:
    """Install the cheaper front end once per process; returns whether it is on."""
    global _installed
    if _installed or not available():
        return _installed
    from taichi.lang import kernel_impl
    from taichi.lang.ast import ast_transformer_utils as utils

    _originals.update(
        get_pos_info=utils.ASTTransformerContext.get_pos_info,
        builder_call=utils.Builder.__call__,
        current_src_info=impl.PyTaichi.get_current_src_info,
        getsourcelines=kernel_impl.getsourcelines,
        getsourcefile=kernel_impl.getsourcefile,
        textwrap=kernel_impl.textwrap,
        text_wrapper=utils.TextWrapper,
        check_in_range=expr._check_in_range,
        clamp_unsigned=expr._clamp_unsigned_to_range,
    )
    utils.ASTTransformerContext.get_pos_info = _position_text
    utils.Builder.__call__ = _builder_call
    impl.PyTaichi.get_current_src_info = _current_src_info
    kernel_impl.getsourcelines = _getsourcelines
    kernel_impl.getsourcefile = _getsourcefile
    kernel_impl.textwrap = _textwrap
    utils.TextWrapper = _MemoTextWrapper
    expr._check_in_range = _check_in_range
    expr._clamp_unsigned_to_range = _clamp_unsigned_to_range
    _installed = True
    return True


def uninstall() -> None:
    """Put Taichi's own front end back (for tests that compare the two)."""
    global _installed
    if not _installed:
        return
    from taichi.lang import kernel_impl
    from taichi.lang.ast import ast_transformer_utils as utils

    utils.ASTTransformerContext.get_pos_info = _originals["get_pos_info"]
    utils.Builder.__call__ = _originals["builder_call"]
    impl.PyTaichi.get_current_src_info = _originals["current_src_info"]
    kernel_impl.getsourcelines = _originals["getsourcelines"]
    kernel_impl.getsourcefile = _originals["getsourcefile"]
    kernel_impl.textwrap = _originals["textwrap"]
    utils.TextWrapper = _originals["text_wrapper"]
    expr._check_in_range = _originals["check_in_range"]
    expr._clamp_unsigned_to_range = _originals["clamp_unsigned"]
    _installed = False
