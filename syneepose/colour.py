"""sRGB's transfer function (IEC 61966-2-1, Blender's 'Standard' view) and Rec. 709 luminance: the one copy the
renders, the scene sampler and the IR images share."""

from __future__ import annotations

import numpy as np

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 weights of linear RGB


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear values, clipped to [0, 1], encoded (floats in [0, 1])."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    return np.round(linear_to_srgb(rgb) * 255.0).astype(np.uint8)


def srgb_to_linear(c):
    c = np.asarray(c, dtype=float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
