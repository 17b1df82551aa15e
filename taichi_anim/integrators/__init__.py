"""Time integrators for x' = v, v' = M^-1 f(x, v, t): one `step(model, state, dt)` each."""

from __future__ import annotations

from .. import validate
from ..errors import ParameterError
from .adaptive import IntegratorAdaptive
from .base import Integrator
from .implicit_euler import IntegratorImplicitEuler
from .rk45 import IntegratorRK45
from .runge_kutta import (
    IntegratorExplicitEuler,
    IntegratorMidpoint,
    IntegratorRK4,
    IntegratorRungeKutta,
    Tableau,
)
from .symplectic_euler import IntegratorSymplecticEuler

INTEGRATORS = {
    "explicit_euler": IntegratorExplicitEuler,
    "symplectic_euler": IntegratorSymplecticEuler,
    "midpoint": IntegratorMidpoint,
    "rk4": IntegratorRK4,
    "rk45": IntegratorRK45,
    "implicit_euler": IntegratorImplicitEuler,
    "adaptive": IntegratorAdaptive,
}


def make_integrator(name: str, **options) -> Integrator:
    """An integrator by name (see INTEGRATORS) with keyword options; unknown names raise ParameterError."""
    validate.choice("integrator", name, INTEGRATORS)
    try:
        return INTEGRATORS[name](**options)
    except TypeError as e:  # an option this method does not take: name it instead of a raw TypeError
        if "unexpected keyword argument" not in str(e):
            raise
        bad = str(e).split("argument")[-1].strip()
        raise ParameterError(f"integrator {name!r} has no option {bad} (got {options!r})") from None


__all__ = [
    "INTEGRATORS",
    "Integrator",
    "IntegratorAdaptive",
    "IntegratorExplicitEuler",
    "IntegratorImplicitEuler",
    "IntegratorMidpoint",
    "IntegratorRK4",
    "IntegratorRK45",
    "IntegratorRungeKutta",
    "IntegratorSymplecticEuler",
    "Tableau",
    "make_integrator",
]
