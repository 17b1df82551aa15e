"""Colliders (signed-distance shapes as `@ti.func`s) and the collision response applied after each step."""

from .colliders import ColliderPlane, ColliderSolidBox, ColliderSphere, CollisionMode
from .motion import RigidMotion
from .response import collide

__all__ = ["CollisionMode", "ColliderPlane", "ColliderSolidBox", "ColliderSphere", "RigidMotion", "collide"]
