"""Demo scenes, by name: what `taichi-anim demo NAME` runs."""

from .. import validate
from . import (
    blobs,
    cloth,
    dam_break,
    dominoes,
    drape,
    flag,
    fountain,
    layers,
    moving_mesh,
    pile,
    pour,
    rigid_cloth,
    spheres,
    tablecloth,
)
from .base import Scene

SCENES = {
    "fountain": fountain,
    "blobs": blobs,
    "spheres": spheres,
    "cloth": cloth,
    "drape": drape,
    "flag": flag,
    "layers": layers,
    "tablecloth": tablecloth,
    "moving_mesh": moving_mesh,
    "dominoes": dominoes,
    "pile": pile,
    "rigid_cloth": rigid_cloth,
    "dam_break": dam_break,
    "pour": pour,
}
DEFAULT_SCENE = "fountain"


def make_scene(name: str, **options) -> Scene:
    """Build the scene `name` (see SCENES) with its keyword options."""
    validate.choice("demo", name, SCENES)
    return SCENES[name].build(**options)


def describe() -> dict[str, str]:
    """Scene name -> one-line description (from each module's docstring)."""
    return {n: (m.__doc__ or "").strip().split("\n")[0] for n, m in SCENES.items()}


__all__ = ["DEFAULT_SCENE", "SCENES", "Scene", "describe", "make_scene"]
