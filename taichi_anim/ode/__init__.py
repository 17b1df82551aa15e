"""General ODE systems u' = F(t, u) of any dimension, batched over many independent systems: the
engine's time-integration methods (explicit Euler, symplectic Euler, midpoint, RK4, Dormand–Prince
RK45, step doubling, implicit Euler with Newton) for any state, not only particles.

    system = ta.ode.System(f, dim=2)              # f: @ti.func (t, u) -> ti.Vector
    system = ta.ode.System.numpy(f_np, dim=2)     # f_np: (t (m,), U (m, dim)) -> (m, dim)
    result = ta.ode.solve(system, u0, (0.0, T), method="rk4", dt=1e-3)
    result.u, result.u_eval, result.stats()
"""

from .solve import METHODS, Result, solve
from .system import System

__all__ = ["METHODS", "Result", "System", "solve"]
