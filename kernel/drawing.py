"""What the project's pictures share, drawn with OpenCV on RGB uint8 images: the colours, a mask's outline,
caption strips and images side by side. The generator's contact sheets (syneepose/show.py) and the
evaluator's overlays and report draw with them, so a ground-truth outline looks the same in both."""

from __future__ import annotations

import cv2
import numpy as np

GT_COLOUR = (255, 230, 0)  # yellow: the ground-truth silhouette, in the contact sheets and the pose overlays
EST_COLOUR = (255, 0, 255)  # magenta: a model at an estimate (the evaluator's overlays, the calibration's page)
BACKGROUND = (32, 32, 32)
TEXT = (235, 235, 235)
FONT, FONT_SCALE, LINE_H = cv2.FONT_HERSHEY_SIMPLEX, 0.35, 14


def draw_outline(image: np.ndarray, mask: np.ndarray, colour, thickness: int = 1) -> np.ndarray:
    """`image` with the boundary of `mask` (holes included) drawn on it, in place."""
    contours, _ = cv2.findContours(np.asarray(mask, dtype=np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(image, contours, -1, colour, thickness, cv2.LINE_8)
    return image


def caption(width: int, text: str) -> np.ndarray:
    """One line of text on a dark strip (Hershey fonts: ASCII only)."""
    strip = np.full((LINE_H, width, 3), BACKGROUND, np.uint8)
    cv2.putText(strip, text, (3, LINE_H - 4), FONT, FONT_SCALE, TEXT, 1, cv2.LINE_AA)
    return strip


def side_by_side(images: list[np.ndarray], gap: int = 2) -> np.ndarray:
    """Images of one height in a row, `gap` dark pixels apart."""
    spacer = np.full((images[0].shape[0], gap, 3), BACKGROUND, np.uint8)
    return np.hstack([part for im in images for part in (spacer, im)][1:])
