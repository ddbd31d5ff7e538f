"""How far the calibration may be off, stated where it is used: as the mean displacement of the points the
end-effector visited (in the base frame) and as an angle.

The parts, added in quadrature. The scatter of the calibrations the estimator held over the second half of
the recording's estimated frames about the final one sees what the frames disagree on; a bias every frame
shares it cannot see, and on the twelve stereo segments below it was 1.5-18x below the true error. The shared part has two
terms: one proportional to the robot's median depth residual at the final calibration (a stereo camera's
depth errs alike over frames at the robot's edges and surfaces), and a floor of a fraction of a pixel at
the robot's distance (with exact depth the outline's sub-pixel fit is what is left). Their two constants
were set on seeds 0 (six stereo segments and the 17 of 18 exact-depth segments calibrated) and 7 (six stereo
segments) as the smallest round values whose 2-sigma covers each (each segment needed at most 0.107 mm per mm
of depth residual and a floor of 0.064 px); seeds 11 (stereo) and 7 (exact depth) checked them
(docs/results.md, "The calibration tool")"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernel.transforms import inv_T, rotation_angle

MIN_FRAMES = 3  # fewer calibrations than this in the second half: no uncertainty is stated
SHARED_PER_DEPTH_MM = 0.125  # sigma of the shared error (mm at the workspace) per mm of median depth residual
SHARED_PX = 0.07  # and its floor, in pixels at the robot's distance


@dataclass
class Uncertainty:
    sigma_mm: float  # at the workspace; nan when not stated (too few frames, or no depth)
    sigma_deg: float  # the scatter's alone
    frames: int  # calibrations the scatter is taken over
    scatter_mm: float  # its parts
    shared_mm: float

    @property
    def missing(self) -> str | None:
        """Why no bound is stated, if none is."""
        if self.frames < MIN_FRAMES:
            return f"{self.frames} calibrations in the second half of the estimated frames, {MIN_FRAMES} needed"
        if not np.isfinite(self.shared_mm):
            return "no depth residual or robot outline to judge the shared error by (RGB only, or flange poses)"
        return None


def displacement_mm(T_a: np.ndarray, T_b: np.ndarray, points: np.ndarray) -> float:
    """Mean distance (mm) by which a point seen by the camera lands apart in the base under T_a and T_b
    (camera-to-base, T_cam_base)."""
    rel = inv_T(T_a) @ T_b
    return float(np.linalg.norm(points @ rel[:3, :3].T + rel[:3, 3] - points, axis=1).mean() * 1e3)


def estimate(calibrations: list[np.ndarray], final: np.ndarray, points: np.ndarray, depth_residual_mm: float,
             pixel_mm: float) -> Uncertainty:
    """`calibrations`: T_cam_base after each estimated frame, in order; `points`: the workspace (base, m);
    `depth_residual_mm`: median over the frames of the robot's median depth residual (nan: no depth);
    `pixel_mm`: a pixel's width at the robot."""
    later = calibrations[len(calibrations) // 2:-1]
    if len(later) < MIN_FRAMES:
        return Uncertainty(float("nan"), float("nan"), len(later), float("nan"), float("nan"))
    mm = np.array([displacement_mm(T, final, points) for T in later])
    deg = np.degrees([rotation_angle(T[:3, :3], final[:3, :3]) for T in later])
    scatter = float(np.sqrt(np.mean(mm**2)))
    shared = float(np.hypot(SHARED_PER_DEPTH_MM * depth_residual_mm, SHARED_PX * pixel_mm))
    return Uncertainty(float(np.hypot(scatter, shared)), float(np.sqrt(np.mean(deg**2))), len(later), scatter, shared)
