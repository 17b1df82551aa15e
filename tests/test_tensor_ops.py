"""Taichi's vector and matrix operations built straight into the IR (taichi_anim/tensor_ops.py): the same
values as Taichi's own inlined functions, bit for bit, in both precisions; Taichi's errors for calls
outside the shapes they handle; Python-scope matrices untouched."""

import numpy as np
import pytest
import taichi as ti

import taichi_anim as ta
from taichi_anim import tensor_ops

pytestmark = pytest.mark.skipif(not tensor_ops.available(), reason="replacements not checked on this Taichi")

N = 64  # random operand sets


def _every_operation(precision: str) -> np.ndarray:
    """Each replaced operation (as a method, through `@` and through ti.math) on N random vectors and
    matrices, in a fresh program of `precision`, as an (N, values) array."""
    ta.init("cpu", precision=precision)
    dtype = np.float32 if precision == "f32" else np.float64
    a, b = ti.Vector.field(3, float, N), ti.Vector.field(3, float, N)
    m, r = ti.Matrix.field(3, 3, float, N), ti.Matrix.field(2, 3, float, N)
    rng = np.random.default_rng(7)
    for f, shape in ((a, (N, 3)), (b, (N, 3)), (m, (N, 3, 3)), (r, (N, 2, 3))):
        f.from_numpy(rng.normal(size=shape).astype(dtype))
    out = ti.field(float, (N, 32))

    @ti.kernel
    def evaluate():
        for i in range(N):
            x, y, q, p = a[i], b[i], m[i], r[i]
            values = [
                x.dot(y), x.cross(y)[0], x.cross(y)[2], x.xy.cross(y.xy), x.sum(), q.sum(),
                x.norm(), x.norm(1e-3), x.norm_sqr(), x.norm_inv(), x.normalized()[1], x.normalized(1e-2)[2],
                x.max(), x.min(), q.max(), (q @ x)[2], (x @ q)[1], (q @ q)[1, 2], (p @ q)[1, 0], (p @ x)[1],
                q.transpose()[0, 1], p.transpose()[2, 1], x.outer_product(y)[2, 0], (x - y).dot(x + y),
                ti.math.length(x), ti.math.normalize(y)[0], ti.math.cross(x, y)[1], ti.math.dot(x, y),
                (q @ q @ x)[0], x @ y, (q.transpose() @ q)[2, 2], (p @ q.transpose() @ x)[0],
            ]  # fmt: skip
            for c in ti.static(range(len(values))):
                out[i, c] = values[c]

    evaluate()
    return out.to_numpy()


@pytest.mark.parametrize("precision", ["f32", "f64"])
def test_every_operation_gives_taichis_bits(precision):
    direct = _every_operation(precision)
    tensor_ops.uninstall()
    try:
        inlined = _every_operation(precision)
    finally:
        tensor_ops.install()
    assert np.isfinite(inlined).all()
    # The same operations in the same order: the same bits (a tolerance of round-off would hide a
    # reordered sum, which is what the replacements must not do).
    np.testing.assert_array_equal(direct, inlined)


def test_a_later_write_does_not_change_a_product_already_taken():
    """As Taichi copies a function's arguments, the replacements read each operand once, when called."""
    out = ti.field(float, 3)

    @ti.kernel
    def k():
        x = ti.Vector([1.0, 2.0, 3.0])
        d = x.dot(x)
        c = x.cross(ti.Vector([0.0, 0.0, 1.0]))
        x[0] = 100.0
        out[0], out[1], out[2] = d, c[0], c[1]

    k()
    assert out.to_numpy().tolist() == [14.0, 2.0, -1.0]


def test_calls_outside_the_handled_shapes_raise_taichis_errors():
    @ti.kernel
    def dot_of_a_matrix() -> float:
        q = ti.Matrix([[1.0, 0.0], [0.0, 1.0]])
        return q.dot(q)

    @ti.kernel
    def mismatched_product() -> float:
        q = ti.Matrix([[1.0, 0.0], [0.0, 1.0]])
        return (q @ ti.Vector([1.0, 2.0, 3.0]))[0]

    with pytest.raises(ti.TaichiCompilationError, match="not a vector"):
        dot_of_a_matrix()
    with pytest.raises(ti.TaichiCompilationError, match="[Dd]imension mismatch"):
        mismatched_product()


def test_python_scope_matrices_are_taichis():
    x, y = ti.Vector([1.0, 2.0, 2.0]), ti.Vector([0.0, 1.0, 0.0])
    assert x.dot(y) == 2.0 and x.norm() == 3.0 and list(x.cross(y)) == [-2.0, 0.0, 1.0]
    q = ti.Matrix([[1.0, 2.0], [3.0, 4.0]])
    assert (q @ q).to_numpy().tolist() == [[7.0, 10.0], [15.0, 22.0]]
