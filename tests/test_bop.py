"""BOP scene writer/reader: exact round trip, gt_info known answers, resume after a kill, clear errors."""

import json
import re

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kernel import files
from kernel.bop import Frame, SceneMeta, SceneWriter, gt_info, read_frame, read_scene
from kernel.errors import UserError
from kernel.transforms import make_T

H, W = 24, 32

OBJ_IDS = list(range(1, 7))  # the data set's objects, the COCO categories


def _pose(rng) -> np.ndarray:
    return make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-1.0, 1.0, 3))


def _meta(ee="robotiq_2f85") -> SceneMeta:
    return SceneMeta(obj_id=3, arm="ur5e", end_effector=ee, joint_names=[f"joint_{i}" for i in range(6)],
                     T_cam_base=_pose(np.random.default_rng(99)))


def _frame(im_id: int) -> Frame:
    rng = np.random.default_rng(im_id)
    depth = rng.uniform(0.3, 2.0, (H, W))
    depth[:2] = 0.0  # no depth
    depth[5, 5] = 6.5535  # the farthest depth a uint16 PNG holds at depth_scale 0.1
    mask = np.zeros((H, W), bool)
    mask[4 + im_id:15, 6:20] = True
    mask_visib = mask.copy()
    mask_visib[:, 15:] = False
    K = np.array([[300.0 + im_id, 0.0, 16.2], [0.0, 301.5, 11.7], [0.0, 0.0, 1.0]])
    return Frame(im_id=im_id, rgb=rng.integers(0, 256, (H, W, 3), dtype=np.uint8), depth=depth, mask=mask,
                 mask_visib=mask_visib, K=K, T_cam_ee=_pose(rng), joint_positions=rng.uniform(-3, 3, 6),
                 T_base_ee=_pose(rng))


def _assert_same(got: Frame, want: Frame, depth_scale=0.1):
    assert got.im_id == want.im_id
    assert got.rgb.dtype == np.uint8 and np.array_equal(got.rgb, want.rgb)
    assert np.abs(got.depth - want.depth).max() * 1000.0 <= depth_scale / 2 + 1e-9
    assert np.array_equal(got.depth == 0, want.depth == 0)
    assert np.array_equal(got.mask, want.mask) and np.array_equal(got.mask_visib, want.mask_visib)
    assert np.allclose(got.K, want.K, rtol=0, atol=1e-9)
    for T_got, T_want in ((got.T_cam_ee, want.T_cam_ee), (got.T_base_ee, want.T_base_ee)):
        assert np.abs(T_got[:3, 3] - T_want[:3, 3]).max() < 1e-6
        assert np.abs(T_got[:3, :3] - T_want[:3, :3]).max() < 1e-9
        assert np.array_equal(T_got[3], [0, 0, 0, 1])
    assert np.array_equal(got.joint_positions, want.joint_positions)


def _json(scene, name):
    return json.loads((scene / f"{name}.json").read_text())


def test_round_trip_three_frames(tmp_path):
    scene = tmp_path / "train_pbr" / "000007"
    meta = _meta()
    writer = SceneWriter(scene, meta, OBJ_IDS)
    frames = [_frame(i) for i in range(3)]
    for frame in frames:
        writer.write(frame)

    got_meta, im_ids = read_scene(scene)
    assert im_ids == [0, 1, 2]
    assert (got_meta.obj_id, got_meta.arm, got_meta.end_effector, got_meta.joint_names, got_meta.depth_scale) == \
        (3, "ur5e", "robotiq_2f85", meta.joint_names, 0.1)
    assert np.abs(got_meta.T_cam_base - meta.T_cam_base).max() < 1e-12
    for frame in frames:
        _assert_same(read_frame(scene, frame.im_id), frame)

    # The files as bop_toolkit reads them.
    depth_png = cv2.imread(str(scene / "depth" / "000001.png"), cv2.IMREAD_UNCHANGED)
    assert depth_png.dtype == np.uint16 and depth_png[5, 5] == 65535 and depth_png[0, 0] == 0
    assert np.abs(depth_png * 0.1 - frames[1].depth * 1000.0).max() <= 0.05 + 1e-9
    mask_png = cv2.imread(str(scene / "mask_visib" / "000002_000000.png"), cv2.IMREAD_UNCHANGED)
    assert mask_png.dtype == np.uint8 and set(np.unique(mask_png)) == {0, 255}
    camera, gt, robot = _json(scene, "scene_camera"), _json(scene, "scene_gt"), _json(scene, "scene_robot")
    assert sorted(camera) == sorted(gt) == ["0", "1", "2"]
    assert np.allclose(camera["1"]["cam_t_w2c"], meta.T_cam_base[:3, 3] * 1000.0)
    assert np.allclose(np.reshape(camera["1"]["cam_R_w2c"], (3, 3)), meta.T_cam_base[:3, :3])
    assert camera["1"]["depth_scale"] == 0.1 and len(camera["1"]["cam_K"]) == 9
    assert gt["2"][0]["obj_id"] == 3 and np.allclose(gt["2"][0]["cam_t_m2c"], frames[2].T_cam_ee[:3, 3] * 1000.0)
    assert robot["config"] == "ur5e+robotiq_2f85" and np.array(robot["frames"]["0"]["T_base_ee"]).shape == (4, 4)
    assert (scene / "scene_gt.json").read_text().startswith('{\n  "0": [')
    assert not list(scene.rglob(".*"))  # no temp files left


def test_gt_info_known_answers(tmp_path):
    mask = np.zeros((10, 12), bool)
    mask[2:5, 3:7] = True  # rows 2..4, cols 3..6: 12 px
    mask_visib = mask.copy()
    mask_visib[4] = False  # 8 px visible
    depth = np.ones((10, 12))
    depth[2, 3] = depth[3, 4] = 0.0  # two mask pixels without depth
    depth[0, 0] = 0.0  # outside the mask: does not count
    info = gt_info(mask, mask_visib, depth)
    assert info == {"bbox_obj": [3, 2, 3, 2], "bbox_visib": [3, 2, 3, 1], "px_count_all": 12,
                    "px_count_valid": 10, "px_count_visib": 8, "visib_fract": pytest.approx(8 / 12)}

    empty = np.zeros_like(mask)
    assert gt_info(empty, empty, depth) == {"bbox_obj": [-1, -1, -1, -1], "bbox_visib": [-1, -1, -1, -1],
                                            "px_count_all": 0, "px_count_valid": 0, "px_count_visib": 0,
                                            "visib_fract": 0.0}
    hidden = gt_info(mask, empty, depth)
    assert hidden["bbox_obj"] == [3, 2, 3, 2] and hidden["bbox_visib"] == [-1, -1, -1, -1]
    assert hidden["visib_fract"] == 0.0

    # The written record is gt_info of the written masks and depth.
    frame = _frame(0)
    SceneWriter(tmp_path, _meta(), OBJ_IDS).write(frame)
    written = _json(tmp_path, "scene_gt_info")["0"][0]
    assert written == gt_info(frame.mask, frame.mask_visib, frame.depth)
    assert written["px_count_all"] == 11 * 14 and written["px_count_visib"] == 11 * 9


def test_resume_keeps_written_frames(tmp_path):
    frames = [_frame(i) for i in range(3)]
    first = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    first.write(frames[0])
    first.write(frames[1])

    again = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    assert again.done(0) and again.done(1) and not again.done(2)
    again.write(frames[2])
    assert again.done(2)
    assert read_scene(tmp_path)[1] == [0, 1, 2]
    for name in ("scene_camera", "scene_gt", "scene_gt_info"):
        assert sorted(_json(tmp_path, name)) == ["0", "1", "2"]
    assert sorted(_json(tmp_path, "scene_robot")["frames"]) == ["0", "1", "2"]
    for frame in frames:
        _assert_same(read_frame(tmp_path, frame.im_id), frame)


def test_leftover_temp_file_is_not_a_frame(tmp_path):
    writer = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    writer.write(_frame(0))
    (tmp_path / "rgb" / ".000001.png.tmp123").write_bytes(b"half a png")
    (tmp_path / ".scene_gt.json.tmp123").write_text('{"1": [')
    resumed = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    assert resumed.done(0) and not resumed.done(1)
    assert read_scene(tmp_path)[1] == [0]
    with pytest.raises(UserError, match="frame 1"):
        read_frame(tmp_path, 1)


def test_killed_between_json_writes_is_not_done(tmp_path, monkeypatch):
    """All images of frame 1 and some JSONs on disk, then a kill: frame 1 is not done and is redone."""
    writer = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    writer.write(_frame(0))
    real_write = files.write_atomic

    def killed_at_gt_info(path, data):
        if path.name == "scene_gt_info.json":
            raise KeyboardInterrupt
        real_write(path, data)

    monkeypatch.setattr(files, "write_atomic", killed_at_gt_info)
    with pytest.raises(KeyboardInterrupt):
        writer.write(_frame(1))
    monkeypatch.undo()
    assert (tmp_path / "rgb" / "000001.png").exists() and "1" in _json(tmp_path, "scene_gt")

    resumed = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    assert resumed.done(0) and not resumed.done(1)
    assert read_scene(tmp_path)[1] == [0]
    resumed.write(_frame(1))
    assert read_scene(tmp_path)[1] == [0, 1]
    _assert_same(read_frame(tmp_path, 1), _frame(1))


@pytest.mark.parametrize("bad", [7.0, -0.5, np.nan])
def test_depth_out_of_range(tmp_path, bad):
    writer = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    frame = _frame(4)
    frame.depth[3, 3] = bad
    with pytest.raises(UserError, match=r"frame 4: depth .* 0\.\.6\.5535 m"):
        writer.write(frame)
    assert not writer.done(4) and not list((tmp_path / "rgb").iterdir())


def test_mismatched_image_sizes(tmp_path):
    writer = SceneWriter(tmp_path, _meta(), OBJ_IDS)
    frame = _frame(5)
    frame.mask_visib = frame.mask_visib[:, :-1]
    with pytest.raises(UserError, match=r"frame 5: image sizes differ: .*depth \(24, 32\).*mask_visib \(24, 31\)"):
        writer.write(frame)
    assert not writer.done(5) and not list((tmp_path / "rgb").iterdir())


def test_scene_of_another_robot_is_refused(tmp_path):
    SceneWriter(tmp_path, _meta(), OBJ_IDS).write(_frame(0))
    before = (tmp_path / "scene_robot.json").read_text()
    with pytest.raises(UserError, match=r"ur5e\+robotiq_2f85.*not ur5e\+franka_hand"):
        SceneWriter(tmp_path, _meta(ee="franka_hand"), OBJ_IDS)
    assert (tmp_path / "scene_robot.json").read_text() == before


def test_read_missing_frame(tmp_path):
    SceneWriter(tmp_path, _meta(), OBJ_IDS).write(_frame(0))
    with pytest.raises(UserError, match=f"{re.escape(str(tmp_path))}.*frame 9"):
        read_frame(tmp_path, 9)
    with pytest.raises(UserError, match="no complete frame"):
        read_scene(tmp_path / "empty")
