"""bulk.fill: many fields written in one launch hold what from_numpy writes, bit for bit."""

import numpy as np
import pytest
import taichi as ti

from taichi_anim import bulk, capacity


def test_one_launch_writes_what_from_numpy_writes():
    rng = np.random.default_rng(0)
    shapes = [
        ((5,), (), float),
        ((4,), (3,), float),
        ((3,), (3, 3), float),
        ((6,), (), ti.i32),
        ((2,), (4, 3), float),
    ]
    pairs, expected = [], []
    for shape, dims, dtype in shapes:
        if dtype == ti.i32:
            a = rng.integers(-1000, 1000, (*shape, *dims)).astype(np.int32)
        else:
            a = rng.standard_normal((*shape, *dims))
        pairs.append((capacity.make(dtype, shape, dims), a))
        reference = capacity.make(dtype, shape, dims)
        reference.from_numpy(a)
        expected.append(reference)
    bulk.fill(pairs)
    for (field, _), reference in zip(pairs, expected, strict=True):
        np.testing.assert_array_equal(field.to_numpy(), reference.to_numpy())


def test_a_wrong_shape_is_refused():
    f = capacity.make(float, (4,), (3,))
    with pytest.raises(ValueError, match=r"an array of shape \(4,\) for a field of \(4,\) x \(3,\)"):
        bulk.fill([(f, np.zeros(4))])


def test_fields_of_one_length_share_loops_and_hold_what_from_numpy_writes():
    """Forty fields, most of one length (a rigid model's case): one loop per run of at most GROUP fields
    of a length, each field still written whole."""
    rng = np.random.default_rng(1)
    lengths = [7] * 35 + [3, 7, 5, 3, 9]
    pairs, arrays = [], []
    for k, n in enumerate(lengths):
        dims = ((), (3,), (3, 3))[k % 3]
        a = rng.standard_normal((n, *dims))
        pairs.append((capacity.make(float, (n,), dims), a))
        arrays.append(a)
    assert bulk._loops(lengths) == (
        (7, tuple(range(16))),
        (7, tuple(range(16, 32))),
        (7, (32, 33, 34, 36)),
        (3, (35, 38)),
        (5, (37,)),
        (9, (39,)),
    )
    bulk.fill(pairs)
    for (field, _), a in zip(pairs, arrays, strict=True):
        np.testing.assert_array_equal(field.to_numpy(), a)
