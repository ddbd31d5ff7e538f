"""The pinhole camera: camera-frame points (metres) to pixels and back, the one projection every package uses.

Pixel centres sit at integer (u, v), as in OpenCV and BOP's `cam_K`; K has no skew. The arithmetic is
u = fx * x / z + cx in that order: poses are compared bit for bit between versions, and another order
moves their last digits. Compiled loops use `feepe.raster.to_pixel`, the same expression in scalars.
"""

from __future__ import annotations

import numpy as np


def project(P: np.ndarray, K: np.ndarray, *, min_z: float) -> np.ndarray:
    """Pixels (..., 2) of camera points P (..., 3) under K (3, 3), or one K per point (..., 3, 3). Depths
    below `min_z` count as `min_z`: a point at or behind the camera lands far off the image instead of
    dividing by zero or mirroring into it."""
    z = np.maximum(P[..., 2], min_z)
    return np.stack([K[..., 0, 0] * P[..., 0] / z + K[..., 0, 2], K[..., 1, 1] * P[..., 1] / z + K[..., 1, 2]], -1)


def backproject(uv: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) with depths (...) along the optical axis -> camera points (..., 3): `project`'s inverse."""
    x = (uv[..., 0] - K[0, 2]) / K[0, 0]
    y = (uv[..., 1] - K[1, 2]) / K[1, 1]
    return np.stack([x * z, y * z, z], -1)


def point_map(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera points (H, W, 3) of every pixel of a depth image (0 where there is no depth)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return backproject(np.stack([u, v], -1), depth, K)
