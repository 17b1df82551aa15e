"""Headless rendering: a software rasterizer in Taichi with a depth buffer (spheres at their true radius,
smooth-shaded meshes, lines), colour by an attribute with a legend, and MP4/GIF video.

    from taichi_anim.render import Camera, fit_camera, render_png
"""

from .camera import Camera, fit_camera
from .colormap import ColorBy, colormap, draw_legend
from .image import DrawList, Lighting, render_image, render_png, write_png
from .items import render_items
from .video import VideoWriter

__all__ = [
    "Camera",
    "ColorBy",
    "DrawList",
    "Lighting",
    "VideoWriter",
    "colormap",
    "draw_legend",
    "fit_camera",
    "render_image",
    "render_items",
    "render_png",
    "write_png",
]
