"""Symmetry disambiguation with the robot prior.

Every candidate pose of frame i implies a camera-to-base pose `T_cam_ee @ inv(T_base_ee_i)`. A symmetric
end-effector splits a frame's candidates into modes whose implied calibrations differ by the symmetry
(180 deg for a parallel gripper); the right modes are the ones whose relative pose between frames agrees
with forward kinematics, i.e. whose implied calibrations agree. The paper pairs a base frame's two modes
with the current frame's two; this generalises it to every key frame and to any number of modes: every
candidate's implied calibration is a hypothesis, supported by the inliers of all candidates (of any key
frame) whose implied rotation lies within `tolerance_deg` of it; the best-supported hypothesis wins and
the candidates outside its tolerance are dropped.

The vote does not know the end-effector's symmetries, so it drops more than symmetric twins: every
candidate whose implied calibration rotation is more than `tolerance_deg` from the winner's - a twin, a
wrong view from retrieval, a PnP solution on bad matches - leaves the optimisation, in every key frame
and the current one. The paper drops only the wrong one of each frame's two symmetric modes; this is an
outlier filter as well, and on an asymmetric end-effector it is only that. If every candidate of the
current frame is dropped, the current frame contributes no matches and the pose comes from the key frames
through forward kinematics.
"""

from __future__ import annotations

import numpy as np

from kernel.transforms import inv_T


def implied_calibrations(T_cam_ee: np.ndarray, T_base_ee: np.ndarray) -> np.ndarray:
    return T_cam_ee @ inv_T(T_base_ee)


def consensus(frames: list[tuple[np.ndarray, list]], tolerance_deg: float = 20.0) -> tuple[list[list[bool]], np.ndarray]:
    """frames: (T_base_ee, candidates) each. Returns which candidates to keep per frame and the winning
    calibration hypothesis (4, 4)."""
    calib = [implied_calibrations(c.T_cam_ee, T_base_ee) for T_base_ee, cands in frames for c in cands]
    if not calib:
        return [[] for _ in frames], np.eye(4)
    calib = np.stack(calib)
    weight = np.array([c.n_inliers for _, cands in frames for c in cands], dtype=float)
    # cos of the angle between every pair of implied rotations: (trace(Ra^T Rb) - 1) / 2
    R = calib[:, :3, :3].reshape(len(calib), 9)
    agree = (R @ R.T - 1.0) / 2.0 >= np.cos(np.deg2rad(tolerance_deg))
    best = int(np.argmax(agree @ weight))
    keep_flat = agree[best]
    keep, i = [], 0
    for _, cands in frames:
        keep.append([bool(k) for k in keep_flat[i:i + len(cands)]])
        i += len(cands)
    return keep, calib[best]
