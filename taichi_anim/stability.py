"""Stability guard: the model's highest frequency against the explicit method's stability region."""


def guard(stepper, state, dt: float) -> None:
    """Check a step of dt [s] against the stability limit of the stepper's method (placeholder)."""
