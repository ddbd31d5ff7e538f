"""One segment's full description: a trajectory and a camera that sees the end-effector throughout (or,
with the preset's `stations:` section, calibration stations where a marker board is seen: stations.py)."""

from __future__ import annotations

import numpy as np

from kernel.errors import UserError
from syneepose.preset import Preset
from syneepose.scene.motion import MotionChecks, trajectory
from syneepose.scene.sample import rng_for, sample_segment
from syneepose.scene.spec import SegmentSpec

MAX_TRAJECTORIES, MAX_CAMERAS = 30, 10


def plan_segment(preset: Preset, robot, checks: MotionChecks, stream: int, seed: int, n_frames: int,
                 width: int, height: int, images: list[str] | None = None) -> SegmentSpec:
    if preset.stations is not None:
        from syneepose.scene.stations import plan_stations

        return plan_stations(preset, robot, checks, stream, seed, n_frames, width, height, images)
    rng = rng_for(seed, robot.config, stream)
    motion, min_visible, margin = preset.motion, preset.camera.min_visible, preset.camera.margin
    for _ in range(MAX_TRAJECTORIES):
        q = trajectory(rng, robot.arm.home, robot.arm.limits, n_frames, motion.waypoints, motion.spread)
        if not checks.above_floor(q, motion.clearance).all() or checks.self_collision(q).any():
            continue
        for _ in range(MAX_CAMERAS):
            spec = sample_segment(rng, preset, robot, robot.config, stream, seed, q, width, height, images)
            inside, visible = checks.check(q, spec.T_base_cam, spec.K, width, height, margin)
            if np.all(inside >= 0.999) and np.all(visible >= min_visible):
                return spec
    raise UserError(f"{robot.config}: no trajectory and camera met the preset's visibility rules after "
                    f"{MAX_TRAJECTORIES} x {MAX_CAMERAS} attempts; widen its camera distance or lower "
                    f"camera.min_visible")
