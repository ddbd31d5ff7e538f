"""The calibration in the forms a robot stack loads as they are. Every form names its direction: the pose
of the camera's optical frame (OpenCV: x right, y down, z forward; realsense2_camera's
`camera_color_optical_frame`) in the robot's base frame, `p_base = T_base_camera @ p_camera`; quaternions in
x, y, z, w order. Numbers are written with 17 significant digits so each form gives back the same matrix."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from kernel.transforms import R_to_rpy

DIRECTION = ("T_base_camera: the pose of the camera's optical frame (OpenCV: x right, y down, z forward) in the "
             "robot's base frame; p_base = T_base_camera @ p_camera")


@dataclass
class Frames:
    base: str  # the robot's base link
    camera: str  # the camera's optical frame as the stack names it
    effector: str  # the end-effector link (easy_handeye2's robot_effector_frame)


def _num(x: float) -> float:
    return float(f"{float(x):.17g}")


def translation_quaternion(T: np.ndarray) -> tuple[list[float], list[float]]:
    """(x, y, z) and (qx, qy, qz, qw), w >= 0."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    q = -q if q[3] < 0 else q
    return [_num(v) for v in T[:3, 3]], [_num(v) for v in q]


def as_json(T: np.ndarray, frames: Frames, extra: dict) -> dict:
    t, q = translation_quaternion(T)
    return {"direction": DIRECTION, "parent_frame": frames.base, "child_frame": frames.camera,
            "T_base_camera": [[_num(v) for v in row] for row in T], "translation_m": t, "quaternion_xyzw": q,
            **extra}


def as_handeye_yaml(T: np.ndarray, frames: Frames, name: str) -> str:
    """easy_handeye2's saved calibration (eye on base: robot_base_frame -> tracking_base_frame)."""
    t, q = translation_quaternion(T)
    doc = {"parameters": {"name": name, "calibration_type": "eye_on_base", "robot_base_frame": frames.base,
                          "robot_effector_frame": frames.effector, "tracking_base_frame": frames.camera,
                          "tracking_marker_frame": frames.effector, "freehand_robot_movement": True},
           "transform": {"translation": dict(zip("xyz", t)), "rotation": dict(zip("xyzw", q))}}
    return f"# {DIRECTION}\n# rotation: quaternion x, y, z, w\n" + yaml.safe_dump(doc, sort_keys=False)


def as_static_transform_publisher(T: np.ndarray, frames: Frames) -> str:
    """ROS 2's command with named arguments (no positional Euler-order ambiguity)."""
    t, q = translation_quaternion(T)
    values = zip(("x", "y", "z", "qx", "qy", "qz", "qw"), t + q)
    args = " ".join(f"--{k} {v!r}" for k, v in values)
    return (f"# {DIRECTION}\nros2 run tf2_ros static_transform_publisher {args} "
            f"--frame-id {frames.base} --child-frame-id {frames.camera}\n")


def as_urdf_joint(T: np.ndarray, frames: Frames) -> str:
    """A fixed joint for the robot's URDF (origin rpy: fixed axes x, y, z, as URDF defines them)."""
    xyz = " ".join(repr(_num(v)) for v in T[:3, 3])
    rpy = " ".join(repr(_num(v)) for v in R_to_rpy(T[:3, :3]))
    return (f"<!-- {DIRECTION} -->\n<joint name=\"{frames.base}_to_{frames.camera}\" type=\"fixed\">\n"
            f"  <parent link=\"{frames.base}\"/>\n  <child link=\"{frames.camera}\"/>\n"
            f"  <origin xyz=\"{xyz}\" rpy=\"{rpy}\"/>\n</joint>\n")
