"""Kinds of body, one folder each (bodies/base.py describes the protocol). `KINDS` is the registration:
the Builder, Model and State inherit every kind's parts and call its hooks in this order."""

from .base import BodyKind
from .fluid import FLUID
from .particles import PARTICLES
from .rigid import RIGID

KINDS: tuple[BodyKind, ...] = (PARTICLES, RIGID, FLUID)

BUILDER_PARTS = tuple(k.builder for k in KINDS)
MODEL_PARTS = tuple(k.model for k in KINDS)
STATE_PARTS = tuple(k.state for k in KINDS)

__all__ = ["BUILDER_PARTS", "KINDS", "MODEL_PARTS", "STATE_PARTS", "BodyKind"]
