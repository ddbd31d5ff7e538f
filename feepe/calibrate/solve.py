"""The estimator run over a recording, frame by frame as eval.run runs it over a BOP scene, and then each
frame checked against the final calibration: the robot's outline and depth rendered there against what the
frame shows."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from feepe.backbones import DEFAULT as DEFAULT_BACKBONE
from feepe.backbones import get_backbone
from feepe.calibrate.recording import RecordedFrame, Recording
from feepe.calibrate.robot import UrdfRobot
from feepe.estimator import Estimator, FeepeOptions, RobotView, fitting_own_masks, load_models
from feepe.onboarding import onboard
from feepe.registration import depth_tolerance
from feepe.silhouette import PartsSilhouette, SilhouetteModel, outline_pixels, placed
from kernel.errors import UserError

MASKS = ("none", "given")


@dataclass(frozen=True)
class SolveSettings:
    templates: Path  # the end-effector's template set
    model: Path  # the end-effector's BOP model (.ply, mm) in the end-effector link's frame
    masks: str = "none"  # none: the estimator segments the robot itself; given: the recording's masks as a prior
    backbone: str = DEFAULT_BACKBONE


@dataclass
class FrameOutcome:
    name: str
    stamp: float
    T_base_ee: np.ndarray  # (4, 4) from the robot's state
    T_cam_base: np.ndarray | None  # the estimator's calibration after this frame; None: no estimate yet
    ms: float
    robot_mask: np.ndarray | None = None  # the estimator's own robot mask (packed bits), for the check
    key_frame: bool = False  # held in the estimator's memory at the end (its refinement fits these)
    outline_px: float = float("nan")  # at the final calibration: mean distance of the model's outline to the mask's
    outline_mm: float = float("nan")  # the same distances as lengths at the robot (px x depth / focal length)
    pixel_mm: float = float("nan")  # a pixel's width at the robot (median model depth / focal length)
    depth_mm: float = float("nan")  # median |sensor - model| depth over the model's pixels that agree
    depth_agree: float = float("nan")  # share of the model's pixels with depth that agree


@dataclass
class Solve:
    T_cam_base: np.ndarray | None  # after the last frame
    frames: list[FrameOutcome]
    options: dict  # the estimator's, as eval.run records them
    parts: PartsSilhouette  # the robot's meshes as the estimator renders them, for the check


def estimator_for(settings: SolveSettings, robot: UrdfRobot | None, has_depth: bool) -> Estimator:
    """With the robot's joints: the robot's outline fitted to the estimator's own segmentation (masks given
    enter it as a prior), with depth where there is depth, as eval.run's `--masks none`. With flange poses
    only: the end-effector's outline fitted to the masks given."""
    if robot is None and settings.masks == "none":
        raise UserError("with flange poses instead of joint states the robot's links cannot be placed, so the "
                        "end-effector's masks are needed: give masks/ and --masks given, or record joint states")
    if robot is not None:
        opts = fitting_own_masks(FeepeOptions(given_masks="prior" if settings.masks == "given" else "truth"),
                                 has_depth)
    else:
        opts = FeepeOptions(refine="silhouette")
    for flag, path in (("--templates", settings.templates), ("--model", settings.model)):
        if not Path(path).exists():
            raise UserError(f"{flag} {path} does not exist")
    backbone = get_backbone(settings.backbone)
    bank = onboard(settings.templates, backbone, opts.single.pad, {"assignment": "foundpose"})
    model, silhouette = load_models(Path(settings.model), opts)
    estimator = Estimator(bank, backbone, opts, model, silhouette)
    arm = [SilhouetteModel(robot.link_mesh(name)) for name in robot.arm_links] if robot is not None else None
    estimator.reset(arm=arm)
    return estimator


def solve(recording: Recording, robot: UrdfRobot | None, settings: SolveSettings, progress: bool = True,
          keep=None) -> Solve:
    """`keep(frame)`, if given, sees every frame as read (the saved samples)."""
    frames = recording.read()
    first = next(frames, None)
    if first is None:
        raise UserError(f"{recording.source}: no frame to read")
    estimator = estimator_for(settings, robot if first.joints is not None else None, first.depth is not None)
    outcomes = []
    for frame in tqdm(_chain(first, frames), total=recording.count, desc="calibrate", unit="frame",
                      disable=not progress):
        if keep is not None:
            keep(frame)
        T_base_ee, view = _robot_state(robot, frame)
        mask = frame.mask if settings.masks == "given" else None
        if settings.masks == "given" and mask is None:
            raise UserError(f"frame {frame.name}: --masks given but no mask for it; give masks/{frame.name}.png or "
                            "use --masks none")
        result = estimator.step(frame.rgb, frame.depth, mask, frame.K, T_base_ee, view)
        own = None if not result.masks else np.packbits(result.masks["robot"])
        outcomes.append(FrameOutcome(frame.name, frame.stamp, T_base_ee, result.T_cam_base, result.timings["total"],
                                     own))
    for entry in estimator.pool.entries:
        outcomes[entry.frame].key_frame = True
    return Solve(estimator.T_cam_base, outcomes, estimator.options(), estimator.parts)


def check(solve_: Solve, recording: Recording, robot: UrdfRobot | None, on_frame=None) -> None:
    """Each frame's residuals at the final calibration (the recording read again: no frame is held in
    memory). `on_frame(name, rgb, rendered depth, residuals text)` sees each frame as it is checked."""
    if solve_.T_cam_base is None or robot is None:
        return
    outcomes = iter(solve_.frames)
    for frame in recording.read():
        outcome = next(outcomes)
        if frame.joints is None:  # flange poses: the robot's links cannot be placed
            return
        poses = robot.poses(frame.joints)
        T_base_parts = np.concatenate([poses.T_base_ee[None], poses.T_base_links])
        shape = frame.rgb.shape[:2]
        rendered = solve_.parts.render_depth(placed(solve_.T_cam_base, T_base_parts), frame.K, shape)
        if rendered.any():
            outcome.pixel_mm = float(np.median(rendered[rendered > 0]) / frame.K[0, 0] * 1e3)
        if outcome.robot_mask is not None:
            seen = np.unpackbits(outcome.robot_mask)[:shape[0] * shape[1]].reshape(shape).astype(bool)
            outcome.outline_px, outcome.outline_mm = outline_distance(rendered, seen, frame.K[0, 0])
        if frame.depth is not None:
            drawn = (rendered > 0) & (frame.depth > 0)
            error = np.abs(frame.depth - rendered)
            close = drawn & (error < depth_tolerance(rendered))
            if drawn.any():
                outcome.depth_agree = np.count_nonzero(close) / np.count_nonzero(drawn)
            if close.any():
                outcome.depth_mm = float(np.median(error[close]) * 1e3)
        if on_frame is not None:
            on_frame(frame.name, frame.rgb, rendered, f"outline {outcome.outline_px:.2f} px, depth {outcome.depth_mm:.1f} mm")


def outline_distance(rendered: np.ndarray, seen: np.ndarray, focal_px: float) -> tuple[float, float]:
    """Mean distance from the model's outline pixels (`rendered`: its depth, 0 off it) to the seen mask's
    outline: in pixels, and as a length at the model's depth there (mm)."""
    edge, drawn = outline_pixels(seen), outline_pixels(rendered > 0)
    if not edge.any() or not drawn.any():
        return float("nan"), float("nan")
    distance = cv2.distanceTransform((~edge).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[drawn]
    return float(np.mean(distance)), float(np.mean(distance * rendered[drawn]) / focal_px * 1e3)


def _robot_state(robot: UrdfRobot | None, frame: RecordedFrame) -> tuple[np.ndarray, RobotView | None]:
    if frame.joints is None:
        return frame.T_base_ee, None
    poses = robot.poses(frame.joints)
    return poses.T_base_ee, RobotView(None, poses.T_base_links)


def _chain(first, rest):
    yield first
    yield from rest
