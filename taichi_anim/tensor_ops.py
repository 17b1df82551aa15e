"""Taichi's vector and matrix operations (dot, cross, sum, norms, @, ...) built straight into a kernel's IR.

Taichi 1.7 writes them as Python functions (`taichi.lang.matrix_ops`) that its front end inlines at every
call the way it inlines a `ti.func`: it parses the function's source, copies each argument into a new
local variable and visits every node of the body, at each `.dot`, `.cross`, `.norm()` and `@`, and `dot`
calls `sum`, which calls `_reduce`, each inlined in turn. On the rigid contact step that was about half
of the front end's time, which every process pays for every kernel instance, warm offline cache or not
(the cache key is a hash of the IR the front end builds).

The functions below build the same arithmetic in the same order from Python directly: a dot product is
((x0 y0 + x1 y1) + x2 y2), a matrix product's entries are summed onto the same zero as Taichi's, a norm
is sqrt(sum of squares + eps). Each tensor argument is copied once, as Taichi copies a function's
arguments, so a later write to a variable never changes a product already taken. The IR is smaller than
Taichi's (fewer copies), so its offline cache keys differ from those of Taichi's own functions; the
results are the same (tests/test_tensor_ops.py). A call with arguments outside the shapes handled here
(a Python-scope matrix, a dot of a matrix, mismatched sizes) goes to Taichi's own function, which raises
its own errors.

`install()` replaces the module's attributes, which Taichi's front end looks up at each call (a method
on a tensor expression, `@`, `ti.math`). It is on for the Taichi versions it was checked against;
TAICHI_ANIM_PLAIN_MATRIX_OPS=1 turns it off.
"""

from taichi._lib import core as _core
from taichi.lang import impl, matrix, ops
from taichi.lang.expr import Expr, make_expr_group

from .frontend import patch_allowed

CHECKED_VERSIONS = {(1, 7, 4)}
REPLACED = (
    "dot", "cross", "outer_product", "sum", "norm_sqr", "norm", "norm_inv", "normalized", "max", "min",
    "transpose", "matmul",
)  # fmt: skip

_originals: dict = {}
_installed = False


def _shape(x):
    """x's tensor shape inside a kernel, or None for anything else (then Taichi's own function runs)."""
    if isinstance(x, Expr) and impl.inside_kernel() and x.is_tensor():
        return tuple(x.get_shape())
    return None


class _Reader:
    """Elements of a copy of tensor x, read with one source position (Taichi formats one per read)."""

    def __init__(self, x):
        self.builder = impl.get_runtime().compiling_callable.ast_builder()
        self.info = _core.DebugInfo(impl.get_runtime().get_current_src_info())
        self.var = impl.expr_init(x)

    def __getitem__(self, index):
        index = index if isinstance(index, tuple) else (index,)
        return Expr(self.builder.expr_subscript(self.var.ptr, make_expr_group(*index), self.info))


def _entries(shape):
    """Indices of a tensor of `shape` in row-major order (Taichi's _reduce order)."""
    if len(shape) == 1:
        return [(i,) for i in range(shape[0])]
    return [(i, j) for i in range(shape[0]) for j in range(shape[1])]


def _reduce(x, shape, fun):
    r = _Reader(x)
    items = _entries(shape)
    out = r[items[0]]
    for index in items[1:]:
        out = fun(out, r[index])
    return out


def _vector(shape):
    return shape is not None and len(shape) == 1


def sum(mat):  # noqa: A001 (Taichi's name)
    shape = _shape(mat)
    if shape is None:
        return _originals["sum"](mat)
    return _reduce(mat, shape, ops.add)


def max(mat):  # noqa: A001
    shape = _shape(mat)
    if shape is None:
        return _originals["max"](mat)
    return _reduce(mat, shape, ops.max_impl)


def min(mat):  # noqa: A001
    shape = _shape(mat)
    if shape is None:
        return _originals["min"](mat)
    return _reduce(mat, shape, ops.min_impl)


def norm_sqr(mat):
    shape = _shape(mat)
    if shape is None:
        return _originals["norm_sqr"](mat)
    m = _Reader(mat).var
    return _reduce(m * m, shape, ops.add)


def norm(mat, eps=0.0):
    if _shape(mat) is None:
        return _originals["norm"](mat, eps)
    return ops.sqrt(norm_sqr(mat) + eps)


def norm_inv(mat, eps=0.0):
    if _shape(mat) is None:
        return _originals["norm_inv"](mat, eps)
    return ops.rsqrt(norm_sqr(mat) + eps)


def normalized(vec, eps=0.0):
    if not _vector(_shape(vec)):
        return _originals["normalized"](vec, eps)
    v = _Reader(vec).var
    invlen = 1 / (norm(v) + eps)
    return invlen * v


def dot(vec_x, vec_y):
    sx, sy = _shape(vec_x), _shape(vec_y)
    if not (_vector(sx) and sx == sy):
        return _originals["dot"](vec_x, vec_y)
    x, y = _Reader(vec_x).var, _Reader(vec_y).var
    return _reduce(x * y, sx, ops.add)


def cross(vec_x, vec_y):
    sx, sy = _shape(vec_x), _shape(vec_y)
    if not (sx == sy and sx in ((2,), (3,))):
        return _originals["cross"](vec_x, vec_y)
    x, y = _Reader(vec_x), _Reader(vec_y)
    if sx == (2,):
        return x[0] * y[1] - x[1] * y[0]
    return matrix.make_matrix(
        [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]]
    )


def outer_product(vec_x, vec_y):
    sx, sy = _shape(vec_x), _shape(vec_y)
    if not (_vector(sx) and _vector(sy)):
        return _originals["outer_product"](vec_x, vec_y)
    x, y = _Reader(vec_x), _Reader(vec_y)
    return matrix.make_matrix([[x[i] * y[j] for j in range(sy[0])] for i in range(sx[0])])


def transpose(mat):
    shape = _shape(mat)
    if shape is None or len(shape) != 2:
        return _originals["transpose"](mat)
    m = _Reader(mat)
    return matrix.make_matrix([[m[i, j] for i in range(shape[0])] for j in range(shape[1])])


def matmul(mat_x, mat_y):
    """Taichi's matmul: vector @ vector is a dot; vector @ matrix is (matrix^T) @ vector; each entry of
    a product is summed onto zero_elem (x[0, 0] y[0] 0, which carries the result's type) in k order."""
    sx, sy = _shape(mat_x), _shape(mat_y)
    if sx is None or sy is None:
        return _originals["matmul"](mat_x, mat_y)
    if len(sx) == 1 and len(sy) == 1:
        return dot(mat_x, mat_y) if sx == sy else _originals["matmul"](mat_x, mat_y)
    if len(sx) == 1:  # x @ Y = Y^T x
        if sy[0] != sx[0]:
            return _originals["matmul"](mat_x, mat_y)
        return matmul(transpose(mat_y), mat_x)
    if sx[1] != sy[0]:
        return _originals["matmul"](mat_x, mat_y)
    x, y = _Reader(mat_x), _Reader(mat_y)
    if len(sy) == 1:
        zero = impl.expr_init(x[0, 0] * y[0] * 0)
        out = []
        for i in range(sx[0]):
            acc = zero
            for k in range(sx[1]):
                acc = acc + x[i, k] * y[k]
            out.append(acc)
        return matrix.make_matrix(out)
    zero = impl.expr_init(x[0, 0] * y[0, 0] * 0)
    rows = []
    for i in range(sx[0]):
        row = []
        for j in range(sy[1]):
            acc = zero
            for k in range(sx[1]):
                acc = acc + x[i, k] * y[k, j]
            row.append(acc)
        rows.append(row)
    return matrix.make_matrix(rows)


def available() -> bool:
    """Whether this Taichi is one the replacements were checked against, and they are not turned off."""
    return patch_allowed("TAICHI_ANIM_PLAIN_MATRIX_OPS", CHECKED_VERSIONS)


def install() -> bool:
    """Replace Taichi's matrix operations once per process; returns whether they are replaced."""
    global _installed
    if _installed or not available():
        return _installed
    from taichi.lang import matrix_ops

    here = globals()
    for name in REPLACED:
        _originals[name] = getattr(matrix_ops, name)
        setattr(matrix_ops, name, here[name])
    _installed = True
    return True


def uninstall() -> None:
    """Put Taichi's own functions back (for tests that compare the two)."""
    global _installed
    if not _installed:
        return
    from taichi.lang import matrix_ops

    for name in REPLACED:
        setattr(matrix_ops, name, _originals[name])
    _installed = False
