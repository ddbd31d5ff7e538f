"""Symmetry disambiguation with the robot prior.

Every candidate pose of frame i implies a camera-to-base pose `T_cam_ee @ inv(T_base_ee_i)`. A symmetric
end-effector splits a frame's candidates into modes whose implied calibrations differ by the symmetry
(180 deg for a parallel gripper); the right modes are the ones whose relative pose between frames agrees
with forward kinematics, i.e. whose implied calibrations agree. The paper pairs a base frame's two modes
with the current frame's two; this generalises it to every key frame and to any number of modes: each
mode of each frame is a hypothesis, every frame votes with its closest mode, and the hypothesis with the
most inlier support wins. Candidates further than `tolerance_deg` from it are dropped.
"""

from __future__ import annotations

import numpy as np

from syneepose.transforms import inv_T, rotation_angle


def implied_calibrations(T_cam_ee: np.ndarray, T_base_ee: np.ndarray) -> np.ndarray:
    return T_cam_ee @ inv_T(T_base_ee)


def consensus(frames: list[tuple[np.ndarray, list]], tolerance_deg: float = 20.0) -> tuple[list[list[bool]], np.ndarray]:
    """frames: (T_base_ee, candidates) each. Returns which candidates to keep per frame and the winning
    calibration hypothesis (4, 4)."""
    tol = np.deg2rad(tolerance_deg)
    calib = [[implied_calibrations(c.T_cam_ee, T_base_ee) for c in cands] for T_base_ee, cands in frames]
    weight = [[c.n_inliers for c in cands] for _, cands in frames]
    hypotheses = [C for per_frame in calib for C in per_frame]
    best, best_support = None, -1.0
    for H in hypotheses:
        support = 0.0
        for per_frame, w in zip(calib, weight):
            if not per_frame:
                continue
            ang = rotation_angle(np.stack([C[:3, :3] for C in per_frame]), H[:3, :3])
            support += float(np.sum(np.asarray(w)[ang <= tol]))
        if support > best_support:
            best, best_support = H, support
    if best is None:
        return [[] for _ in frames], np.eye(4)
    keep = [[bool(rotation_angle(C[:3, :3], best[:3, :3]) <= tol) for C in per_frame] for per_frame in calib]
    return keep, best
