"""Rendering a scene's frame content (content.py: Points, Mesh, Lines) with the rasterizer.

Points with radii are balls of those radii (hard spheres), points without are balls of `point_radius`;
meshes are smooth-shaded from their vertex normals, cloth with a back colour of its own (two-sided);
lines are drawn in their colour. Colour by an attribute replaces the points' colours by the colormap
and adds its legend."""

import numpy as np

from ..content import Lines, Mesh, Points
from .camera import Camera
from .colormap import ColorBy, colormap, draw_legend
from .image import BACKGROUND, DrawList, Lighting, render_image

WHITE = np.ones(3)


def back_color(front) -> np.ndarray:
    """The back side of a cloth: its front colour lightened halfway to white, so folds read clearly."""
    return 0.5 * np.asarray(front, dtype=np.float64) + 0.5 * WHITE


def items_draw_list(items, *, point_radius: float, color_by: ColorBy | None = None):
    """(DrawList, legend (label, lo, hi) or None) for content items."""
    draw = DrawList()
    points = [i for i in items if isinstance(i, Points) and len(i.positions)]
    legend = None
    values = None
    if color_by is not None:
        values = [color_by.values(p.positions, p.attributes) for p in points]
        known = [v for v in values if v is not None]
        if known:
            lo, hi = color_by.range(np.concatenate(known))
            legend = (color_by.label, lo, hi)
    for item in items:
        if isinstance(item, Mesh) and len(item.triangles):
            back = back_color(item.color) if item.role == "cloth" else None
            draw.add_mesh(
                item.vertices, item.triangles, normals=item.normals, colors=item.color, back_color=back
            )
        elif isinstance(item, Lines) and len(item.segments):
            draw.add_lines(item.points[item.segments[:, 0]], item.points[item.segments[:, 1]], item.color)
    for k, p in enumerate(points):
        radius = point_radius if p.radii is None else p.radii
        colors = p.colors
        if legend is not None and values[k] is not None:
            colors = colormap(values[k], legend[1], legend[2])
        draw.add_spheres(p.positions, radius, colors)
    return draw, legend


def render_items(
    items,
    camera: Camera,
    *,
    point_radius: float,
    color_by: ColorBy | str | None = None,
    background=BACKGROUND,
    samples: int = 2,
    lighting: Lighting | None = None,
    line_width_px: float = 1.0,
) -> np.ndarray:
    """The picture of content items seen by `camera`, (H, W, 3) uint8 (row 0 at the top).

    point_radius [m]: the radius of points without radii; color_by: a ColorBy, an attribute name
    ("speed", "height", "age"; range from the frame) or None (the items' own colours); a legend is
    drawn when some points carry the attribute."""
    if isinstance(color_by, str):
        color_by = ColorBy(color_by)
    draw, legend = items_draw_list(items, point_radius=point_radius, color_by=color_by)
    img = render_image(
        draw, camera, background=background, samples=samples, lighting=lighting, line_width_px=line_width_px
    )
    if legend is not None:
        img = draw_legend(img, label=legend[0], lo=legend[1], hi=legend[2])
    return img
