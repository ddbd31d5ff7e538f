"""Calibration starts from the robot's depth (feepe/robot_starts.py): an asymmetric arm seen from its front,
with false blobs and depth noise, gives a start near the true camera-to-base pose; too few points give none."""

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from feepe.robot_starts import RobotSamples, robot_starts
from kernel.transforms import inv_T, make_T, rotation_angle, transform_points

T_CAM_BASE = make_T(Rotation.from_euler("xyz", [-2.0, 0.3, 0.7]).as_matrix(), [0.1, -0.2, 1.4])


def _arm() -> list[trimesh.Trimesh]:
    """A column, an upper arm and a forearm bent two ways, and a small hand: no symmetry left."""
    column = trimesh.creation.box([0.12, 0.12, 0.5], make_T(t=[0.0, 0.0, 0.25]))
    upper = trimesh.creation.box([0.4, 0.08, 0.08], make_T(t=[0.2, 0.0, 0.5]))
    fore = trimesh.creation.box([0.06, 0.3, 0.06], make_T(t=[0.4, 0.15, 0.5]))
    hand = trimesh.creation.box([0.05, 0.05, 0.1], make_T(t=[0.4, 0.3, 0.45]))
    return [hand, column, upper, fore]


def test_front_view_with_blobs_and_noise_gives_a_start_near_the_truth():
    meshes = _arm()
    model = np.concatenate(RobotSamples.of(meshes).points)
    rng = np.random.default_rng(1)
    dense = trimesh.util.concatenate(meshes).sample(6000, seed=2)
    in_cam = transform_points(T_CAM_BASE, dense)
    normals_toward = in_cam[:, 2] < np.median(in_cam[:, 2])  # the near half: what a camera sees
    seen = in_cam[normals_toward][:500] + rng.normal(0, 0.003, (500, 3))
    blobs = rng.uniform(-0.3, 0.3, (40, 3)) + in_cam.mean(0)  # a segmenter's false pixels, elsewhere
    pivot_base = np.array([0.4, 0.3, 0.45])
    pivot_cam = transform_points(T_CAM_BASE, pivot_base[None])[0] + [0.0, 0.0, -0.02]  # seen on the surface
    starts = robot_starts(model, np.concatenate([seen, blobs]), pivot_base, pivot_cam)
    assert len(starts) == 3
    angle = min(np.degrees(rotation_angle(T[:3, :3], T_CAM_BASE[:3, :3])) for T in starts)
    offset = min(np.linalg.norm((inv_T(T) @ T_CAM_BASE)[:3, 3]) for T in starts)
    assert angle < 3.0 and offset < 0.02


def test_too_few_points_give_no_start():
    model = np.concatenate(RobotSamples.of(_arm()).points)
    assert robot_starts(model, np.zeros((5, 3)), np.zeros(3), np.ones(3)) == []
