"""Colour by an attribute: a perceptual colormap and its legend.

The map is viridis (van der Walt & Smith, 2015; released as CC0): its lightness rises monotonically and
evenly from one end to the other, so equal steps of the value read as equal steps of colour, also in
greyscale and for the common forms of colour blindness. It is stored as 17 samples, interpolated
linearly (a sample spacing of 1/16 keeps the interpolation within 1/255 of the full table).

The legend is a colour bar with the attribute's name and unit and the ends of its range, drawn with
Pillow onto the finished picture (imported inside the function)."""

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError

VIRIDIS = np.array(
    [
        (0.2670, 0.0049, 0.3294),
        (0.2823, 0.0950, 0.4173),
        (0.2788, 0.1755, 0.4834),
        (0.2590, 0.2515, 0.5247),
        (0.2297, 0.3224, 0.5457),
        (0.1994, 0.3876, 0.5546),
        (0.1727, 0.4488, 0.5579),
        (0.1490, 0.5081, 0.5573),
        (0.1276, 0.5669, 0.5506),
        (0.1206, 0.6258, 0.5335),
        (0.1579, 0.6838, 0.5017),
        (0.2461, 0.7389, 0.4520),
        (0.3692, 0.7889, 0.3829),
        (0.5160, 0.8312, 0.2943),
        (0.6785, 0.8637, 0.1895),
        (0.8456, 0.8873, 0.0997),
        (0.9932, 0.9062, 0.1439),
    ]
)

# What `color_by` can name: the unit shown in the legend, and how a Points item gives the value.
ATTRIBUTES = {"speed": "m/s", "height": "m", "age": "s"}


def colormap(values, lo: float, hi: float) -> np.ndarray:
    """(N,) values -> (N,3) RGB in [0,1]: lo maps to the dark (violet) end, hi to the light (yellow) end,
    values outside [lo, hi] are clamped. lo == hi maps everything to the middle."""
    x = np.asarray(values, dtype=np.float64).reshape(-1)
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi < lo:
        raise ParameterError(f"color range must be finite with lo <= hi, got ({lo}, {hi})")
    s = np.full_like(x, 0.5) if hi == lo else np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    s = np.nan_to_num(s, nan=0.0)
    pos = s * (len(VIRIDIS) - 1)
    k = np.minimum(pos.astype(np.int64), len(VIRIDIS) - 2)
    w = (pos - k)[:, None]
    return (1.0 - w) * VIRIDIS[k] + w * VIRIDIS[k + 1]


@dataclass(frozen=True)
class ColorBy:
    """Colour points by `attribute` ("speed" [m/s], "height" [m] or "age" [s]) over the range (lo, hi)
    [in the attribute's unit]; None for an end takes it from the frame (a video should fix both, so that
    a colour means the same value in every frame)."""

    attribute: str
    lo: float | None = None
    hi: float | None = None

    def __post_init__(self):
        if self.attribute not in ATTRIBUTES:
            raise ParameterError(f"color_by must be one of {sorted(ATTRIBUTES)}, got {self.attribute!r}")

    @property
    def unit(self) -> str:
        """The attribute's unit ("m/s", "m", "s")."""
        return ATTRIBUTES[self.attribute]

    def values(self, positions, attributes: dict) -> np.ndarray | None:
        """The attribute's (N,) values for points at `positions` (N,3) with per-point `attributes`
        ("velocity" (N,3), "age" (N,)), or None when the points do not carry it."""
        if self.attribute == "height":
            return np.asarray(positions)[:, 1]
        if self.attribute == "speed":
            v = attributes.get("velocity")
            return None if v is None else np.linalg.norm(np.asarray(v), axis=1)
        age = attributes.get("age")
        return None if age is None else np.asarray(age, dtype=np.float64).reshape(-1)

    def range(self, values) -> tuple[float, float]:
        """(lo, hi): the fixed ends, the others from `values` (0..1 if there are none)."""
        v = np.asarray(values, dtype=np.float64)
        v = v[np.isfinite(v)]
        lo = self.lo if self.lo is not None else (float(v.min()) if len(v) else 0.0)
        hi = self.hi if self.hi is not None else (float(v.max()) if len(v) else 1.0)
        return lo, max(hi, lo)

    @property
    def label(self) -> str:
        """The legend's title, e.g. "speed [m/s]"."""
        return f"{self.attribute} [{self.unit}]"


def draw_legend(image: np.ndarray, *, label: str, lo: float, hi: float) -> np.ndarray:
    """Return a copy of `image` (H, W, 3) uint8 with a vertical colour bar at its right edge: the top is
    `hi`, the bottom `lo`, with those values and `label` (the attribute and its unit) written beside it."""
    from PIL import Image, ImageDraw, ImageFont

    h, w = image.shape[:2]
    pic = Image.fromarray(np.ascontiguousarray(image)).convert("RGBA")
    panel = Image.new("RGBA", pic.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(panel)
    size = max(10, h // 36)
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has one fixed-size default font
        font = ImageFont.load_default()
    bar_h, bar_w = max(int(0.4 * h), 8), max(w // 60, 6)
    x1 = w - max(w // 40, 4)
    x0 = x1 - bar_w
    y0 = (h - bar_h) // 2
    # A translucent white panel under the bar and its labels keeps them legible over the scene.
    left = x0 - 6 - max(draw.textlength(f"{v:.3g}", font=font) for v in (lo, hi))
    left = min(left, x1 - draw.textlength(label, font=font)) - 4
    draw.rectangle(
        [left, max(y0 - 2 * size - 4, 0), w - 1, min(y0 + bar_h + 4, h - 1)], fill=(255, 255, 255, 170)
    )
    pic = Image.alpha_composite(pic, panel).convert("RGB")
    draw = ImageDraw.Draw(pic)
    ramp = colormap(np.linspace(hi, lo, bar_h), lo, hi) if hi > lo else colormap(np.zeros(bar_h), 0, 1)
    bar = np.repeat((ramp * 255.0 + 0.5).astype(np.uint8)[:, None, :], bar_w, axis=1)
    pic.paste(Image.fromarray(bar), (x0, y0))
    draw.rectangle([x0 - 1, y0 - 1, x1, y0 + bar_h], outline=(40, 40, 40))
    ink = (20, 20, 20)
    for text, y in ((f"{hi:.3g}", y0), (f"{lo:.3g}", y0 + bar_h - size)):
        tw = draw.textlength(text, font=font)
        draw.text((x0 - 4 - tw, y), text, fill=ink, font=font)
    tw = draw.textlength(label, font=font)
    draw.text((min(x1 - tw, w - tw - 2), max(y0 - 2 * size, 0)), label, fill=ink, font=font)
    return np.asarray(pic)


def legend_box(image_shape) -> tuple[int, int, int, int]:
    """(row0, row1, col0, col1) of the colour bar that draw_legend paints into an image of this shape."""
    h, w = image_shape[:2]
    bar_h, bar_w = max(int(0.4 * h), 8), max(w // 60, 6)
    x1 = w - max(w // 40, 4)
    y0 = (h - bar_h) // 2
    return y0, y0 + bar_h, x1 - bar_w, x1
