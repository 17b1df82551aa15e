"""Force terms. Pointwise terms act on each particle alone and provide, as `@ti.func`s,
`force(i, m, x, v, t) -> vec3` and `jacobian(i, m, x, v, t) -> (df/dx, df/dv)` (3x3 each);
integrators fuse them into their kernels at compile time, so a scene compiles only the terms it has.
A term whose Jacobian is identically zero says so with `has_jacobian = False`. Springs (springs.py)
couple particles and gather over fields instead."""

from .anchor_spring import AnchorSpring
from .drag import Drag
from .gravity import Gravity

__all__ = ["AnchorSpring", "Drag", "Gravity"]
