"""Depth images as geometry: depth at pixels and camera-frame surface normals (back-projection: kernel.camera)."""

from __future__ import annotations

import cv2
import numpy as np

from kernel.camera import point_map


def depth_at(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest-pixel depth (0 outside the image): depth edges must not be blended."""
    h, w = depth.shape
    u = np.round(uv[:, 0]).astype(int)
    v = np.round(uv[:, 1]).astype(int)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.zeros(len(uv))
    out[ok] = depth[v[ok], u[ok]]
    return out


def normal_map(depth: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals facing the camera (H, W, 3) and where they are valid (all 3x3 neighbours have depth)."""
    P = point_map(depth, K)
    du = np.gradient(P, axis=1)
    dv = np.gradient(P, axis=0)
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = n / np.maximum(norm, 1e-12)
    n = np.where(np.sum(n * P, -1, keepdims=True) > 0, -n, n)
    valid = cv2.erode((depth > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    valid &= norm[..., 0] > 0
    n[~valid] = 0.0
    return n, valid


def align_to_axis(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the ray through pixel `uv` onto the optical axis.

    Normals rotated by it look as if the object sat in the image centre, as in the templates.
    """
    d = np.linalg.solve(K, np.array([uv[0], uv[1], 1.0]))
    d /= np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(d, z)
    s, c = np.linalg.norm(axis), float(d @ z)
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * Kx + (1 - c) * (Kx @ Kx)
