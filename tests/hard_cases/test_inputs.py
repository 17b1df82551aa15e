"""Hard cases for input holes: each bad input a new user might pass (NaN or inf where a number is needed,
a value that is finite in float64 but overflows the float32 fields, a fractional index, an array of the
wrong shape, a seed the 32-bit generator cannot hold, None, a string or a bool for a number) raises
ParameterError at the call that received it (or at finalize(), where the precision is known), and the
message names the parameter and the value."""

import numpy as np
import pytest

import taichi_anim as ta

NAN, INF = float("nan"), float("inf")
MESH = (np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1]]), [[0, 1, 2]])


def two_particles() -> ta.Builder:
    b = ta.Builder()
    b.add_particles([[0.0, 0, 0], [1.0, 0, 0]])
    return b


def finalized(*adds):
    """A builder with one particle, the given additions, finalized (where precision checks run)."""
    b = ta.Builder()
    b.add_particles([[0.0, 0, 0]])
    for add in adds:
        add(b)
    return b.finalize()


def cloth(**kw):
    return ta.Builder().add_cloth_grid(resolution=(3, 3), **kw)


def membrane(**kw):
    b = ta.Builder()
    b.add_force_membrane(b.add_cloth_grid(resolution=(3, 3)), youngs_modulus=1e3, **kw)


def aero(**kw):
    b = ta.Builder()
    b.add_force_aerodynamics(b.add_cloth_grid(resolution=(3, 3)), **kw)


# (case id, call, substrings the message must contain: the parameter's name and the value)
CALL_TIME = [
    ("plane offset NaN", lambda: two_particles().add_collider_plane((0, 1, 0), NAN), ["offset", "nan"]),
    ("plane offset inf", lambda: two_particles().add_collider_plane((0, 1, 0), INF), ["offset", "inf"]),
    ("plane offset None", lambda: two_particles().add_collider_plane((0, 1, 0), None), ["offset", "None"]),
    ("plane offset str", lambda: two_particles().add_collider_plane((0, 1, 0), "1"), ["offset", "'1'"]),
    ("plane normal NaN", lambda: two_particles().add_collider_plane((NAN, 1, 0)), ["normal", "nan"]),
    ("plane normal inf", lambda: two_particles().add_collider_plane((0, INF, 0)), ["normal", "inf"]),
    ("plane normal zero", lambda: two_particles().add_collider_plane((0, 0, 0)), ["normal", "(0, 0, 0)"]),
    (
        "plane restitution NaN",
        lambda: two_particles().add_collider_plane(restitution=NAN),
        ["restitution", "nan"],
    ),
    ("plane friction None", lambda: two_particles().add_collider_plane(friction=None), ["friction", "None"]),
    ("sphere center NaN", lambda: two_particles().add_collider_sphere((0, NAN, 0), 1.0), ["center", "nan"]),
    ("sphere radius inf", lambda: two_particles().add_collider_sphere((0, 0, 0), INF), ["radius", "inf"]),
    ("sphere radius str", lambda: two_particles().add_collider_sphere((0, 0, 0), "1"), ["radius", "'1'"]),
    ("box lo NaN", lambda: two_particles().add_collider_box((NAN, 0, 0), (1, 1, 1)), ["lo", "nan"]),
    ("box hi inf", lambda: two_particles().add_collider_box((0, 0, 0), (1, INF, 1)), ["hi", "inf"]),
    (
        "box friction NaN",
        lambda: two_particles().add_collider_box((0, 0, 0), (1, 1, 1), friction=NAN),
        ["friction", "nan"],
    ),
    (
        "mesh thickness NaN",
        lambda: two_particles().add_collider_mesh(MESH, thickness=NAN),
        ["thickness", "nan"],
    ),
    (
        "mesh thickness None",
        lambda: two_particles().add_collider_mesh(MESH, thickness=None),
        ["thickness", "None"],
    ),
    (
        "mesh restitution inf",
        lambda: two_particles().add_collider_mesh(MESH, restitution=INF),
        ["restitution", "inf"],
    ),
    ("pinned 1.7", lambda: cloth(pinned=[1.7]), ["pinned", "1.7"]),
    ("pinned NaN", lambda: cloth(pinned=[0, NAN]), ["pinned", "nan"]),
    ("pinned bool", lambda: cloth(pinned=[True]), ["pinned", "True"]),
    ("pinned str", lambda: cloth(pinned=["0"]), ["pinned", "'0'"]),
    ("pinned out of range", lambda: cloth(pinned=[9]), ["pinned", "9"]),
    ("spring pair 0.5", lambda: two_particles().add_springs([[0, 0.5]], stiffness=1.0), ["pairs", "0.5"]),
    ("spring pair NaN", lambda: two_particles().add_springs([[0, NAN]], stiffness=1.0), ["pairs", "nan"]),
    (
        "anchor particle 1.5",
        lambda: two_particles().add_force_anchor_spring(1.5, (0, 0, 0), stiffness=1.0),
        ["particle", "1.5"],
    ),
    (
        "anchor particle None",
        lambda: two_particles().add_force_anchor_spring(None, (0, 0, 0), stiffness=1.0),
        ["particle", "None"],
    ),
    (
        "mass of wrong length",
        lambda: ta.Builder().add_particles(np.zeros((3, 3)), mass=[1.0, 2.0]),
        ["mass", "(3,)", "(2,)"],
    ),
    (
        "mass of wrong rank",
        lambda: ta.Builder().add_particles(np.zeros((3, 3)), mass=np.ones((3, 1))),
        ["mass", "(3,)", "(3, 1)"],
    ),
    ("mass str", lambda: ta.Builder().add_particles(np.zeros((3, 3)), mass="1"), ["mass", "'1'"]),
    (
        "radius of wrong length",
        lambda: ta.Builder().add_particles(np.zeros((3, 3)), radius=[0.1] * 4),
        ["radius", "(3,)", "(4,)"],
    ),
    (
        "velocity of wrong shape",
        lambda: ta.Builder().add_particles(np.zeros((3, 3)), np.zeros((2, 3))),
        ["v", "(3, 3)", "(2, 3)"],
    ),
    (
        "stiffness per spring, wrong length",
        lambda: two_particles().add_springs([[0, 1]], stiffness=[1.0, 2.0]),
        ["stiffness", "(1,)", "(2,)"],
    ),
    (
        "damping None",
        lambda: two_particles().add_springs([[0, 1]], stiffness=1.0, damping=None),
        ["damping", "None"],
    ),
    ("positions str", lambda: ta.Builder().add_particles("abc"), ["x", "abc"]),
    ("thickness bool", lambda: cloth(thickness=True), ["thickness", "True"]),
    ("resolution None", lambda: ta.Builder().add_cloth_grid(resolution=(None, 3)), ["resolution", "None"]),
    ("drag coefficient str", lambda: ta.Builder().add_force_drag("0.1"), ["coefficient", "'0.1'"]),
    ("gravity str", lambda: ta.Builder().add_force_gravity("down"), ["g", "down"]),
    (
        "emitter colour above 1",
        lambda: ta.Builder().add_particle_emitter(capacity=8, rate=1, color_start=(5, 0, 0)),
        ["color_start", "5"],
    ),
    (
        "emitter capacity 1e12",
        lambda: ta.Builder().add_particle_emitter(capacity=10**12, rate=1),
        ["capacity", "1000000000000"],
    ),
    ("aerodynamics unknown option", lambda: aero(bogus=1), ["aerodynamics", "bogus"]),
    ("aerodynamics gust NaN", lambda: aero(gust_amplitude=NAN), ["gust_amplitude", "nan"]),
    ("membrane damping NaN", lambda: membrane(damping=NAN), ["damping", "nan"]),
    ("continuous 'no'", lambda: two_particles().add_sphere_contacts(continuous="no"), ["continuous", "'no'"]),
    (
        "solid 'yes'",
        lambda: two_particles().add_collider_box((0, 0, 0), (1, 1, 1), solid="yes"),
        ["solid", "'yes'"],
    ),
    ("init with an unknown Taichi option", lambda: ta.init("cpu", bogus=1), ["bogus"]),
]


def failures(cases) -> list[str]:
    """Each case whose call does not raise ParameterError with every expected word in its message.
    (One test runs the whole table: a test of its own would pay Taichi's start-up per case.)"""
    bad = []
    for case, call, words in cases:
        try:
            call()
        except ta.ParameterError as e:
            missing = [w for w in words if w not in str(e)]
            if missing:
                bad.append(f"{case}: {missing} not in {str(e)!r}")
        except Exception as e:  # noqa: BLE001 - a raw NumPy/Taichi error is the failure being looked for
            bad.append(f"{case}: {type(e).__name__}: {e}")
        else:
            bad.append(f"{case}: no error")
    return bad


def test_bad_input_is_named_where_it_is_given():
    """Pass: for every case of CALL_TIME, ParameterError, and its message contains the parameter's name
    and the offending value (or, for a shape, the expected and the given shape)."""
    assert failures(CALL_TIME) == []


MOTION_FAR = dict(times=[0.0, 1.0], translations=[[0, 0, 0], [1e300, 0, 0]])
FINALIZE_F32 = [
    ("position 1e300", lambda: finalized(lambda b: b.add_particles([[1e300, 0, 0]])), ["x", "1e+300"]),
    (
        "velocity -1e300",
        lambda: finalized(lambda b: b.add_particles([[0, 0, 0]], [[0, -1e300, 0]])),
        ["v", "-1e+300"],
    ),
    (
        "mass 1e300",
        lambda: finalized(lambda b: b.add_particles([[1.0, 0, 0]], mass=1e300)),
        ["mass", "1e+300"],
    ),
    (
        "mass 1e-45 (rounds to 0: pinned)",
        lambda: finalized(lambda b: b.add_particles([[1.0, 0, 0]], mass=1e-45)),
        ["mass", "1e-45"],
    ),
    (
        "radius 1e39",
        lambda: finalized(lambda b: b.add_particles([[1.0, 0, 0]], radius=1e39)),
        ["radius", "1e+39"],
    ),
    (
        "cloth origin 1e300",
        lambda: finalized(lambda b: b.add_cloth_grid(origin=(0, 1e300, 0), resolution=(2, 2))),
        ["x", "1e+300"],
    ),
    (
        "stiffness 1e300",
        lambda: finalized(
            lambda b: b.add_particles([[1.0, 0, 0]]), lambda b: b.add_springs([[0, 1]], stiffness=1e300)
        ),
        ["stiffness", "1e+300"],
    ),
    (
        "plane offset 1e300",
        lambda: finalized(lambda b: b.add_collider_plane((0, 1, 0), 1e300)),
        ["offset", "1e+300"],
    ),
    (
        "sphere radius 1e300",
        lambda: finalized(lambda b: b.add_collider_sphere((0, 0, 0), 1e300)),
        ["radius", "1e+300"],
    ),
    ("gravity 1e300", lambda: finalized(lambda b: b.add_force_gravity((0, -1e300, 0))), ["g", "-1e+300"]),
    (
        "anchor 1e300",
        lambda: finalized(lambda b: b.add_force_anchor_spring(0, (1e300, 0, 0), stiffness=1.0)),
        ["anchor_springs", "1e+300"],
    ),
    (
        "moving collider 1e300",
        lambda: finalized(
            lambda b: b.add_collider_sphere((0, 0, 0), 1.0, motion=ta.RigidMotion(**MOTION_FAR))
        ),
        ["translations", "1e+300"],
    ),
    (
        "mesh collider vertex 1e300",
        lambda: finalized(lambda b: b.add_collider_mesh((MESH[0] * [1, 1, 1e300], MESH[1]))),
        ["vertices", "1e+300"],
    ),
    (
        "emitter speed 1e300",
        lambda: finalized(lambda b: b.add_particle_emitter(capacity=4, rate=1, speed=1e300)),
        ["speed", "1e+300"],
    ),
]


def test_values_that_overflow_float32_are_named_at_finalize():
    """Pass: under precision="f32", for every case of FINALIZE_F32 finalize() raises ParameterError naming
    the parameter and the value that would become inf (or 0) in a float32 field, and says "float32"."""
    ta.init("cpu", precision="f32")
    assert failures([(case, call, [*words, "float32"]) for case, call, words in FINALIZE_F32]) == []


def test_float64_holds_what_float32_cannot():
    """Pass: under precision="f64" the same 1e300 position and 1e-45 mass are accepted and read back
    exactly (the limit is the precision's own)."""
    ta.init("cpu", precision="f64")
    b = ta.Builder()
    b.add_particles([[1e300, 0, 0], [0, 0, 0]], mass=[1e-45, 1.0])
    state = b.finalize().state()
    assert state.positions()[0, 0] == 1e300


@pytest.mark.parametrize("seed", [2**32, 2**32 + 7, 2**64, -1, -(2**32), 1.5, None, "7", True])
def test_seeds_the_generator_cannot_hold_are_rejected(seed):
    """Pass: a seed outside [0, 2**32) (which the kernels' 32-bit hash would cut to a smaller seed's
    run: 2**32 + 7 repeated seed 7), a negative, fractional or non-integer seed raises ParameterError
    naming `seed` and the value."""
    with pytest.raises(ta.ParameterError) as err:
        two_particles().finalize(seed=seed)
    assert "seed" in str(err.value) and repr(seed) in str(err.value)


def test_largest_seed_is_accepted():
    """Pass: 2**32 - 1 and a NumPy integer seed are valid."""
    assert two_particles().finalize(seed=2**32 - 1).seed == 2**32 - 1
    assert two_particles().finalize(seed=np.uint32(5)).seed == 5


@pytest.mark.parametrize("name", ["implicit_euler", "rk45", "symplectic_euler"])
def test_unknown_integrator_option_names_it(name):
    """Pass: an option the method does not take is a ParameterError naming the method and the option,
    not a raw TypeError."""
    with pytest.raises(ta.ParameterError, match=rf"{name}.*bogus"):
        ta.make_integrator(name, bogus=1)
