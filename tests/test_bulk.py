"""bulk.fill: many fields written in one launch hold what from_numpy writes, bit for bit; bulk.read:
many fields read in one launch give what to_numpy gives."""

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


def test_one_launch_reads_what_to_numpy_reads(monkeypatch):
    """Scalars, vectors and matrices of floats and ints, read over their first rows in one launch: the
    same values and types as to_numpy, with the requested shapes; floats alone; no row and too many
    rows."""
    rng = np.random.default_rng(1)
    fields = []
    for dims, dtype in [((), float), ((3,), float), ((3, 3), float), ((), ti.i32), ((4,), float)]:
        f = capacity.make(dtype, (7,), dims)
        f.from_numpy(
            rng.integers(-99, 99, (7, *dims)).astype(np.int32) if dtype == ti.i32 else rng.random((7, *dims))
        )
        fields.append(f)
    launches = []
    kernel = bulk._read_kernel
    monkeypatch.setattr(bulk, "_read_kernel", lambda *a: launches.append(1) or kernel(*a))
    got = bulk.read(fields, 5)
    assert len(launches) == 1
    for f, a in zip(fields, got, strict=True):
        expected = f.to_numpy()[:5]
        assert a.dtype == expected.dtype and a.shape == expected.shape
        np.testing.assert_array_equal(a, expected)
    assert [a.shape for a in bulk.read(fields[:2], 0)] == [(0,), (0, 3)] and len(launches) == 1
    # Floats only: the launch with one array argument, the same values.
    floats_only = [fields[i] for i in (0, 1, 2, 4)]
    kernel_floats = bulk._read_floats_kernel
    monkeypatch.setattr(bulk, "_read_floats_kernel", lambda *a: launches.append(2) or kernel_floats(*a))
    for f, a in zip(floats_only, bulk.read(floats_only, 6), strict=True):
        np.testing.assert_array_equal(a, f.to_numpy()[:6])
    assert launches == [1, 2]
    with pytest.raises(ValueError, match=r"8 rows of a field of shape \(7,\)"):
        bulk.read(fields, 8)


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


def test_a_batch_writes_everything_in_one_launch_on_leaving(monkeypatch):
    """Fills inside a batch (a nested one joins it) write nothing until the outer one is left, then all
    in one launch; a batch left by an error writes nothing."""
    launches = []
    launch = bulk._launch
    monkeypatch.setattr(bulk, "_launch", lambda entries: (launches.append(len(entries)), launch(entries)))
    a, b = capacity.make(float, (3,), ()), capacity.make(ti.i32, (2,), (3,))
    with bulk.batch():
        bulk.fill([(a, [1.0, 2.0, 3.0])])
        with bulk.batch():
            bulk.fill([(b, np.arange(6).reshape(2, 3))])
        assert launches == [] and a.to_numpy().tolist() == [0.0, 0.0, 0.0]
    assert launches == [2]
    assert a.to_numpy().tolist() == [1.0, 2.0, 3.0] and b.to_numpy().tolist() == [[0, 1, 2], [3, 4, 5]]
    with pytest.raises(RuntimeError, match="stop"), bulk.batch():
        bulk.fill([(a, [7.0, 7.0, 7.0])])
        raise RuntimeError("stop")
    assert launches == [2] and a.to_numpy().tolist() == [1.0, 2.0, 3.0]


def test_a_state_of_three_kinds_starts_in_one_launch(monkeypatch):
    """Model.state(): the particles', the rigid bodies' and the liquid's starts are one fill launch, and
    each holds its start (the liquid at rest density and zero pressure, the box where it was put)."""
    import taichi_anim as ta

    b = ta.Builder()
    b.add_force_gravity()
    b.add_collider_box((0.0, 0.0, 0.0), (0.2, 0.2, 0.06), restitution=0.0)
    b.add_fluid(spacing=0.02)
    b.add_fluid_block((0.0, 0.0, 0.0), (0.1, 0.04, 0.06))
    b.add_rigid_body(ta.shapes.Box((0.02, 0.02, 0.02)), density=500.0, position=(0.15, 0.1, 0.03))
    model = b.finalize()
    launches = []
    launch = bulk._launch
    monkeypatch.setattr(bulk, "_launch", lambda entries: (launches.append(len(entries)), launch(entries)))
    state = model.state()
    assert len(launches) == 1 and launches[0] >= 12  # particles 2, rigid bodies 6, liquid 4
    np.testing.assert_array_equal(state.fluid_densities(), np.full(model.fluid_count, model.fluid_density))
    np.testing.assert_array_equal(state.fluid_pressures(), np.zeros(model.fluid_count))
    np.testing.assert_allclose(state.rigid_x.to_numpy()[0], [0.15, 0.1, 0.03], atol=1e-12)
    np.testing.assert_array_equal(state.rigid_v.to_numpy()[0], [0.0, 0.0, 0.0])
