"""The rigid kind's builder part: `add_rigid_body`. Each body's mass properties come from its shape and
density (shapes.py) and are turned into the frame the dynamics runs in: the centre of mass and the
principal axes of inertia (as MuJoCo's inertial frame), so that the inertia tensor is diagonal there."""

from __future__ import annotations

import numpy as np

from ... import validate
from ...collision.motion import RigidMotion
from ...errors import ParameterError
from ...shapes import Shape
from .geometry import contact_geometry
from .quaternion import matrix_to_quat, quat_product, quat_to_matrix

MAX_RIGID_BODIES = 1 << 20


def principal_frame(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(moments (3,) ascending [kg m^2], rotation (3,3) whose columns are the principal axes in the
    shape's frame, a proper rotation) of a symmetric inertia tensor."""
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    return moments, axes


def unit_quaternion(name: str, value) -> np.ndarray:
    """An orientation (x, y, z, w), normalised; refused when not finite or far from unit length."""
    q = validate.finite_array(name, np.asarray(value, dtype=np.float64).reshape(-1))
    if q.shape != (4,):
        raise ParameterError(f"{name} must be a quaternion (x, y, z, w), got {value!r}")
    n = float(np.linalg.norm(q))
    if not 0.9 < n < 1.1:
        raise ParameterError(f"{name} must be a unit quaternion (x, y, z, w), got {value!r} (norm {n:.4g})")
    return q / n


class RigidBuilder:
    """Builder methods of the rigid kind: add_rigid_body."""

    def _init_rigid(self) -> None:
        self._rigid: list[dict] = []
        self._rigid_contacts: dict | None = None
        self.set_rigid_contacts()  # the defaults: set_rigid_contacts's signature holds them once

    def set_rigid_contacts(
        self,
        *,
        enabled: bool = True,
        iterations: int = 8,
        relax_iterations: int = 4,
        beta: float = 0.2,
        slop: float = 0.005,
        max_push: float = 3.0,
        bounce_speed: float = 1.0,
        capacity: int | None = None,
        manifold_points: int = 0,
    ) -> None:
        """Options of the contacts between rigid bodies and with colliders (on by default):
        iterations and relax_iterations: sweeps of the solver per step (biased, then relaxed); beta in
        (0, 1]: the fraction of a penetration past `slop` [m] pushed out per step, at most `max_push`
        [m/s]; bounce_speed [m/s]: slower approaches do not bounce; capacity: contacts held per step
        (default from the bodies' points and the colliders); manifold_points: 0 keeps every corner found
        per pair of convex parts (up to 16 for two boxes; on a stack, each corner twice, once from each
        side), 4 keeps the four that span the contact polygon most, as Jolt and Bullet do: about half the
        contacts of a pile and up to a third less time per step (a 1000-box bin), but a 1:100
        heavy-on-light stack no longer stands at the default sweeps (docs/guide/rigid.md).
        enabled=False: bodies pass through."""
        if not validate.flag("enabled", enabled):
            self._rigid_contacts = None
            return
        self._rigid_contacts = dict(
            iterations=validate.count("iterations", iterations, 1, 10_000),
            relax_iterations=validate.count("relax_iterations", relax_iterations, 0, 10_000),
            beta=validate.in_range("beta", beta, 0.0, 1.0),
            slop=validate.non_negative("slop", slop),
            max_push=validate.non_negative("max_push", max_push),
            bounce_speed=validate.non_negative("bounce_speed", bounce_speed),
            capacity=None if capacity is None else validate.count("capacity", capacity, 1, 1 << 24),
            manifold_points=validate.count("manifold_points", manifold_points, 0, 4),
        )
        if self._rigid_contacts["manifold_points"] not in (0, 4):
            raise ParameterError(f"manifold_points must be 0 (keep all) or 4, got {manifold_points!r}")

    @property
    def rigid_count(self) -> int:
        """Rigid bodies added so far."""
        return len(self._rigid)

    def add_rigid_body(
        self,
        shape: Shape,
        *,
        density: float = 1000.0,
        position=(0.0, 0.0, 0.0),
        orientation=(0.0, 0.0, 0.0, 1.0),
        velocity=(0.0, 0.0, 0.0),
        angular_velocity=(0.0, 0.0, 0.0),
        kinematic: bool = False,
        friction: float = 0.5,
        restitution: float = 0.0,
        linear_damping: float = 0.0,
        angular_damping: float = 0.0,
        motion=None,
    ) -> int:
        """Add a rigid body and return its index.

        shape: from `ta.shapes` (Sphere, Box, Capsule, ConvexHull, Mesh), in the body's frame;
        density [kg/m^3] (mass and inertia follow from it exactly); position [m] and orientation
        (x, y, z, w) place the shape's frame in the world; velocity [m/s] of the centre of mass and
        angular_velocity [rad/s], both in world axes (as Newton, Bullet and Jolt take them);
        kinematic: the body moves at its velocities, unmoved by forces (infinite mass); friction: its
        Coulomb coefficient (a contact takes the geometric mean of its two sides', as Box2D and Jolt);
        restitution in [0, 1] (a contact takes the larger of its two sides'); linear_damping and
        angular_damping [1/s]: drag dv/dt = -c v and dw/dt = -c w, integrated exactly over each step
        (v e^(-c h), as Jolt and Bullet damp); motion: a RigidMotion
        (keyframes) that carries the body, placed as given, along: its frame is at R(t) p + T(t) (as a
        collider's), the body kinematic and its velocities the keyframes' (it pushes, nothing pushes it)."""
        if not isinstance(shape, Shape):
            raise ParameterError(f"shape must be one of ta.shapes (Sphere, Box, ...), got {shape!r}")
        if len(self._rigid) >= MAX_RIGID_BODIES:
            raise ParameterError(f"add_rigid_body: at most {MAX_RIGID_BODIES} rigid bodies")
        if motion is not None and not isinstance(motion, RigidMotion):
            raise ParameterError(f"motion must be a RigidMotion or None, got {motion!r}")
        props = shape.mass_properties(validate.positive("density", density))
        moments, axes = principal_frame(props.inertia)
        if moments[0] <= 1e-12 * moments[2]:
            raise ParameterError(f"shape {shape.kind!r} has a degenerate inertia (moments {moments})")
        q_shape = unit_quaternion("orientation", orientation)
        q_principal = matrix_to_quat(axes)  # principal frame -> shape frame
        origin = np.asarray(validate.vec3("position", position))
        self._rigid.append(
            dict(
                shape=shape,
                density=float(density),
                mass=props.mass,
                com=props.com,
                inertia=props.inertia,
                moments=moments,
                principal=q_principal,
                x=origin + quat_to_matrix(q_shape) @ props.com,
                q=quat_product(q_shape, q_principal),
                v=np.asarray(validate.vec3("velocity", velocity)),
                w=np.asarray(validate.vec3("angular_velocity", angular_velocity)),
                kinematic=validate.flag("kinematic", kinematic) or motion is not None,
                motion=motion,
                friction=validate.non_negative("friction", friction),
                restitution=validate.in_range("restitution", restitution, 0.0, 1.0),
                damping=(
                    validate.non_negative("linear_damping", linear_damping),
                    validate.non_negative("angular_damping", angular_damping),
                ),  # fmt: skip
                geometry=contact_geometry(shape, props.com, axes),
            )
        )
        return len(self._rigid) - 1

    def rigid_arrays(self) -> dict:
        """The rigid kind's arrays for finalize (init_model's keyword arguments)."""
        return dict(bodies=list(self._rigid), contacts=self._rigid_contacts)

    def rigid_settings(self) -> dict:
        """run.json's record of the bodies (shape, density, mass, kinematic)."""
        return {
            "rigid_bodies": [
                {
                    **b["shape"].settings(),
                    **{k: b[k] for k in ("density", "mass", "kinematic")},
                    **({"motion": b["motion"].settings()} if b["motion"] is not None else {}),
                }  # fmt: skip
                for b in self._rigid
            ]
        }
