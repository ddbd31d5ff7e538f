"""Metrics against hand-computed answers: ADD / ADD-S, AUC closed forms, pose and calibration errors."""

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from eval.metrics import add, adds, auc, calibration_error, rotation_error_deg, translation_error_mm
from eval.model_points import MAX_QUERY, load_eval_model
from kernel.bop import read_frame, read_scene, split_dir
from kernel.dataset import MODELS_EVAL
from kernel.transforms import axis_angle_to_R, make_T, transform_points

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
    """On every vertex of the evaluation model; the remeshed vertices are not themselves symmetric, so a
    symmetric pose leaves ADD-S at the nearest-vertex distance (well under the vertex spacing)."""
    model = load_eval_model(assets, 2, max_query=None)
    info = json.loads((assets / MODELS_EVAL / "models_info.json").read_text())["2"]
    S = np.array(info["symmetries_discrete"][0]).reshape(4, 4)  # 180 deg about z, no translation
    rng = np.random.default_rng(2)
    T_gt = np.stack([_random_pose(rng) for _ in range(3)])
    T_est = T_gt @ S
    # A half turn about z moves (x, y, z) to (-x, -y, z): a distance of 2 |(x, y)|.
    radial = 2 * np.linalg.norm(model.vertices[:, :2], axis=1).mean()
    assert add(T_est, T_gt, model.vertices) == pytest.approx([radial] * 3)
    assert add(T_est, T_gt, model.vertices).min() > 0.05
    assert adds(T_est, T_gt, model.vertices, model.tree).max() < 3e-4


def _perturbed(frames_T: np.ndarray, per_frame: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Estimates as a good method makes them: a few mm and degrees off each ground-truth pose."""
    T_gt = np.repeat(frames_T, per_frame, axis=0)
    noise = np.tile(np.eye(4), (len(T_gt), 1, 1))
    noise[:, :3, :3] = Rotation.from_rotvec(rng.normal(0.0, np.radians(2.0), (len(T_gt), 3))).as_matrix()
    noise[:, :3, 3] = rng.normal(0.0, 0.003, (len(T_gt), 3))
    return T_gt @ noise, T_gt


def _rendered_gt(dataset) -> dict[int, np.ndarray]:
    """obj_id -> the ground-truth poses of every frame of the rendered data set."""
    poses = {}
    for scene in sorted(split_dir(dataset).iterdir()):
        meta, im_ids = read_scene(scene)
        poses.setdefault(meta.obj_id, []).extend(read_frame(scene, i).T_cam_ee for i in im_ids)
    return {obj_id: np.stack(T) for obj_id, T in poses.items()}


def _brute_force(T_est, T_gt, vertices) -> tuple[np.ndarray, np.ndarray]:
    """BOP's add / adi written plainly: all vertices posed twice, every pair of distances for ADD-S."""
    add_m, adds_m = [], []
    for Te, Tg in zip(T_est, T_gt):
        est, gt = transform_points(Te, vertices), transform_points(Tg, vertices)
        add_m.append(np.linalg.norm(est - gt, axis=1).mean())
        adds_m.append(np.concatenate([cdist(block, est).min(axis=1) for block in np.array_split(gt, 40)]).mean())
    return np.array(add_m), np.array(adds_m)


def test_bop_metrics_exactly_on_a_rendered_scene(tiny_dataset):
    """With every vertex as query, ADD and ADD-S equal the brute-force BOP definitions to 1e-6 m."""
    rng = np.random.default_rng(3)
    for obj_id, frames_T in _rendered_gt(tiny_dataset).items():
        if obj_id != 2:  # the 2F-85 (64k vertices) keeps the all-pairs check near ten seconds
            continue
        model = load_eval_model(tiny_dataset, obj_id, max_query=None)
        points, weights = model.query_points([(0, 0), (0, 1)])
        assert not model.subsampled and weights is None and points is model.vertices
        assert len(model.vertices) == len(np.unique(model.vertices, axis=0))
        T_est, T_gt = _perturbed(frames_T[:2], 1, rng)
        want_add, want_adds = _brute_force(T_est, T_gt, model.vertices)
        assert add(T_est, T_gt, points) == pytest.approx(want_add, abs=1e-6)
        assert adds(T_est, T_gt, points, model.tree) == pytest.approx(want_adds, abs=1e-6)
        assert (want_adds > 1e-4).all()  # the perturbation is large enough to be a check


def test_query_subsample_keeps_the_auc_of_all_vertices(tiny_dataset):
    """The evaluator's default (one vertex drawn per cell and frame, at most MAX_QUERY cells, the whole
    model searched) against every vertex: AUC of ADD and ADD-S at 1 and 2 cm within 0.1 points on
    perturbed rendered ground truth."""
    rng = np.random.default_rng(4)
    for obj_id, frames_T in _rendered_gt(tiny_dataset).items():
        full = load_eval_model(tiny_dataset, obj_id, max_query=None)
        sub = load_eval_model(tiny_dataset, obj_id)
        assert sub.subsampled and 0.9 * MAX_QUERY < sub.n_query <= MAX_QUERY  # a real subsample
        T_est, T_gt = _perturbed(frames_T, 40, rng)
        points, weights = sub.query_points([(obj_id, i) for i in range(len(T_gt))])
        assert points.shape == (len(T_gt), sub.n_query, 3) and weights.sum() == pytest.approx(1.0)
        for exact, estimate in ((add(T_est, T_gt, full.vertices), add(T_est, T_gt, points, weights)),
                                (adds(T_est, T_gt, full.vertices, full.tree),
                                 adds(T_est, T_gt, points, sub.tree, weights))):
            for max_error in (0.01, 0.02):
                assert abs(auc(estimate, max_error) - auc(exact, max_error)) < 0.1
            assert 20 < auc(exact, 0.01) < 90  # errors spread over the curve, not all 0 or all beyond


def test_query_draws_are_per_frame_reproducible_and_unbiased(assets):
    """One vertex per cell, drawn from the frame's own key: the same key gives the same points whatever
    else is drawn with it, other keys give other points, and the weighted mean of a function of the
    vertices averages to its mean over every vertex (the estimate BOP's mean is replaced by is unbiased)."""
    model = load_eval_model(assets, 2)
    cells = model.cells
    alone, _ = model.query_points([(7, 3)])
    batch, weights = model.query_points([(7, 2), (7, 3), (8, 3)])
    np.testing.assert_array_equal(alone[0], batch[1])
    assert not np.array_equal(batch[0], batch[1]) and not np.array_equal(batch[1], batch[2])
    index = {tuple(v): i for i, v in enumerate(model.vertices)}
    picked = np.array([index[tuple(v)] for v in batch[1]])
    owner = np.empty(len(model.vertices), dtype=int)
    owner[cells.order] = np.repeat(np.arange(len(cells.counts)), cells.counts)
    np.testing.assert_array_equal(owner[picked], np.arange(len(cells.counts)))  # one vertex in each cell
    f = np.linalg.norm(model.vertices - [0.01, 0.02, 0.03], axis=1) ** 3  # any function of the vertex
    draws, weights = model.query_points([(0, i) for i in range(400)])
    estimates = (np.linalg.norm(draws - [0.01, 0.02, 0.03], axis=-1) ** 3) @ weights
    spread = estimates.std() / np.sqrt(len(estimates))
    assert spread > 0 and abs(estimates.mean() - f.mean()) < 4 * spread


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
