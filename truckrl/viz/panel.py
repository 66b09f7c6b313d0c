"""A text side panel (HUD and key help) drawn with OpenCV next to the bird's-eye view."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from truckrl.viz.draw import COLORS

LINE_PX = 19  # [px] text line pitch
TAB_PX = 84  # [px] column width of tab-separated text
FONT_SCALE = 0.45

#: A panel line: plain text (HUD colour) or ``(text, RGB colour)``.
Line = str | tuple[str, tuple[int, int, int]]


def text_panel(lines: Sequence[Line], width: int, height: int) -> np.ndarray:
    """Lines of text top-down on the background colour: ``[height, width, 3]`` uint8 RGB.

    A tab starts the next column (``TAB_PX`` wide). Lines that do not fit below ``height`` are
    dropped; long lines are clipped at the edge.
    """
    img = np.empty((height, width, 3), dtype=np.uint8)
    img[:] = COLORS["background"]
    img[:, :2] = COLORS["curb"]  # separator from the bird's-eye view
    for i, line in enumerate(lines):
        text, color = (line, COLORS["hud"]) if isinstance(line, str) else line
        y = 10 + LINE_PX * (i + 1)
        if y > height - 4:
            break
        for col, part in enumerate(text.split("\t")):
            org = (12 + col * TAB_PX, y)
            cv2.putText(img, part, org, cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALE, color, 1, cv2.LINE_AA)
    return img


def with_panel(view: np.ndarray, lines: Sequence[Line], width: int) -> np.ndarray:
    """``view [H, W, 3]`` with a ``width``-px text panel on its right: ``[H, W + width, 3]``."""
    if width <= 0:
        return view
    return np.concatenate((view, text_panel(lines, width, view.shape[0])), axis=1)


def with_banner(
    view: np.ndarray,
    title: str,
    color: tuple[int, int, int] = COLORS["hud"],
    subtitle: str = "",
) -> np.ndarray:
    """A copy of ``view`` with a banner near the top: ``title`` large in ``color``, ``subtitle``
    below, centred.

    The banner is a darkened band across the image, below the caption line (the truck usually
    sits near the centre of the view and stays visible); its text scales with the image width.
    """
    img = view.copy()
    h, w = img.shape[:2]
    scale = max(0.5, w / 640.0)
    font = cv2.FONT_HERSHEY_DUPLEX
    (tw, th), _ = cv2.getTextSize(title, font, 1.3 * scale, max(1, round(2 * scale)))
    (sw, sh), _ = cv2.getTextSize(subtitle, font, 0.6 * scale, 1) if subtitle else ((0, 0), 0)
    gap = round(14 * scale)
    band = th + (sh + gap if subtitle else 0) + 2 * gap
    top = min(max(28, h // 16), max(0, h - band))
    region = img[top : top + band]
    region[:] = (region.astype(np.uint16) * 3 // 10).astype(np.uint8)  # darken to 30 %
    y = top + gap + th
    org = (max(0, (w - tw) // 2), y)
    cv2.putText(img, title, org, font, 1.3 * scale, color, max(1, round(2 * scale)), cv2.LINE_AA)
    if subtitle:
        org = (max(0, (w - sw) // 2), y + gap + sh)
        cv2.putText(img, subtitle, org, font, 0.6 * scale, COLORS["hud"], 1, cv2.LINE_AA)
    return img
