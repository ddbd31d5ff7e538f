"""FEEPE templates: views on a Fibonacci sphere x in-plane rotations, object centred (pure numpy).

Rendering lives in `syneepose/blender/templates.py`; this module decides poses and intrinsics. The files of
a set (and their reader) are `kernel/template_set.py`.
"""

from __future__ import annotations

import numpy as np

from kernel.transforms import inv_T, make_T
from syneepose.scene.sample import look_at

FOV_DEG = 30.0
FILL = 0.9  # the bounding sphere spans this fraction of the image width


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z**2)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def intrinsics(resolution: int) -> np.ndarray:
    f = resolution / 2 / np.tan(np.deg2rad(FOV_DEG) / 2)
    c = (resolution - 1) / 2
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def poses(n_views: int, n_inplane: int, center: np.ndarray, radius: float) -> list[tuple[int, int, np.ndarray]]:
    """(view, inplane, T_cam_model) with the model's bounding-sphere centre on the optical axis."""
    distance = radius / np.sin(np.deg2rad(FOV_DEG) / 2 * FILL)
    out = []
    for v, direction in enumerate(fibonacci_sphere(n_views)):
        up = (0.0, 0.0, 1.0) if abs(direction[2]) < 0.99 else (1.0, 0.0, 0.0)
        T_model_cam = look_at(center + distance * direction, center, up)
        for k in range(n_inplane):
            a = 2 * np.pi * k / n_inplane
            roll = make_T(np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]]))
            out.append((v, k, inv_T(T_model_cam @ roll)))
    return out
