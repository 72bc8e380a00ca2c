"""The 3-D view's PNG made fit for a report: the colour scale it was drawn with and a caption
(the run, its step, what the colours are) drawn into the image's bottom-left corner. The
browser renders the scene alone (the viewer's legend is a panel of the page, not of the
scene), and a picture of a thickness map without its scale says nothing.

Pure: an image and a scale (server.colormap's Continuous or Categories) in, an image out."""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from server.colormap import Categories, Continuous, colorize, scale_ends

PAD = 8  # px around the legend's contents
BAR_W, BAR_H = 240, 14  # px: a continuous scale's bar
SWATCH = 14  # px: a category's swatch
BOX = (255, 255, 255, 215)  # the legend's backing: mostly opaque, the part shows faintly through
INK = (34, 34, 34)
MUTED = (85, 85, 85)


def _font(px: int) -> ImageFont.ImageFont:
    # Pillow's own TrueType font (>= 10.1): the same glyphs on every machine, no system fonts
    return ImageFont.load_default(size=px)


# the default font lacks these glyphs (a box in the caption: "Tool speed ▯ 1.5", a browser
# review), even some of Latin-1's: the signs written as text
PLAIN = str.maketrans({"≥": ">=", "≤": "<=", "–": "-", "—": "-", "›": ">", "→": "->",
                       "…": "...", "×": "x", "−": "-", "µ": "u", "²": "^2", "³": "^3",
                       "≈": "~", "Δ": "delta "})


def _text_w(draw: ImageDraw.ImageDraw, text: str, font: ImageFont.ImageFont) -> int:
    box = draw.textbbox((0, 0), text, font=font)
    return int(np.ceil(box[2] - box[0]))


def with_legend(image: np.ndarray, scale: Continuous | Categories | None,
                caption: str | list[str]) -> np.ndarray:
    """``image`` (h, w, 3 or 4) uint8 with ``caption`` (its first line larger) and ``scale``'s
    legend in a box at its bottom-left corner (no scale: the caption alone). The same shape
    and dtype back."""
    captions = [caption] if isinstance(caption, str) else list(caption)
    base = Image.fromarray(np.ascontiguousarray(image)).convert("RGBA")
    scale_px = max(1.0, base.height / 720)  # a tall render gets a legend of the same share
    big, small = _font(round(14 * scale_px)), _font(round(12 * scale_px))
    pad, line = round(PAD * scale_px), round(18 * scale_px)
    probe = ImageDraw.Draw(base)
    lines: list[tuple[str, ImageFont.ImageFont, tuple[int, int, int]]] = [
        (c.translate(PLAIN), big if i == 0 else small, INK) for i, c in enumerate(captions)]
    if scale is not None:
        unit = f" [{scale.unit}]" if isinstance(scale, Continuous) and scale.unit not in ("", "-") \
            else ""
        lines.append(((f"{scale.label}{unit}" + (f": {scale.note}" if scale.note else ""))
                      .translate(PLAIN), small, MUTED))
    width = max(_text_w(probe, t, f) for t, f, _ in lines)
    bar_w, bar_h = round(BAR_W * scale_px), round(BAR_H * scale_px)
    if isinstance(scale, Continuous):
        lo, mid, hi = scale_ends(scale.lo, 0.5 * (scale.lo + scale.hi), scale.hi)
        u = f" {scale.unit}" if scale.unit not in ("", "-") else ""
        # the ends hold the values beyond them (colormap.colorize clips): said as at most /
        # at least, in words a default font has glyphs for
        ends = (f"{lo}{u} or less", mid, f"{hi}{u} or more")
        bar_w = max(bar_w, sum(_text_w(probe, t, small) for t in ends) + 4 * pad)
        width = max(width, bar_w)
        height = len(lines) * line + bar_h + line + 2 * pad
    elif isinstance(scale, Categories):
        rows = [(text.translate(PLAIN), rgb) for text, rgb in scale.names.values()]
        width = max(width, max(_text_w(probe, t, small) for t, _ in rows) + SWATCH * 2)
        height = (len(lines) + len(rows)) * line + 2 * pad
    else:
        height = len(lines) * line + 2 * pad
    box_w = min(width + 2 * pad, base.width)
    x0, y0 = 0, max(0, base.height - height)
    layer = Image.new("RGBA", base.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    draw.rectangle([x0, y0, x0 + box_w, base.height], fill=BOX)
    y = y0 + pad
    for text, font, ink in lines:
        draw.text((x0 + pad, y), text, font=font, fill=ink)
        y += line
    if isinstance(scale, Continuous):
        bar_w = min(bar_w, box_w - 2 * pad)
        ramp = colorize(np.linspace(scale.lo, scale.hi, bar_w), scale.lo, scale.hi, scale.cmap)
        bar = np.repeat(ramp[None], bar_h, axis=0)
        layer.paste(Image.fromarray(bar).convert("RGBA"), (x0 + pad, y))
        draw.rectangle([x0 + pad - 1, y - 1, x0 + pad + bar_w, y + bar_h], outline=MUTED)
        y += bar_h + round(3 * scale_px)
        left, centre, right = ends
        draw.text((x0 + pad, y), left, font=small, fill=INK)
        cw = _text_w(draw, centre, small)
        draw.text((x0 + pad + (bar_w - cw) // 2, y), centre, font=small, fill=INK)
        draw.text((x0 + pad + bar_w - _text_w(draw, right, small), y), right, font=small,
                  fill=INK)
    elif isinstance(scale, Categories):
        sw = round(SWATCH * scale_px)
        for text, rgb in rows:
            draw.rectangle([x0 + pad, y + 2, x0 + pad + sw, y + 2 + round(11 * scale_px)],
                           fill=tuple(rgb), outline=MUTED)
            draw.text((x0 + pad + sw + pad, y), text, font=small, fill=INK)
            y += line
    out = Image.alpha_composite(base, layer)
    mode = "RGBA" if image.ndim == 3 and image.shape[2] == 4 else "RGB"
    return np.asarray(out.convert(mode))


__all__ = ["with_legend"]
