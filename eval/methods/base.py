"""What the runner hands a method and what it gets back. Methods never see the ground truth: the
observation holds sensor data and robot state only, and the scene meta they get has T_cam_base = NaN."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from kernel.bop import SceneMeta


@dataclass
class Observation:
    im_id: int
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray | None  # (H, W) metres, 0 = no depth; None with `--depth-dir none` (an RGB camera)
    mask: np.ndarray | None  # (H, W) bool: the visible end-effector (the paper gives every method GT masks);
    # None with `--masks none`: no mask of any kind
    K: np.ndarray  # (3, 3)
    joint_positions: np.ndarray  # (n,)
    T_base_ee: np.ndarray  # (4, 4) metres, forward kinematics of the joint positions
    robot_mask: np.ndarray | None = None  # (H, W) bool: the visible robot, arm and end-effector (None: not rendered)


@dataclass
class Estimate:
    T_cam_ee: np.ndarray | None  # (4, 4) metres; None = no estimate (scored as a failure)
    score: float
    time_s: float  # the method's own time for this frame (BOP `time`); -1 unknown
    T_cam_base: np.ndarray | None = None  # the camera-to-base calibration so far, if the method makes one
    extra: dict = field(default_factory=dict)
    masks: dict | None = None  # the method's own visible masks, "ee" and "robot" (H, W) bool, when it makes them
    # ({} for a frame it has none for); None: it makes no masks


class Method(Protocol):
    """A method class declares its options as a dataclass, `Options`, of `eval.methods.option` fields (the
    command line is made from it) and is built with one instance of it."""

    name: str
    Options: type

    def options(self) -> dict:
        """Everything that sets the method's behaviour, JSON-able (goes into summary.json)."""

    def start_scene(self, meta: SceneMeta, scene_dir: Path) -> None:
        """A new video segment begins: reset any memory."""

    def check(self, scenes: dict[int, list[int]], split_dir: Path) -> None:
        """Optional: validate what the method reads against the data set (scene id -> frame ids) before the
        run writes anything; raise UserError naming the file and the problem."""

    def given(self, masks: bool, depth: bool) -> None:
        """Optional: told once, before the run writes anything, whether the observations will hold masks
        (`--masks given`) and depth (not `--depth-dir none`); raise UserError when the method needs what is
        not given, or set itself up for what is."""

    def inputs(self, meta: SceneMeta, scene_dir: Path) -> list[Path]:
        """Optional: the files or folders the method reads for this scene besides its frames (templates,
        models, a results file), so that a rerun scores the scene again when they change."""

    def estimate(self, obs: Observation) -> Estimate:
        """One frame, in frame order (online)."""
