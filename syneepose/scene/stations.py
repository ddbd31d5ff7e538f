"""Calibration stations as a careful marker hand-eye user picks them (the preset's `stations:` section).

A practitioner bolts the board to the flange facing the camera and drives the arm to poses where the board
is seen whole, face-on within a tilt limit and unoccluded, spread in orientation because hand-eye solvers
(Tsai-Lenz and its successors) need rotations about several axes. Here: one camera, a pool of arm poses
drawn around home, the board's turn about the tool axis that faces the camera in most of them, then the
poses that pass every rule, chosen greedily farthest apart in end-effector orientation. Frames are
stations, not a smooth motion. Nothing depends on whether the board is drawn, so the same command
without `--marker` renders the marker-free twin.
"""

from __future__ import annotations

import numpy as np

from kernel.errors import UserError
from kernel.transforms import inv_T, rotation_angle, transform_points
from syneepose.preset import Preset
from syneepose.scene.marker import MarkerBoard, board_from_preset, board_pose, facing
from syneepose.scene.motion import IN_VIEW, MotionChecks
from syneepose.scene.sample import rng_for, sample_segment
from syneepose.scene.spec import SegmentSpec

MAX_CAMERAS, YAW_STEPS = 20, 72


def spread_apart(R: np.ndarray, n: int, first: int) -> list[int]:
    """Greedy farthest-point choice of n rotations (geodesic angle), starting from index `first`."""
    chosen = [first]
    nearest = np.array([rotation_angle(R[first], r) for r in R])
    while len(chosen) < n:
        k = int(np.argmax(nearest))
        chosen.append(k)
        nearest = np.minimum(nearest, [rotation_angle(R[k], r) for r in R])
    return chosen


def plan_stations(preset: Preset, robot, checks: MotionChecks, stream: int, seed: int, n_frames: int,
                  width: int, height: int, images: list[str] | None = None) -> SegmentSpec:
    rules = preset.stations
    board, mount = board_from_preset(preset)
    rng = rng_for(seed, robot.config, stream)
    motion = preset.motion
    lo, hi = np.asarray(robot.arm.limits, float).T
    home = np.asarray(robot.arm.home, float)
    min_visible, margin = preset.camera.min_visible, preset.camera.margin
    radius = float(np.hypot(checks.hull_ee.vertices[:, 0], checks.hull_ee.vertices[:, 1]).max())
    cos_tilt = np.cos(np.deg2rad(rules.max_tilt_deg))
    for _ in range(MAX_CAMERAS):
        pool = np.clip(home + rng.uniform(-1, 1, (rules.pool, len(home))) * motion.spread, lo, hi)
        pool = pool[checks.above_floor(pool, motion.clearance)]
        pool = pool[~checks.self_collision(pool)]
        if len(pool) < n_frames:
            continue
        spec = sample_segment(rng, preset, robot, robot.config, stream, seed, pool, width, height, images)
        T_cam_ee = inv_T(spec.T_base_cam) @ robot.T_base_ee(pool)
        mounts = [board_pose(board, yaw, radius, **mount) for yaw in np.linspace(0, 2 * np.pi, YAW_STEPS, False)]
        counts = [np.sum(facing(T_cam_ee @ T, board) >= cos_tilt) for T in mounts]
        T_ee_board = mounts[int(np.argmax(counts))]
        keep = np.flatnonzero(facing(T_cam_ee @ T_ee_board, board) >= cos_tilt)
        if len(keep) < n_frames:
            continue
        corners = transform_points(T_ee_board, board.corners())
        inside, seen = checks.seen(pool[keep], spec.T_base_cam, spec.K, width, height, corners, margin,
                                   ee_occludes=True)
        keep = keep[(inside >= 1.0) & (seen >= 1.0)]
        inside, visible = checks.check(pool[keep], spec.T_base_cam, spec.K, width, height, margin)
        keep = keep[(inside >= IN_VIEW) & (visible >= min_visible)]
        if len(keep) < n_frames:
            continue
        R = robot.T_base_ee(pool[keep])[:, :3, :3]
        chosen = keep[spread_apart(R, n_frames, int(rng.integers(len(keep))))]
        spec.q = pool[chosen]
        spec.marker = MarkerBoard(board.dictionary, board.squares, board.square, board.marker, board.margin,
                                  T_ee_board)
        return spec
    raise UserError(f"{robot.config}: fewer than {n_frames} stations showed the whole board within "
                    f"{rules.max_tilt_deg} deg of face-on for each of {MAX_CAMERAS} cameras; raise "
                    "stations.max_tilt_deg or stations.pool, or move the camera closer (camera.distance)")
