"""Square crops around a mask, as an affine map so points and intrinsics move with the pixels.

Pixel centres sit at integer coordinates (OpenCV). A crop of side `size` maps the mask box centre to
the crop centre and scales the padded box side to `size`; the crop's intrinsics are `A @ K`, the same
camera frame, so poses solved in crop pixels are poses in the original camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class Crop:
    rgb: np.ndarray  # (S, S, 3) uint8, background black
    depth: np.ndarray  # (S, S) metres, 0 where unknown or off the mask
    mask: np.ndarray  # (S, S) bool
    K: np.ndarray  # (3, 3) intrinsics of the crop pixels
    A: np.ndarray  # (3, 3) original pixel -> crop pixel

    @property
    def size(self) -> int:
        return self.mask.shape[0]


def mask_box(mask: np.ndarray) -> tuple[float, float, float] | None:
    """Centre (x, y) and side of the tight square around the mask, or None for an empty mask."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    side = max(xs.max() - xs.min(), ys.max() - ys.min()) + 1.0
    return (xs.max() + xs.min()) / 2.0, (ys.max() + ys.min()) / 2.0, float(side)


def crop_affine(cx: float, cy: float, side: float, size: int) -> np.ndarray:
    s = size / side
    c = (size - 1) / 2.0
    return np.array([[s, 0.0, c - s * cx], [0.0, s, c - s * cy], [0.0, 0.0, 1.0]])


def crop_around_mask(rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray, K: np.ndarray, size: int,
                     pad: float) -> Crop | None:
    """The masked object, background blacked out (templates are rendered on black). None if mask empty."""
    box = mask_box(mask)
    if box is None:
        return None
    cx, cy, side = box
    A = crop_affine(cx, cy, side * (1.0 + pad), size)
    M = A[:2]
    dsize = (size, size)
    crop_mask = cv2.warpAffine(mask.astype(np.uint8), M, dsize, flags=cv2.INTER_NEAREST) > 0
    source = np.ascontiguousarray(rgb)
    if A[0, 0] < 0.8:  # shrinking: low-pass first so the crop does not alias
        source = cv2.GaussianBlur(source, (0, 0), 0.5 / A[0, 0])
    crop_rgb = cv2.warpAffine(source, M, dsize, flags=cv2.INTER_LINEAR)
    crop_rgb[~crop_mask] = 0
    crop_depth = cv2.warpAffine(depth.astype(np.float32), M, dsize, flags=cv2.INTER_NEAREST)
    crop_depth[~crop_mask] = 0.0
    return Crop(crop_rgb, crop_depth.astype(np.float64), crop_mask, A @ K, A)
