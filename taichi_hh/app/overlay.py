"""Labels on frames: a header band with the time, a phase legend or a colour
bar, and the box's walls as a grey frame around the particles.

Text is rasterised by FreeType through matplotlib's ``ft2font`` binding (the
DejaVu Sans font matplotlib ships), a few milliseconds per label, so frames
stay cheap: no figure, no canvas.  Everything here works on numpy u8 images.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: grey of the walls' frame and of the header's rule
FRAME_GREY = (150, 150, 150)
TEXT_COLOUR = (30, 30, 30)


@lru_cache(maxsize=4)
def _font(size_px: int):
    from matplotlib import font_manager
    from matplotlib.ft2font import FT2Font
    font = FT2Font(font_manager.findfont("DejaVu Sans"))
    font.set_size(size_px, 72)          # 72 dpi: points are pixels
    return font


def text_bitmap(text: str, size_px: int) -> np.ndarray:
    """Coverage (0..255, u8, (h, w)) of ``text`` set in DejaVu Sans at ``size_px``."""
    font = _font(int(size_px))
    font.set_text(text, 0.0)
    font.draw_glyphs_to_bitmap(antialiased=True)
    return np.asarray(font.get_image(), dtype=np.uint8)


def blend(image: np.ndarray, coverage: np.ndarray, x: int, y: int, colour) -> None:
    """Paint ``colour`` into ``image`` (u8 (H, W, 3), in place) through the
    coverage mask whose top-left corner goes to column ``x``, row ``y``
    (clipped at the image's edges)."""
    h, w = coverage.shape
    H, W = image.shape[:2]
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, W), min(y + h, H)
    if x1 <= x0 or y1 <= y0:
        return
    a = coverage[y0 - y:y1 - y, x0 - x:x1 - x, None].astype(np.float32) / 255.0
    region = image[y0:y1, x0:x1].astype(np.float32)
    image[y0:y1, x0:x1] = np.round(region * (1 - a) + a * np.asarray(colour, np.float32)).astype(np.uint8)


def draw_text(image, text: str, x: int, y: int, size_px: int, colour=TEXT_COLOUR) -> int:
    """Draw ``text`` with its top-left corner at (x, y); returns its width in pixels."""
    bitmap = text_bitmap(text, size_px)
    blend(image, bitmap, x, y, colour)
    return bitmap.shape[1]


@dataclass
class FrameLabels:
    """What the header of every frame shows.

    legend: ``[(label, (r, g, b)), ...]`` for colouring by phase; or
    colorbar: ``(name, vmin, vmax, table)`` with ``table`` the (256, 3) u8
    colormap, for colouring by a scalar.  wall_px: width of the grey frame
    drawn around the box (the walls); 0 for none.
    """
    legend: list | None = None
    colorbar: tuple | None = None
    wall_px: int = 4


def header_height(width: int) -> int:
    """Height of the label band for a frame ``width`` pixels wide."""
    return max(22, int(round(width * 0.055)))


def label_frame(image: np.ndarray, time: float, labels: FrameLabels,
                background=(255, 255, 255)) -> np.ndarray:
    """A new image: ``image`` inside a grey wall frame, under a header band
    with ``t = ...`` on the left and the legend or colour bar on the right
    (left out when the frame is too narrow for both)."""
    h, w = image.shape[:2]
    wall = int(labels.wall_px)
    band = header_height(w + 2 * wall)
    out = np.empty((band + h + 2 * wall, w + 2 * wall, 3), dtype=np.uint8)
    out[:band] = background
    out[band:] = FRAME_GREY
    out[band + wall:band + wall + h, wall:wall + w] = image[..., :3]
    size = max(10, int(band * 0.55))
    top = (band - size) // 2
    used = wall + 4 + draw_text(out, f"t = {time:.2f}", wall + 4, top, size)
    # the legend or colour bar from the right, as far as it fits beside the time
    parts = []                              # (coverage or None, colour, width) right to left
    if labels.legend:
        for label, colour in reversed(labels.legend):
            text = text_bitmap(label, size)
            parts += [(text, TEXT_COLOUR, text.shape[1]), (None, None, size // 3),
                      (np.full((size - 2, size), 255, np.uint8), colour, size), (None, None, size)]
    elif labels.colorbar:
        name, vmin, vmax, table = labels.colorbar
        bar_w = max(40, w // 5)
        ramp = table[np.linspace(0, len(table) - 1, bar_w).astype(int)][None, :, :]
        for item in (text_bitmap(f"{vmax:.3g}", size), None, ramp, None,
                     text_bitmap(f"{vmin:.3g}", size), None, text_bitmap(name, size)):
            if item is None:
                parts.append((None, None, size // 3))
            elif item.ndim == 3:
                parts.append((item, None, item.shape[1]))
            else:
                parts.append((item, TEXT_COLOUR, item.shape[1]))
    if sum(width for _, _, width in parts) <= out.shape[1] - wall - 4 - used - size:
        right = out.shape[1] - wall - 4
        for item, colour, width in parts:
            right -= width
            if item is None:
                continue
            if item.ndim == 3:              # colour bar ramp
                out[top + 1:top + size - 1, right:right + width] = item
            else:
                blend(out, item, right, top + (1 if colour is not TEXT_COLOUR else 0), colour)
    return out
