"""FEEPE templates: views on a Fibonacci sphere x in-plane rotations, object centred (numpy and cv2, no bpy).

Rendering lives in `syneepose/blender/templates.py`; this module decides poses and intrinsics and derives the
in-plane rotations of a view from its one render. The files of a set (and their reader) are
`kernel/template_set.py`.
"""

from __future__ import annotations

import cv2
import numpy as np

from kernel.transforms import fibonacci_sphere, inv_T, make_T
from syneepose.scene.sample import look_at

FOV_DEG = 30.0
FILL = 0.9  # the bounding sphere spans this fraction of the image width
DEPTH_EDGE_M = 0.005  # roll_template: neighbouring depths further apart than this meet at an edge
INPLANE_BY = ("rotated", "rendered")  # in-plane rotations: rolled from the view's render (roll_template), or rendered
# The denoiser's fast prefilter: at 128 px the accurate one cost 0.3 s of a view's 0.39 s (issue 36, docs/syneepose.md)
DENOISE_PREFILTER = "fast"


def intrinsics(resolution: int) -> np.ndarray:
    f = resolution / 2 / np.tan(np.deg2rad(FOV_DEG) / 2)
    c = (resolution - 1) / 2
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def poses(n_views: int, n_inplane: int, centre: np.ndarray, radius: float) -> list[tuple[int, int, np.ndarray]]:
    """(view, inplane, T_cam_model) with the model's bounding-sphere centre on the optical axis."""
    distance = radius / np.sin(np.deg2rad(FOV_DEG) / 2 * FILL)
    out = []
    for v, direction in enumerate(fibonacci_sphere(n_views)):
        up = (0.0, 0.0, 1.0) if abs(direction[2]) < 0.99 else (1.0, 0.0, 0.0)
        T_model_cam = look_at(centre + distance * direction, centre, up)
        for k in range(n_inplane):
            a = 2 * np.pi * k / n_inplane
            roll = make_T(np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]]))
            out.append((v, k, inv_T(T_model_cam @ roll)))
    return out


def _roll(image: np.ndarray, angle: float, interpolation: int) -> np.ndarray:
    """`image` as the camera of `poses` rolled by `angle` (radians) sees it: with the principal point at the
    image centre, rolling the camera about its axis rotates the image about the centre."""
    c = (image.shape[1] - 1) / 2, (image.shape[0] - 1) / 2
    M = cv2.getRotationMatrix2D(c, -np.degrees(angle), 1.0)  # OpenCV's angle turns the other way, in degrees
    return cv2.warpAffine(image, M, (image.shape[1], image.shape[0]), flags=interpolation | cv2.WARP_INVERSE_MAP,
                          borderValue=0)


def roll_template(rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray,
                  angle: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The in-plane template at `angle` from its view's unrolled render. Depth values do not change under a
    roll, and nothing leaves the frame: the bounding sphere projects to a centred disc (FILL); corners are
    background (0). RGB is interpolated linearly, the mask is the linearly interpolated coverage >= 0.5, and
    depth the mean of the valid depths around each new pixel (linear weights), or the nearest one where the
    two differ by more than DEPTH_EDGE_M (a depth edge inside the object, which a mean would invent)."""
    rgb = _roll(rgb, angle, cv2.INTER_LINEAR)
    valid = (depth > 0).astype(np.float32)
    weight = _roll(valid, angle, cv2.INTER_LINEAR)
    mean = _roll((depth * valid).astype(np.float32), angle, cv2.INTER_LINEAR) / np.maximum(weight, 1e-6)
    nearest = _roll(depth.astype(np.float32), angle, cv2.INTER_NEAREST)
    inside = (_roll(np.asarray(mask, np.float32), angle, cv2.INTER_LINEAR) >= 0.5) & (weight > 0)
    depth = np.where((np.abs(mean - nearest) <= DEPTH_EDGE_M) | (nearest == 0), mean, nearest)
    return rgb, np.where(inside, depth, 0.0), inside
