"""SynEEPose: ray-traced RGB-D video of robot arms with exact end-effector ground truth, in BOP format
(kernel/bop.py), the robot assets it renders (robots/) and FEEPE's templates; `python -m syneepose assets |
render | templates | show`."""

__version__ = "0.1.0"
