"""Errors raised by taichi_anim: bad parameters and diverging simulations."""


class ParameterError(ValueError):
    """A parameter has an invalid value; the message names the parameter and the value."""


class DivergenceError(RuntimeError):
    """A step produced non-finite positions or velocities; the message says which step and how many."""
