"""The backbone interface: a crop (image, depth, mask, intrinsics) -> descriptors on a grid of points.

Every backbone samples its grid only inside the mask eroded by a 5x5 square (FoundPose), so features do
not straddle the silhouette, where the black template background and the real background differ.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from feepe.crop import Crop


@dataclass
class PatchFeatures:
    uv: np.ndarray  # (N, 2) crop pixel coordinates of the descriptors
    desc: np.ndarray  # (N, D) float32, unit length (cosine similarity = dot product)


class Backbone(Protocol):
    name: str
    crop_size: int

    def options(self) -> dict:
        """Everything that changes the features: part of the onboarding cache key."""

    def extract(self, crop: Crop) -> PatchFeatures:
        ...


def eroded(mask: np.ndarray, kernel: int = 5) -> np.ndarray:
    return cv2.erode(mask.astype(np.uint8), np.ones((kernel, kernel), np.uint8)) > 0


def grid_points(mask: np.ndarray, stride: int, offset: float) -> np.ndarray:
    """Grid points (x, y) at `offset + k * stride` that fall inside the eroded mask."""
    size_y, size_x = mask.shape
    xs = np.arange(offset, size_x, stride)
    ys = np.arange(offset, size_y, stride)
    gx, gy = np.meshgrid(xs, ys)
    uv = np.stack([gx.ravel(), gy.ravel()], 1)
    inside = eroded(mask)[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)]
    return uv[inside].astype(np.float64)


def unit_rows(x: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return (x / np.maximum(n, 1e-12)).astype(np.float32)
