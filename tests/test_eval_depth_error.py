"""`python -m eval.depth_error` on a data set written to have a known answer: every statistic it prints is
derived by hand below, not recomputed with the code under test."""

import numpy as np

from eval.depth_error import ee_depth_errors, main
from kernel.bop import DEPTH_SCALE, Frame, SceneMeta, SceneWriter
from kernel.dataset import Dataset

H, W = 30, 40
GT_M = 1.0  # exact depth everywhere (10000 PNG units at DEPTH_SCALE 0.1 mm: every error below is a whole unit)
# 2F-85: 501 end-effector pixels with errors (k - 300) x 0.1 mm, k = 0..500, i.e. -30.0 .. +20.0 mm, and 167
# holes. By hand: median = error of k = 250 = -5.0 mm; 10th / 90th percentiles (numpy's linear rule, indices
# 50 / 450 of 501, whole) = -25.0 / +15.0 mm; |err|: 1 + 2n values lie within n x 0.1 mm (n <= 200), so the
# 251st smallest, the median, is 12.5 mm; holes 167 / (501 + 167) = 25.0 %.
ERRORS_MM = (np.arange(501) - 300) * 0.1
HOLES = 167
# Kinova 3F: 100 pixels all 2.0 mm short, no holes.
EXPECTED = ["kinova_3f: median -2.0 mm, |err| median 2.0 mm, 10-90% [-2.0, -2.0] mm, no depth on 0.0% of its pixels",
            "robotiq_2f85: median -5.0 mm, |err| median 12.5 mm, 10-90% [-25.0, +15.0] mm, no depth on 25.0% of its "
            "pixels"]


def _write_scene(root, scene_id, obj_id, ee, sensor_mm, mask):
    """One stereo-depth frame: exact depth GT_M, sensor depth GT_M + sensor_mm on `mask` (0 = hole) and
    0.5 m too far off it (pixels the tool must ignore), one mask pixel without exact depth."""
    depth_gt = np.full((H, W), GT_M)
    depth = np.full((H, W), GT_M + 0.5)
    depth[mask] = np.where(np.isnan(sensor_mm), 0.0, GT_M + np.nan_to_num(sensor_mm) / 1000.0)
    no_truth = np.zeros((H, W), bool)
    no_truth.flat[H * W - 1] = True  # on the mask, with sensor depth, but no exact depth: neither error nor hole
    depth_gt[no_truth], depth[no_truth] = 0.0, GT_M
    meta = SceneMeta(obj_id=obj_id, arm="ur5e", end_effector=ee, joint_names=["j"], T_cam_base=np.eye(4),
                     depth_sensor={"mode": "stereo", "profile": {}})
    f = 100.0
    writer = SceneWriter(Dataset(root).scene_dir(scene_id), meta, [2, 4])
    writer.write(Frame(im_id=0, rgb=np.zeros((H, W, 3), np.uint8), depth=depth, mask=mask | no_truth,
                       mask_visib=mask | no_truth, K=np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]]),
                       T_cam_ee=np.eye(4), joint_positions=np.zeros(1), T_base_ee=np.eye(4), depth_gt=depth_gt))


def test_depth_error_reports_the_statistics_of_a_known_error(tmp_path, capsys):
    assert DEPTH_SCALE == 0.1  # the errors above are whole PNG units at this scale
    rng = np.random.default_rng(0)
    n = len(ERRORS_MM) + HOLES
    sensor = rng.permutation(np.concatenate([ERRORS_MM, np.full(HOLES, np.nan)]))  # scattered over the mask
    mask = np.zeros((H, W), bool)
    mask.flat[rng.choice(H * W - 1, n, replace=False)] = True
    _write_scene(tmp_path, 0, 2, "robotiq_2f85", sensor, mask)
    small = np.zeros((H, W), bool)
    small[10:20, 10:20] = True
    _write_scene(tmp_path, 1, 4, "kinova_3f", np.full(100, -2.0), small)

    errors, holes = ee_depth_errors(tmp_path)
    np.testing.assert_allclose(np.sort(errors["robotiq_2f85"]), ERRORS_MM / 1000.0, atol=1e-9)
    np.testing.assert_allclose(errors["kinova_3f"], -0.002, atol=1e-9)
    assert len(errors["kinova_3f"]) == 100
    assert holes == {"robotiq_2f85": 0.25, "kinova_3f": 0.0}

    out = tmp_path / "h.png"
    assert main([str(tmp_path), "--out", str(out)]) == 0
    assert capsys.readouterr().out.splitlines() == [*EXPECTED, str(out)]
    assert out.stat().st_size > 5000


def _write_robot_scene(root):
    """One stereo frame of a 20 x 30 px robot (rows 5-24, columns 5-34): a pixel's distance to its outline is
    1 + its distance in rows or columns to the nearest edge pixel, 1 to 10. Sensor errors by distance: 1 px
    +9.0 mm (every even column of that ring without depth: 48 of its 96 pixels), 2-3 px +4.0 mm, 4-8 px
    -1.0 mm, 9-10 px +0.5 mm."""
    robot = np.zeros((H, W), bool)
    robot[5:25, 5:35] = True
    rows, cols = np.mgrid[0:H, 0:W]
    dist = np.minimum(np.minimum(rows - 4, 25 - rows), np.minimum(cols - 4, 35 - cols))
    error_mm = np.select([dist == 1, dist <= 3, dist <= 8], [9.0, 4.0, -1.0], 0.5)
    depth = np.where(robot, GT_M + error_mm / 1000.0, GT_M + 0.5)
    depth[robot & (dist == 1) & (cols % 2 == 0)] = 0.0
    meta = SceneMeta(obj_id=2, arm="ur5e", end_effector="robotiq_2f85", joint_names=["j"], T_cam_base=np.eye(4),
                     depth_sensor={"mode": "stereo", "profile": {}}, links=["link", "robotiq_2f85"])
    link_ids = robot.astype(np.uint8)
    link_ids[10:15, 10:15] = 2  # the end-effector: a part of the robot as any other
    f = 100.0
    writer = SceneWriter(Dataset(root).scene_dir(0), meta, [2, 4])
    writer.write(Frame(im_id=0, rgb=np.zeros((H, W, 3), np.uint8), depth=depth, mask=link_ids == 2,
                       mask_visib=link_ids == 2, K=np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]]),
                       T_cam_ee=np.eye(4), joint_positions=np.zeros(1), T_base_ee=np.eye(4),
                       depth_gt=np.full((H, W), GT_M), link_ids=link_ids))


def test_robot_depth_error_by_distance_to_the_outline(tmp_path, capsys):
    _write_robot_scene(tmp_path)
    out = tmp_path / "h.png"
    assert main([str(tmp_path), "--out", str(out), "--robot"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-3:] == ["robot pixels by distance to its outline: median error, |err| median, no depth",
                          "0 ur5e+robotiq_2f85: 0-1.5 px +9.0 mm, 9.0 mm, 50%; 1.5-3.5 px +4.0 mm, 4.0 mm, 0%; "
                          "3.5-8 px -1.0 mm, 1.0 mm, 0%; over 8 px +0.5 mm, 0.5 mm, 0%", str(out)]


def test_robot_depth_error_needs_the_robot_parts(tmp_path, capsys):
    small = np.zeros((H, W), bool)
    small[10:20, 10:20] = True
    _write_scene(tmp_path, 1, 4, "kinova_3f", np.full(100, -2.0), small)
    assert main([str(tmp_path), "--out", str(tmp_path / "h.png"), "--robot"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no robot_mask_visib/" in err[0]
