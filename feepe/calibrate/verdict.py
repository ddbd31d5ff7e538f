"""One line an engineer acts on: OK, or what is wrong and which motion or input would mend it. The
thresholds are judgements stated here, not fitted to any data set: a fit whose outline lies more than
2 px from the frames' robot, or whose depth agrees on under 60 % of the robot's pixels, is poor; a
2-sigma bound above 5 mm is too uncertain for a grasp. A robot that hardly moved (its end-effector spans
under 5 cm and turns under 10 degrees) shows the camera one view of itself, whatever the fit says; an
uncertain calibration is told which motion the recording lacked (under 10 cm of spread across the path,
under 20 degrees of turn)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feepe.calibrate.uncertainty import Uncertainty
from kernel.transforms import rotation_angle

MIN_ESTIMATED = 0.5  # share of the frames with an estimate
MAX_OUTLINE_PX = 2.0  # median over the estimated frames
MIN_DEPTH_AGREE = 0.6
MAX_TWO_SIGMA_MM = 5.0
MIN_SPREAD_M = 0.10  # extent (2 standard deviations) of the end-effector's positions along its second axis
MIN_TURN_DEG = 20.0  # largest angle between the end-effector's orientations
STILL_SPREAD_M, STILL_TURN_DEG = 0.05, 10.0  # below both the robot hardly moved
AXES = ("x", "y", "z")


@dataclass
class Verdict:
    word: str  # OK, POOR FIT, UNCERTAIN, TOO LITTLE MOTION or NO CALIBRATION
    reasons: list[str]

    def line(self) -> str:
        return self.word if not self.reasons else f"{self.word}: " + "; ".join(self.reasons)


def judge(n_frames: int, n_estimated: int, outline_px: float, depth_agree: float, uncertainty: Uncertainty,
          T_base_ee: np.ndarray) -> Verdict:
    """`outline_px`, `depth_agree`: medians over the estimated frames (nan: not measured);
    `T_base_ee`: (n, 4, 4) the end-effector's poses over the recording."""
    if n_estimated == 0:
        return Verdict("NO CALIBRATION", ["the robot was not found in any frame: is the whole arm in view, "
                                          "are the URDF, --ee-link and the joint names those of this robot?"])
    poor = []
    if n_estimated < MIN_ESTIMATED * n_frames:
        poor.append(f"only {n_estimated} of {n_frames} frames have an estimate")
    if outline_px > MAX_OUTLINE_PX:
        poor.append(f"the robot's outline lies {outline_px:.1f} px from the frames' (> {MAX_OUTLINE_PX:g})")
    if depth_agree < MIN_DEPTH_AGREE:
        poor.append(f"depth agrees on {100 * depth_agree:.0f} % of the robot's pixels (< {100 * MIN_DEPTH_AGREE:.0f} %)")
    if poor:
        return Verdict("POOR FIT", poor + ["check the intrinsics, the depth scale and that the joint states are "
                                           "this camera's time"])
    spread, turn = motion(T_base_ee)
    advice = []
    if spread[0] < MIN_SPREAD_M:
        advice.append(f"the end-effector spans {100 * spread[0]:.0f} cm across its path (< {100 * MIN_SPREAD_M:.0f}); "
                      f"move it {100 * MIN_SPREAD_M:.0f} cm or more along the base's {spread[1]} axis too")
    if turn < MIN_TURN_DEG:
        advice.append(f"the end-effector turns {turn:.0f} degrees at most (< {MIN_TURN_DEG:.0f}); turn the wrist")
    if spread[0] < STILL_SPREAD_M and turn < STILL_TURN_DEG:
        return Verdict("TOO LITTLE MOTION", advice)
    if not 2 * uncertainty.sigma_mm <= MAX_TWO_SIGMA_MM:  # nan too: too few frames to say
        told = (f"no bound ({uncertainty.missing})" if np.isnan(uncertainty.sigma_mm)
                else f"2-sigma {2 * uncertainty.sigma_mm:.1f} mm")
        return Verdict("UNCERTAIN", [f"{told} (> {MAX_TWO_SIGMA_MM:g} mm wanted): record more frames with the "
                                     "arm moving through the workspace", *advice])
    return Verdict("OK", [])


def motion(T_base_ee: np.ndarray) -> tuple[tuple[float, str], float]:
    """The end-effector's spread across its path (2 standard deviations along the second principal axis of
    its positions, m, and the base axis nearest that direction) and its largest turn from the first pose (deg)."""
    positions = T_base_ee[:, :3, 3]
    values, vectors = np.linalg.eigh(np.cov(positions.T) if len(positions) > 1 else np.zeros((3, 3)))
    extent = 2 * np.sqrt(max(values[1], 0.0))  # eigh: ascending
    turn = max(np.degrees(rotation_angle(T_base_ee[0, :3, :3], T[:3, :3])) for T in T_base_ee)
    return (float(extent), AXES[int(np.argmax(np.abs(vectors[:, 1])))]), float(turn)
