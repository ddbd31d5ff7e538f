"""Calibration starts from where the end-effector is (our extension, issue 13; not in the paper).

With a static camera, every frame pairs a point known in the base frame - the end-effector model's centre
moved by forward kinematics - with the same point seen by the camera: the mask's centroid back-projected at
the median masked depth. Pairs that span a plane fix the camera-to-base pose (Kabsch) whatever the
end-effector looks like: a symmetric or texture-less gripper matches several templates but has one
position. Pairs along a line leave the rotation about that line free; it is swept, and the masks choose.

The seen point lies on the visible surface, a few cm in front of the model's centre and not exactly on
it, so these are starts for the silhouette refinement, not estimates.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from kernel.camera import backproject
from kernel.transforms import make_T

MIN_DEPTH_PX = 20  # masked pixels with depth needed for a centre


def observed_centre(depth: np.ndarray, mask: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """Camera-frame point: the mask centroid's ray at the median depth of the mask's interior (its edge
    pixels are where a stereo camera's depth flies). None when too little depth is seen."""
    mask = np.asarray(mask, bool)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    z = np.asarray(depth, float)[inner]
    z = z[z > 0]
    if len(z) < MIN_DEPTH_PX:
        return None
    v, u = np.nonzero(mask)
    return backproject(np.array([[u.mean(), v.mean()]]), np.array([np.median(z)]), K)[0]


class CentreTrack:
    """The pairs seen so far, one per place the end-effector visited (`spacing_m` apart in the base frame)."""

    def __init__(self, centre_ee: np.ndarray, spacing_m: float = 0.01):
        self.centre_ee = np.asarray(centre_ee, float)
        self.spacing_m = spacing_m
        self.base: list[np.ndarray] = []
        self.cam: list[np.ndarray] = []

    def add(self, T_base_ee: np.ndarray, seen: np.ndarray | None) -> None:
        if seen is None:
            return
        p = T_base_ee[:3, :3] @ self.centre_ee + T_base_ee[:3, 3]
        if self.base and np.min(np.linalg.norm(np.asarray(self.base) - p, axis=1)) < self.spacing_m:
            return
        self.base.append(p)
        self.cam.append(np.asarray(seen, float))

    def starts(self, min_spread_m: float = 0.02, plane_spread_m: float = 0.05, n_sweep: int = 12) -> list[np.ndarray]:
        return calibration_starts(np.asarray(self.base).reshape(-1, 3), np.asarray(self.cam).reshape(-1, 3),
                                  min_spread_m, plane_spread_m, n_sweep)


def calibration_starts(base: np.ndarray, cam: np.ndarray, min_spread_m: float = 0.02,
                       plane_spread_m: float = 0.05, n_sweep: int = 12) -> list[np.ndarray]:
    """T_cam_base candidates from paired points: Kabsch when they span a plane (RMS spread across their main
    direction >= min_spread_m), the rotation about their line swept in `n_sweep` steps when they span less
    than `plane_spread_m` across it; none when they all lie within `min_spread_m` of one place."""
    if len(base) < 2:
        return []
    p_mean, q_mean = base.mean(0), cam.mean(0)
    P, Q = base - p_mean, cam - q_mean
    _, s, Vt = np.linalg.svd(P, full_matrices=False)
    spread = s / np.sqrt(len(P))
    if spread[0] < min_spread_m:
        return []
    starts = []
    if len(spread) > 1 and spread[1] >= min_spread_m:
        R, _ = Rotation.align_vectors(Q, P)
        starts.append(_pose(R.as_matrix(), p_mean, q_mean))
    if len(spread) < 2 or spread[1] < plane_spread_m:
        d_base = Vt[0]
        along = P @ d_base
        d_cam = along @ Q / (along @ along)
        R0, _ = Rotation.align_vectors(d_cam[None] / np.linalg.norm(d_cam), d_base[None])
        for angle in np.arange(n_sweep) * 2 * np.pi / n_sweep:
            R = Rotation.from_rotvec(angle * d_cam / np.linalg.norm(d_cam)) * R0
            starts.append(_pose(R.as_matrix(), p_mean, q_mean))
    return starts


def _pose(R_cam_base: np.ndarray, p_mean: np.ndarray, q_mean: np.ndarray) -> np.ndarray:
    return make_T(R_cam_base, q_mean - R_cam_base @ p_mean)
