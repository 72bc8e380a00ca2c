"""The 3-D view's PNG with its colour scale drawn in (server.snapshot): the image keeps its
shape and everything outside the legend's corner; the scale's colours are the ones the sheet
is painted with (server.colormap), to the bit, so a reader can match them."""

from __future__ import annotations

import numpy as np
import pytest

from server.colormap import VIRIDIS, Continuous, colorize, thinning_scale
from server.snapshot import with_legend


def _has(region: np.ndarray, rgb) -> bool:
    return bool(np.all(region.reshape(-1, 3) == np.asarray(rgb, np.uint8), axis=1).any())


@pytest.mark.parametrize("channels", [3, 4])
def test_a_continuous_scale_in_the_bottom_left_corner_only(channels):
    image = np.full((720, 960, channels), 200, np.uint8)
    scale = Continuous("Thickness", "mm", 0.45, 1.6, "range of this run")
    out = with_legend(image, scale, "cup: run cup-q3t-1, step 50 of 50")
    assert out.shape == image.shape and out.dtype == np.uint8
    changed = np.any(out != image, axis=2)
    rows, cols = np.nonzero(changed)
    # the box holds a caption, a line naming the scale, its bar and the bar's end values:
    # low in the image, on its left, leaving most of the view as rendered
    assert rows.min() > 720 // 2 and cols.min() == 0 and cols.max() < 960 * 3 // 4
    assert changed.mean() < 0.15
    corner = out[rows.min():, : cols.max() + 1, :3]
    # the bar's ends are the sheet's colours at lo and hi: the map's ends
    for v, end in ((0.45, VIRIDIS[0]), (1.6, VIRIDIS[-1])):
        assert np.array_equal(colorize(np.array([v]), 0.45, 1.6)[0], end)
        assert _has(corner, end), v


def test_categories_show_each_swatch_and_the_caption_alone_without_a_scale():
    image = np.full((1080, 1440, 3), 90, np.uint8)
    scale = thinning_scale()
    out = with_legend(image, scale, "cup: run x, step 3 of 6")
    corner = out[1080 // 2:, : 1440 // 2]
    for _, rgb in scale.names.values():
        assert _has(corner, rgb), rgb
    # recorded colours (no scale): the caption's box alone, shorter than with a scale
    alone = with_legend(image, None, "cup: run x, step 3 of 6")
    assert np.any(alone != image, axis=2).sum() < np.any(out != image, axis=2).sum()
    assert np.all(alone[: 1080 // 2] == image[: 1080 // 2])


def test_a_second_caption_line_and_signs_the_font_lacks():
    """What the run changed goes under the first line (smaller); the arrows and ellipses of
    the Runs table's words are written as text (the default font has no glyph for them: a
    box was drawn)."""
    from server.snapshot import PLAIN

    image = np.full((720, 960, 3), 200, np.uint8)
    one = with_legend(image, None, "cup: run x, step 50 of 50")
    two = with_legend(image, None, ["cup: run x, step 50 of 50",
                                    "as run: mesh.edge_length 2 → 4 mm; Friction × 0.5 …"])
    rows = lambda out: np.flatnonzero(np.any(out != image, axis=(1, 2)))  # noqa: E731
    assert rows(two).min() < rows(one).min()  # a taller box
    assert "2 -> 4 mm; Friction x 0.5 ..." in "2 → 4 mm; Friction × 0.5 …".translate(PLAIN)


def test_every_sign_a_caption_may_hold_has_a_glyph():
    """A browser review's PNG read "Tool speed ▯ 1.5": the default font has no "×", nor "−",
    "µ", "²", though they are Latin-1's or near. Every character of the words the page and
    the legends write, as the PNG writes them, is drawn, not the font's missing glyph (that
    of a CJK character, which it certainly lacks)."""
    from PIL import ImageFont

    from server.snapshot import PLAIN

    font = ImageFont.load_default(size=20)

    def glyph(c: str) -> tuple:
        return bytes(font.getmask(c)), font.getbbox(c)

    missing = glyph("\u4e00")
    words = ("as run: Tool speed × 1.5 from step 19; mesh.edge_length 2 → 4 mm … ≥ 1.2 mm, "
             "≤ 0.9 mm – — › −3 °C 5 µm 2.8 m² 1 m³ ≈ Δr ± 0.1 · ABCxyz0123456789()[]%/,.:;'")
    absent = sorted({c for c in words.translate(PLAIN) if c != " " and glyph(c) == missing})
    assert absent == [], absent
