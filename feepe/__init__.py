"""FEEPE: training-free end-effector pose estimation and online camera-to-base calibration."""

from feepe.estimator import Estimator, FeepeOptions, FrameResult

__all__ = ["Estimator", "FeepeOptions", "FrameResult"]
