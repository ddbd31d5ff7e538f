"""One segment's full description: a trajectory and a camera that sees the end-effector throughout (or,
with the preset's `stations:` section, calibration stations where a marker board is seen: stations.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kernel.errors import UserError
from syneepose.preset import Preset
from syneepose.scene import hard
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
    cases = preset.hard
    exits = cases is not None and cases.exit is not None
    for _ in range(MAX_TRAJECTORIES):
        q = trajectory(rng, robot.arm.home, robot.arm.limits, n_frames, motion.waypoints, motion.spread)
        if not checks.above_floor(q, motion.clearance).all() or checks.self_collision(q).any():
            continue
        # where the end-effector leaves the image must suit the trajectory: each place of the run is tried
        runs = hard.exit_runs(rng, n_frames, cases.exit) if exits else [None]
        for _ in range(MAX_CAMERAS):
            for out in runs:
                spec = sample_segment(rng, preset, robot, robot.config, stream, seed, q, width, height, images,
                                      in_view=None if out is None else ~out)
                in_view, keep = np.ones(n_frames, bool), np.ones(n_frames, bool)
                if out is not None:
                    T_base_cam = hard.turned_away(spec, checks.ee_points(q), out, width, height, margin)
                    if T_base_cam is None:
                        continue
                    spec = replace(spec, T_base_cam=T_base_cam)
                    in_view, keep = ~out, ~out & ~hard.free_frames(out)
                if checks.accepts(q, spec.T_base_cam, spec.K, width, height, margin, min_visible, keep):
                    return _with_hard_cases(rng, preset, robot, checks, spec, in_view, width, height)
    rules = " and hard.exit's run out of view" if exits else ""
    raise UserError(f"{robot.config}: no trajectory and camera met the preset's visibility rules{rules} after "
                    f"{MAX_TRAJECTORIES} x {MAX_CAMERAS} attempts; widen its camera distance or lower "
                    f"camera.min_visible")


def _with_hard_cases(rng, preset: Preset, robot, checks: MotionChecks, spec: SegmentSpec, in_view: np.ndarray,
                     width: int, height: int) -> SegmentSpec:
    """The preset's occluder and arm-coloured objects added to an accepted segment (drawn last: a preset
    without them plans as before)."""
    cases = preset.hard
    if cases is None:
        return spec
    ee_path = robot.T_base_ee(spec.q)[:, :3, 3]
    if cases.occluder is not None:
        radius = float(np.linalg.norm(checks.points - checks.points.mean(0), axis=1).max())
        spec = replace(spec, occluders=[hard.occluder(rng, cases.occluder, preset, spec, ee_path, radius,
                                                      in_view)])
    if cases.arm_coloured is not None:
        objects, dropped = hard.arm_coloured(rng, cases.arm_coloured, spec, ee_path, hard.arm_colours(robot),
                                             width, height)
        spec = replace(spec, distractors=spec.distractors + objects,
                       dropped_distractors=spec.dropped_distractors + dropped)
    return spec
