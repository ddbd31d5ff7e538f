"""The peers that run here: marker hand-eye calibration and PPF + ICP, on data with known answers."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.handeye import METHODS, BoardDetector, calibrate
from feepe.ppf import PpfDetector, PpfOptions, _hash_table, voxel_sample
from feepe.icp import SurfaceModel
from kernel.errors import UserError
from kernel.transforms import make_T, rotation_angle, transform_points
from syneepose.scene.marker import MarkerBoard, board_pose, mount_facing_camera


def _random_T(rng, spread=0.3):
    return make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-spread, spread, 3))


@pytest.mark.parametrize("method", sorted(METHODS))
def test_hand_eye_on_exact_poses_recovers_the_calibration(method):
    rng = np.random.default_rng(0)
    T_cam_base = make_T(Rotation.from_euler("xyz", [2.2, 0.1, -0.7]).as_matrix(), [0.1, 0.2, 1.3])
    T_ee_board = _random_T(rng, 0.1)
    T_base_ee = [_random_T(rng, 0.4) for _ in range(10)]
    T_cam_board = [T_cam_base @ T @ T_ee_board for T in T_base_ee]
    T = calibrate(T_base_ee, T_cam_board, method)
    assert np.abs(T - T_cam_base).max() <= 1e-6
    with pytest.raises(UserError, match="at least 3 views"):
        calibrate(T_base_ee[:2], T_cam_board[:2])


def test_board_mount_faces_the_camera():
    board = MarkerBoard()
    # the tool axis across the view (a camera looking along it would see the board edge-on at any turn)
    T_cam_ee = np.stack([make_T(Rotation.from_euler("xz", [90, a], degrees=True).as_matrix(), [0, 0, 1.0])
                         for a in (0, 10, 20)])
    mounted = mount_facing_camera(board, T_cam_ee, radius=0.05)
    for T in T_cam_ee:
        T_cam_board = T @ mounted.T_ee_board
        centre = transform_points(T_cam_board, np.array([[board.size[0] / 2, board.size[1] / 2, 0.0]]))[0]
        assert T_cam_board[:3, 2] @ centre / np.linalg.norm(centre) > 0.9  # board z (into it) points away
    # the board's plane stands radius + clearance out from the tool axis, facing along (cos yaw, sin yaw, 0)
    corners = transform_points(board_pose(board, 0.3, 0.05, 0.01, 0.06),
                               np.array([[0, 0, 0], [board.size[0], board.size[1], 0.0]]))
    assert np.allclose(corners[:, :2] @ [np.cos(0.3), np.sin(0.3)], 0.06)
    assert MarkerBoard.from_json(mounted.to_json()).to_json() == mounted.to_json()
    with pytest.raises(UserError, match="dictionary"):
        MarkerBoard(dictionary="DICT_NOPE")


def test_detector_reports_corners_in_the_pixel_centre_convention():
    """A board drawn straight into an image (pattern corners on known pixel edges) is found there."""
    import cv2

    board = MarkerBoard()
    det = BoardDetector(board)
    px, k = 60, np.array([[800.0, 0, 0], [0, 800.0, 0], [0, 0, 1]])
    image = board.cv_board().generateImage((4 * px, 5 * px), marginSize=0)
    image = cv2.GaussianBlur(cv2.copyMakeBorder(image, 40, 40, 40, 40, cv2.BORDER_CONSTANT, value=255), (0, 0), 0.8)
    # 60 px per 5 cm square = 1200 px/m: a camera of focal 800 px at 2/3 m, facing the board, whose
    # pattern origin sits on the pixel edge 40, i.e. at 39.5 with pixel centres at integers
    k[0, 2] = k[1, 2] = 40 - 0.5
    T, n = det.T_cam_board(np.repeat(image[..., None], 3, -1), k)
    expect = make_T(np.eye(3), [0.0, 0.0, 800.0 / 1200.0])
    assert n == 12
    assert np.linalg.norm(T[:3, 3] - expect[:3, 3]) < 5e-4 and rotation_angle(T[:3, :3], np.eye(3)) < 1e-3


def test_ppf_finds_the_gripper_in_a_depth_scene(assets):
    model = SurfaceModel.from_ply(assets / "models" / "obj_000004.ply")
    det = PpfDetector(model)
    rng = np.random.default_rng(3)
    T = make_T(Rotation.random(random_state=rng).as_matrix(), [0.05, -0.03, 0.75])
    seen = SurfaceModel.from_ply(assets / "models" / "obj_000004.ply", n_points=3000, seed=7)
    P, N = transform_points(T, seen.points), seen.normals @ T[:3, :3].T
    front = np.sum(N * -P, 1) > 0  # the side facing the camera
    table = np.c_[rng.uniform(-0.3, 0.3, (800, 2)), np.full(800, 0.9)]  # clutter behind it
    points = np.concatenate([P[front], table])
    normals = np.concatenate([N[front], np.tile([0.0, 0.0, -1.0], (800, 1))])
    T_est, explained = det.detect(points, normals)
    assert np.linalg.norm(T_est[:3, 3] - T[:3, 3]) < 0.01 and np.rad2deg(rotation_angle(T_est[:3, :3], T[:3, :3])) < 5
    assert explained > 0.5
    capped = PpfDetector(model, PpfOptions(scene_step=1, max_references=40))  # a larger scene, a larger step
    assert 0 < len(capped._votes(points, normals)) <= 40 < len(points)


def test_ppf_votes_join_the_first_cluster_they_are_near():
    # the clusters' order decides where a vote near two of them goes (Drost's greedy clustering as we run it),
    # strongest vote first: B joins A; C, 0.15 from A (over a tenth of the diameter), opens its own; E lies
    # nearer C but joins A, opened first; D lies near A and C but turned 30 deg (2 angle bins: 24 deg)
    det = SimpleNamespace(diameter=1.0, opts=PpfOptions(hypotheses=5))
    turned = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    votes = [(8.0, make_T(np.eye(3), [0.15, 0, 0])),  # C
             (10.0, make_T(np.eye(3), [0, 0, 0])),  # A
             (1.0, make_T(turned, [0.07, 0, 0])),  # D
             (9.0, make_T(np.eye(3), [0.08, 0, 0])),  # B
             (2.0, make_T(np.eye(3), [0.09, 0, 0]))]  # E
    poses = PpfDetector._clusters(det, votes)
    assert len(poses) == 3
    np.testing.assert_allclose(poses[0][:3, 3], [(0.08 * 9 + 0.09 * 2) / 21, 0, 0], atol=1e-12)
    np.testing.assert_allclose(poses[1][:3, 3], [0.15, 0, 0], atol=1e-12)
    np.testing.assert_allclose(poses[2][:3, :3], turned, atol=1e-12)


def test_voxel_sample_means_each_occupied_voxel():
    """One point per occupied voxel, in lexicographic order of the voxels' indices (negative ones included), the
    mean of its points and the renormalised mean of its normals, as written out voxel by voxel."""
    rng = np.random.default_rng(3)
    points, normals = rng.normal(0, 0.2, (3000, 3)) + [0.1, -0.3, 0.8], rng.normal(size=(3000, 3))
    sampled, sampled_normals = voxel_sample(points, normals, 0.05)
    cells = np.floor(points / 0.05).astype(int)
    occupied = sorted(set(map(tuple, cells)))
    assert len(sampled) == len(occupied) < len(points)
    for k, cell in enumerate(occupied):
        inside = np.all(cells == cell, axis=1)
        mean_normal = normals[inside].sum(0)
        assert np.allclose(sampled[k], points[inside].mean(0), rtol=0, atol=1e-12)
        assert np.allclose(sampled_normals[k], mean_normal / np.linalg.norm(mean_normal), rtol=0, atol=1e-12)
    assert all(a.shape == (0, 3) for a in voxel_sample(np.zeros((0, 3)), np.zeros((0, 3)), 0.05))


def test_ppf_hash_table_orders_pairs_as_a_stable_sort_and_finds_each_keys_run():
    """The counting sort of the model's pair keys is np.argsort's stable order, and each key's run in it starts
    and ends where a binary search over the sorted keys puts it (a key no pair has: an empty run)."""
    keys = np.random.default_rng(5).integers(0, 500, 20000)
    keys = keys[keys != 17]
    order, first = _hash_table(keys)
    np.testing.assert_array_equal(order, np.argsort(keys, kind="stable"))
    ranked = keys[order]
    for k in (0, 17, 499, int(keys.max())):
        assert (first[k], first[k + 1]) == (np.searchsorted(ranked, k), np.searchsorted(ranked, k + 1))
    assert first[17] == first[18]
    assert len(first) == keys.max() + 2 and _hash_table(np.zeros(0, np.int64))[1].tolist() == [0]
