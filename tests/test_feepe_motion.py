"""A first calibration from the robot's motion, RGB only and no mask (feepe/motion.py, issue 34): on frames of
an arm moving before a still, noisy background, a moving shadow beside it."""

import numpy as np
import trimesh

from feepe import motion
from feepe.robot_starts import RobotSamples
from feepe.silhouette import PartsSilhouette, SilhouetteModel
from kernel.transforms import inv_T, make_T, rotation_angle
from scipy.spatial.transform import Rotation

from tests.test_feepe_no_mask import K, SHAPE
from tests.test_feepe_robot_starts import _arm

BACKGROUND = (40, 60, 160)


def _looking_at(eye, target) -> np.ndarray:
    """T_cam_base of a camera at `eye` looking at `target` (base frame), the base's z up in the image."""
    forward = np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye))
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return inv_T(make_T(np.stack([right, np.cross(forward, right), forward], 1), eye))


T_CAM_BASE = _looking_at([0.9, -0.6, 0.75], [0.2, 0.1, 0.35])  # the whole arm in view, 1.1 m away


def _frames(n: int = 8):
    """n frames of the arm turning about its column by 10 deg each (hand, column, upper arm, forearm: the column
    stands still), grey with a red hand, on a noisy blue background with a dark patch (a shadow) sliding along
    below it; and each frame's parts' poses (base frame)."""
    rng = np.random.default_rng(0)
    meshes = _arm()
    parts = PartsSilhouette([SilhouetteModel(m, None) for m in meshes])
    background = np.clip(np.array(BACKGROUND) + rng.integers(-20, 20, SHAPE + (3,)), 0, 255)
    frames, poses = [], []
    for i in range(n):
        turn = make_T(Rotation.from_euler("z", 10 * i, degrees=True).as_matrix())
        T_base_parts = np.stack([turn, np.eye(4), turn, turn])
        T_cam_parts = np.einsum("ij,njk->nik", T_CAM_BASE, T_base_parts)
        drawn = np.stack([m.render_depth(T, K, SHAPE) for m, T in zip(parts.parts, T_cam_parts)]) > 0
        rgb = background.copy()
        shadow = np.zeros(SHAPE, bool)
        shadow[200:230, 20 + 12 * i:80 + 12 * i] = True
        rgb[shadow] = rgb[shadow] * 0.5
        rgb[drawn[1:].any(0)] = (190, 190, 185)
        rgb[drawn[0]] = (200, 40, 40)
        frames.append(rgb.astype(np.uint8))
        poses.append(T_base_parts)
    return meshes, frames, poses


def _clip(frames, poses, meshes) -> motion.MotionClip:
    samples = RobotSamples.of(meshes)
    clip = motion.MotionClip()
    for rgb, T_base_parts in zip(frames, poses):
        clip.add(rgb, K, samples.placed(T_base_parts)[0])
    return clip


def _error(T: np.ndarray) -> tuple[float, float]:
    d = inv_T(T_CAM_BASE) @ T
    return float(np.degrees(rotation_angle(d[:3, :3], np.eye(3)))), float(np.linalg.norm(T[:3, 3] - T_CAM_BASE[:3, 3]))


def test_a_moving_shadow_is_no_change_the_robot_is():
    meshes, frames, poses = _frames()
    fit = motion.MotionFit(_clip(frames, poses, meshes))
    first_last = np.flatnonzero((fit.a == 0) & (fit.b == len(frames) - 1))[0]
    assert fit.shadow[first_last, 208 // 4:228 // 4].any()  # where the shadow came and went
    assert not fit.changed[first_last, 208 // 4:228 // 4].any()
    assert fit.changed[first_last].sum() > 20 and fit.enough


def test_the_true_calibration_scores_best_and_the_search_comes_near_it():
    """The truth outscores itself turned by 5 deg or shifted by 5 cm; the search over rotations, with no start
    given, returns the truth within 5 deg and 5 cm first (a start the outline refinement takes from there)."""
    meshes, frames, poses = _frames()
    fit = motion.MotionFit(_clip(frames, poses, meshes))
    truth = fit.score(T_CAM_BASE)
    turned = T_CAM_BASE @ make_T(Rotation.from_euler("x", 5, degrees=True).as_matrix())
    assert truth > fit.score(turned) and truth > fit.score(make_T(T_CAM_BASE[:3, :3], T_CAM_BASE[:3, 3] + 0.05))
    found = motion.motion_starts(fit, keep=3)
    angle, offset = _error(found[0][0])
    assert angle < 5.0 and offset < 0.05, (angle, offset)


def test_a_still_robot_gives_no_start():
    meshes, frames, poses = _frames()
    still = [poses[0]] * len(frames)
    fit = motion.MotionFit(_clip([frames[0]] * len(frames), still, meshes))
    assert not fit.enough and motion.motion_starts(fit, keep=3) == []


def test_the_rotation_grid_covers_every_rotation_within_15_degrees():
    grid = motion.rotation_grid(motion.VIEWS, motion.ROLLS)
    assert np.allclose(np.einsum("nij,nkj->nik", grid, grid), np.eye(3)) and np.allclose(np.linalg.det(grid), 1)
    probes = Rotation.random(300, random_state=1).as_matrix()
    nearest = [np.degrees(rotation_angle(grid, R).min()) for R in probes]
    assert max(nearest) < 15.0
