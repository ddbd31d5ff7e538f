"""What the calibration reads from a recording, whatever it came in (a folder, a ROS bag): frames of RGB,
depth registered to it, the intrinsics, and the robot's joint positions (or its flange pose) at the image's
time; and the pure functions that pair streams by time stamp."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from kernel.errors import UserError


@dataclass
class RecordedFrame:
    name: str  # the frame's file stem, or its stamp in nanoseconds from a bag
    stamp: float  # seconds
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray | None  # (H, W) metres, 0 = no depth; None: an RGB camera
    K: np.ndarray  # (3, 3)
    joints: dict[str, float] | None  # joint positions by name; None when the flange pose is given
    T_base_ee: np.ndarray | None = None  # (4, 4) metres: the end-effector link's pose instead of joints
    mask: np.ndarray | None = None  # (H, W) bool: the end-effector's visible mask, when one is given


@dataclass
class Recording:
    source: str  # what was read, for the report
    count: int  # frames that will be read
    read: Callable[[], Iterator[RecordedFrame]]  # reads them one at a time, in time order
    sync: dict = field(default_factory=dict)  # how the streams were paired (tolerances, offsets, dropped frames)


def thinned(recording: Recording, every: int) -> Recording:
    """Every `every`-th frame of the recording (a 30 Hz bag holds far more frames than a calibration needs)."""
    if every == 1:
        return recording
    return Recording(recording.source, -(-recording.count // every),
                     lambda: (f for k, f in enumerate(recording.read()) if k % every == 0),
                     {**recording.sync, "every": every})


def nearest(stamps: np.ndarray, t: float, tolerance: float) -> int | None:
    """Index of the stamp nearest t, if within tolerance (seconds)."""
    if len(stamps) == 0:
        return None
    i = int(np.argmin(np.abs(stamps - t)))
    return i if abs(stamps[i] - t) <= tolerance else None


def interpolate_joints(stamps: np.ndarray, positions: np.ndarray, t: float, max_gap: float) -> np.ndarray | None:
    """Joint positions at time t, linear between the two joint-state messages around it; None when t lies
    outside the stream or the messages around it are more than max_gap seconds apart."""
    i = int(np.searchsorted(stamps, t))
    if i < len(stamps) and stamps[i] == t:
        return positions[i]
    if i == 0 or i == len(stamps) or stamps[i] - stamps[i - 1] > max_gap:
        return None
    w = (t - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
    return (1 - w) * positions[i - 1] + w * positions[i]


def intrinsics(info: dict, where: str) -> tuple[np.ndarray, int | None, int | None]:
    """K (and the image size if stated) from a camera_info-like mapping: ROS's `k` / `K` (9 numbers),
    camera_calibration's `camera_matrix: {data: [...]}`, or `fx, fy, cx, cy`."""
    values = info.get("k", info.get("K"))
    if values is None and isinstance(info.get("camera_matrix"), dict):
        values = info["camera_matrix"].get("data")
    if values is None and all(key in info for key in ("fx", "fy", "cx", "cy")):
        values = [info["fx"], 0, info["cx"], 0, info["fy"], info["cy"], 0, 0, 1]
    try:
        K = np.asarray(values, float).reshape(3, 3)
    except (TypeError, ValueError):
        raise UserError(f"{where}: no intrinsics; give k (9 numbers, row-major), camera_matrix.data, or fx, fy, cx, cy") from None
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise UserError(f"{where}: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    size = lambda key: int(info[key]) if key in info else None
    return K, size("width"), size("height")
