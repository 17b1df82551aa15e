"""Particle systems after Reeves, "Particle Systems — a Technique for Modeling a Class of Fuzzy
Objects" (SIGGRAPH 1983): emitters with rates, lifetimes and colour over life, in a fixed-capacity pool."""

from .emitters import Emitter, EmitterShape

__all__ = ["Emitter", "EmitterShape"]
