"""SynEEPose: ray-traced RGB-D video of robot arms with exact end-effector ground truth."""

__version__ = "0.1.0"
