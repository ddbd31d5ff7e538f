"""Metrics against hand-computed answers: ADD / ADD-S, AUC closed forms, pose and calibration errors."""

import json

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from eval.metrics import add, adds, auc, calibration_error, rotation_error_deg, translation_error_mm
from eval.model_points import load_model_points
from syneepose.transforms import axis_angle_to_R, make_T, transform_points

NAN_POSE = np.full((4, 4), np.nan)


def _random_pose(rng) -> np.ndarray:
    return make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.5, 0.5, 3))


def test_add_and_adds_by_hand():
    line = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0]])
    quarter = np.array([[0.05, 0, 0], [0, 0.05, 0]])
    shift = make_T(t=[0.01, 0, 0])
    turn = make_T(axis_angle_to_R([0, 0, 1], np.pi / 2))
    # Line shifted by one spacing: every point moves 1 cm; two GT points land on an estimate point.
    assert add(shift, np.eye(4), line) == pytest.approx([0.01], abs=1e-15)
    assert adds(shift, np.eye(4), line) == pytest.approx([0.01 / 3], abs=1e-15)
    # Quarter turn: each point moves 5 cm x sqrt 2; (0, 5 cm) is where (5 cm, 0) went, so ADD-S halves.
    assert add(turn, np.eye(4), quarter) == pytest.approx([0.05 * np.sqrt(2)], abs=1e-15)
    assert adds(turn, np.eye(4), quarter) == pytest.approx([0.05 * np.sqrt(2) / 2], abs=1e-15)


def test_vectorised_over_frames_with_failures():
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.1, 0.1, (300, 3))
    T_gt = np.stack([_random_pose(rng) for _ in range(5)])
    T_est = T_gt @ make_T(t=[0.0, 0.003, 0.0])  # 3 mm in the model frame: ADD exactly 3 mm
    T_est[2] = NAN_POSE
    got_add, got_adds = add(T_est, T_gt, points), adds(T_est, T_gt, points)
    assert np.isinf(got_add[2]) and np.isinf(got_adds[2])
    assert np.delete(got_add, 2) == pytest.approx([0.003] * 4, abs=1e-12)
    nothing = np.stack([NAN_POSE] * 2)
    assert np.isinf(add(nothing, T_gt[:2], points)).all() and np.isinf(adds(nothing, T_gt[:2], points)).all()


def test_adds_matches_a_tree_per_estimate_and_never_exceeds_add():
    """The one-tree trick against bop_toolkit's way (a tree of the estimate-posed points per frame)."""
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.1, 0.1, (400, 3))
    T_gt = np.stack([_random_pose(rng) for _ in range(60)])
    T_est = np.stack([_random_pose(rng) for _ in range(30)] +
                     [T @ make_T(Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix(), rng.normal(0, 0.01, 3))
                      for T in T_gt[30:]])
    got = adds(T_est, T_gt, points)
    naive = [cKDTree(transform_points(Te, points)).query(transform_points(Tg, points))[0].mean()
             for Te, Tg in zip(T_est, T_gt)]
    assert got == pytest.approx(naive, abs=1e-12)
    assert (got <= add(T_est, T_gt, points) + 1e-15).all()


def test_adds_vanishes_under_the_2f85_symmetry_while_add_does_not(assets):
    models = assets / "models"
    info = json.loads((models / "models_info.json").read_text())["2"]
    S = np.array(info["symmetries_discrete"][0]).reshape(4, 4)  # 180 deg about z, no translation
    vertices = np.unique(np.asarray(trimesh.load(models / "obj_000002.ply", process=False).vertices), axis=0) / 1000
    rng = np.random.default_rng(2)
    T_gt = np.stack([_random_pose(rng) for _ in range(3)])
    T_est = T_gt @ S
    # A half turn about z moves (x, y, z) to (-x, -y, z): a distance of 2 |(x, y)|.
    assert add(T_est, T_gt, vertices) == pytest.approx([2 * np.linalg.norm(vertices[:, :2], axis=1).mean()] * 3)
    assert add(T_est, T_gt, vertices).min() > 0.05
    assert adds(T_est, T_gt, vertices).max() < 1e-4
    # The evaluator's subsample keeps the symmetry (a plain random one of 2000 points gives ~0.9 mm).
    model = load_model_points(models, 2)
    assert model.subsampled and len(model.points) <= 2000 and model.n_unique == len(vertices)
    assert adds(T_est, T_gt, model.points).max() < 1e-4


def test_auc_closed_forms():
    cm = 0.01
    assert auc(np.zeros(10), cm) == pytest.approx(100.0, abs=1e-12)
    assert auc([np.inf, np.nan, np.inf], cm) == 0.0
    assert auc([0.0, np.inf], cm) == pytest.approx(50.0, abs=1e-12)
    uniform = np.linspace(0.0, cm, 100_001)  # F(x) = x / max: area 1/2
    assert auc(uniform, cm) == pytest.approx(50.0, abs=0.1)
    assert auc(np.linspace(0.0, 2 * cm, 200_001), cm) == pytest.approx(25.0, abs=0.1)
    assert auc(cm * np.sqrt(np.linspace(0.0, 1.0, 100_001)), cm) == pytest.approx(100 / 3, abs=0.1)  # F = (x/max)^2
    assert auc(np.full(7, 0.003), cm) == pytest.approx(70.0, abs=0.1)  # a step at 3 mm
    assert auc(np.full(7, 0.003), 2 * cm) == pytest.approx(85.0, abs=0.1)


def test_rotation_and_translation_errors():
    R = axis_angle_to_R([1.0, 2.0, -0.5], np.radians(30.0))
    T_gt = make_T(Rotation.random(random_state=3).as_matrix(), [0.1, 0.2, 0.9])
    T_est = make_T(R @ T_gt[:3, :3], T_gt[:3, 3] + [0.003, 0.004, 0.0])
    assert rotation_error_deg(T_est, T_gt) == pytest.approx([30.0], abs=1e-9)
    assert translation_error_mm(T_est, T_gt) == pytest.approx([5.0], abs=1e-9)


def test_calibration_error_at_workspace_points():
    T_gt = make_T(Rotation.random(random_state=4).as_matrix(), [0.2, -0.1, 1.3])
    points = np.array([[0.5, 0.0, 0.0], [0.0, 0.3, 0.2], [0.0, 0.0, 0.4], [0.3, 0.4, 0.0], [-0.2, 0.1, 0.1]])
    theta = np.radians(1.0)
    turned = T_gt @ make_T(axis_angle_to_R([0, 0, 1], theta))  # base turned about its own z axis
    shifted = make_T(t=[0.0, 0.002, 0.0]) @ T_gt  # camera-frame offset of 2 mm
    err = calibration_error(np.stack([turned, shifted, NAN_POSE]), T_gt, points)
    chord = 2 * np.linalg.norm(points[:, :2], axis=1) * np.sin(theta / 2) * 1000  # |R_z(theta) p - p|
    assert err.trans_mm[:2] == pytest.approx([0.0, 2.0], abs=1e-9)
    assert err.rot_deg[:2] == pytest.approx([1.0, 0.0], abs=1e-7)
    assert err.points_mm[0] == pytest.approx(chord, abs=1e-9)
    assert err.points_mm[1] == pytest.approx([2.0] * 5, abs=1e-9)
    assert np.isnan(err.trans_mm[2]) and np.isnan(err.points_mm[2]).all()
