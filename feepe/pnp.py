"""Pose from 2D-3D matches: EPnP inside RANSAC, then Levenberg-Marquardt on the inliers (OpenCV)."""

from __future__ import annotations

import cv2
import numpy as np

from kernel.transforms import make_T

MIN_POINTS = 6


def solve_pnp(uv: np.ndarray, xyz: np.ndarray, K: np.ndarray, threshold_px: float = 4.0,
              iterations: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray] | None:
    """(T_cam_model, inlier mask) or None when there are too few points or inliers."""
    if len(uv) < MIN_POINTS:
        return None
    obj = np.ascontiguousarray(xyz, dtype=np.float64)
    img = np.ascontiguousarray(uv, dtype=np.float64)
    cv2.setRNGSeed(seed)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=iterations,
                                                 reprojectionError=threshold_px, confidence=0.999,
                                                 flags=cv2.SOLVEPNP_EPNP)
    if not ok or inliers is None or len(inliers) < MIN_POINTS:
        return None
    idx = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T = make_T(R, tvec.ravel())
    if T[2, 3] <= 0:
        return None
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    inlier = np.linalg.norm(proj.reshape(-1, 2) - img, axis=1) <= threshold_px
    if inlier.sum() < MIN_POINTS:
        return None
    return T, inlier
