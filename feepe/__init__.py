"""FEEPE: training-free end-effector pose estimation and online camera-to-base calibration."""
